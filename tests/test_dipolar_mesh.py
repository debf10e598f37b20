"""The dipolar Ewald sum on a mesh (``Dipolar(method="pme")``, smooth
particle-mesh Ewald): it converges to the k-vector Ewald sum as the mesh is
refined (at the B-spline order's rate), the accuracy knob chooses a mesh
that keeps its promise, its derivatives are those of its energy (finite
differences), it does not depend on where the atoms sit on the mesh beyond
the accuracy, slabs, the prepared operators, a short spin–lattice run, and
its refusals."""

import numpy as np
import pytest
from ase import units
from conftest import CO_BS, CO_LJ
from test_dipolar import _bound, _cobalt, _scene, _unit

import ase_spin
from ase_spin import (
    DIPOLAR_CODATA,
    BetheSlater,
    CollectivePRK,
    Dipolar,
    Exchange,
    LennardJones,
    SpinLatticeCalculator,
    Want,
)
from ase_spin.terms.dipolar_kspace import ewald_parameters
from ase_spin.terms.dipolar_mesh import bspline_weights, mesh_size, mesh_spacing

C = DIPOLAR_CODATA
FIELDS = Want(energy=True, forces=True, magnetic_forces=True)


def _relative(res, ref):
    """Largest relative errors of (energy, magnetic forces, forces)."""
    return (abs(res.energy - ref.energy) / abs(ref.energy),
            np.abs(res.magnetic_forces - ref.magnetic_forces).max()
            / np.abs(ref.magnetic_forces).max(),
            np.abs(res.forces - ref.forces).max() / np.abs(ref.forces).max())


def test_bsplines_are_a_partition_of_unity_with_their_derivatives():
    t = np.linspace(0.0, 0.999, 7)
    for order in (4, 5, 8):
        w, dw, d2w = bspline_weights(t, order)
        np.testing.assert_allclose(w.sum(axis=-1), 1.0, rtol=1e-14)
        np.testing.assert_allclose(dw.sum(axis=-1), 0.0, atol=1e-14)
        np.testing.assert_allclose(d2w.sum(axis=-1), 0.0, atol=1e-13)
        h = 1e-6
        wp, dwp, _ = bspline_weights(t[1:-1] + h, order)
        wm, dwm, _ = bspline_weights(t[1:-1] - h, order)
        np.testing.assert_allclose((wp - wm) / (2 * h), dw[1:-1], atol=1e-8)
        np.testing.assert_allclose((dwp - dwm) / (2 * h), d2w[1:-1], atol=1e-7)


def test_mesh_converges_to_the_ewald_sum_at_the_spline_order():
    """At one α, the mesh's error against the k-vector sum (its k_c far out)
    falls with the mesh spacing h as h^(p−1) for the field and h^(p−2) for
    the forces (a spline differentiated once, twice): fitted log-log slopes
    over K = 12 … 48 at order 6, on a triclinic cell."""
    atoms, mu = _scene("triclinic")
    s = _unit(atoms.get_initial_magnetic_moments())
    alpha, kcut = ewald_parameters(5.0, 1e-6)
    ref = _bound(Dipolar(5.0, "ewald", alpha=alpha, kcut=3 * kcut), atoms, mu).evaluate(
        atoms.positions, s, FIELDS)
    meshes = np.array([12, 16, 24, 32, 48])
    errors = np.array([_relative(_bound(Dipolar(5.0, "pme", alpha=alpha, mesh=K, order=6),
                                        atoms, mu).evaluate(atoms.positions, s, FIELDS), ref)
                       for K in meshes])
    slope_b = -np.polyfit(np.log(meshes), np.log(errors[:, 1]), 1)[0]
    slope_f = -np.polyfit(np.log(meshes), np.log(errors[:, 2]), 1)[0]
    assert slope_b > 6 - 1 - 0.5
    assert slope_f > 6 - 2 - 0.5
    assert errors[-1, :2].max() < 2e-6 and errors[-1, 2] < 3e-5


@pytest.mark.parametrize("accuracy,rc,order", [(1e-3, 4.0, 5), (1e-4, 7.0, 5), (1e-5, 4.0, 8),
                                               (1e-6, 7.0, 8)])
def test_accuracy_knob_chooses_a_mesh_that_keeps_it(accuracy, rc, order):
    """Energy and field within 10× ``accuracy`` (the Ewald sum's own margin,
    test_dipolar.test_ewald_accuracy_knob) of a 1e-13 reference, the forces
    within 30× (their spline is differentiated twice)."""
    atoms, mu = _scene("triclinic")
    s = _unit(atoms.get_initial_magnetic_moments())
    ref = _bound(Dipolar(6.0, "ewald", accuracy=1e-13), atoms, mu).evaluate(
        atoms.positions, s, FIELDS)
    scale = C * mu.max() ** 2 / atoms.get_volume() * len(atoms)
    res = _bound(Dipolar(rc, "pme", accuracy=accuracy, order=order), atoms, mu).evaluate(
        atoms.positions, s, FIELDS)
    assert abs(res.energy - ref.energy) < 10 * accuracy * scale
    assert np.abs(res.magnetic_forces - ref.magnetic_forces).max() < 10 * accuracy * scale
    assert np.abs(res.forces - ref.forces).max() < 30 * accuracy * scale
    # and not by luck: the mesh is finer the tighter the accuracy
    alpha, kcut = Dipolar(rc, "pme", accuracy=accuracy).splitting()
    coarse = mesh_size(atoms.cell.array, alpha, kcut, 100 * accuracy, order)
    assert np.prod(coarse) < np.prod(mesh_size(atoms.cell.array, alpha, kcut, accuracy, order))


def test_mesh_is_translation_invariant_within_its_accuracy():
    """Shifting every atom by fractions of a mesh cell changes the energy and
    fields by less than the accuracy asked (the mesh breaks the invariance
    at the level of its interpolation error), and a shift by whole mesh
    cells not at all (to round-off)."""
    atoms, mu = _scene("triclinic")
    s = _unit(atoms.get_initial_magnetic_moments())
    accuracy = 1e-5
    term = Dipolar(5.0, "pme", accuracy=accuracy, order=6)
    ev = _bound(term, atoms, mu)
    ref = ev.evaluate(atoms.positions, s, FIELDS)
    scale = C * mu.max() ** 2 / atoms.get_volume() * len(atoms)
    mesh = np.array(term.mesh_size(atoms.cell.array))
    cell = atoms.cell.array
    for frac in ([0.5, 0.0, 0.0], [0.25, 0.5, 0.75], [0.3, 0.1, 0.6]):
        shift = (np.array(frac) / mesh) @ cell
        moved = ev.evaluate(atoms.positions + shift, s, FIELDS)
        assert 0 < abs(moved.energy - ref.energy) < accuracy * scale
        assert np.abs(moved.magnetic_forces - ref.magnetic_forces).max() < accuracy * scale
        assert np.abs(moved.forces - ref.forces).max() < 3 * accuracy * scale
    whole = ev.evaluate(atoms.positions + (np.array([2, 1, 3]) / mesh) @ cell, s, FIELDS)
    assert whole.energy == pytest.approx(ref.energy, rel=1e-11)


def test_slab_mesh_agrees_with_the_slab_ewald_sum():
    atoms, mu = _scene("slab")
    s = _unit(atoms.get_initial_magnetic_moments())
    ref = _bound(Dipolar(4.0, "ewald", accuracy=1e-10, slab=3.0), atoms, mu).evaluate(
        atoms.positions, s, FIELDS)
    res = _bound(Dipolar(4.0, "pme", accuracy=1e-6, slab=3.0, order=8), atoms, mu).evaluate(
        atoms.positions, s, FIELDS)
    e, b, f = _relative(res, ref)
    assert max(e, b) < 1e-5 and f < 1e-4


def test_collective_prk_conserves_energy_with_mesh_dipolar():
    """20 steps of 0.25 fs of LJ + exchange + a strong mesh dipolar term
    (2000× the physical prefactor): the energy drifts no more than exchange
    alone makes it (plus 1e-6 eV): the mesh energy is smooth in the positions
    and its forces are its derivatives."""
    drifts = []
    for extra in ([], [Dipolar(3.5, "pme", accuracy=1e-4, order=8,
                               prefactor=2000 * DIPOLAR_CODATA)]):
        atoms = _cobalt()
        atoms.set_momenta(np.random.default_rng(1).normal(0, 0.05, (len(atoms), 3)))
        atoms.calc = SpinLatticeCalculator([LennardJones(**CO_LJ, cutoff="shift"),
                                            Exchange(BetheSlater(*CO_BS), rc=4.0), *extra])
        e0 = atoms.get_potential_energy() + atoms.get_kinetic_energy()
        if extra:
            assert abs(atoms.calc.results["energy_terms"]["dipolar"]) > 1e-3
        CollectivePRK(atoms, 0.25 * units.fs).run(20)
        drifts.append(abs(atoms.get_potential_energy() + atoms.get_kinetic_energy() - e0))
    assert drifts[1] < 3.0 * drifts[0] + 1e-6


def test_mesh_settings_are_checked():
    with pytest.raises(ValueError, match="method='pme'"):
        Dipolar(5.0, "ewald", mesh=16)
    with pytest.raises(ValueError, match="method='pme'"):
        Dipolar(5.0, "ewald", order=6)
    with pytest.raises(ValueError, match="order must lie"):
        Dipolar(5.0, "pme", order=3)
    with pytest.raises(TypeError, match="order"):
        Dipolar(5.0, "pme", order=5.5)
    with pytest.raises(ValueError, match="at least the order"):
        Dipolar(5.0, "pme", mesh=(16, 16, 4), order=5)
    with pytest.raises(ValueError, match="whole numbers"):
        Dipolar(5.0, "pme", mesh=(16, 16))
    with pytest.raises(ValueError, match="not both"):
        Dipolar(5.0, "pme", mesh=16, kcut=3.0)
    wire, mu = _scene("slab")
    wire.pbc = [True, False, False]
    with pytest.raises(ValueError, match="periodic"):
        _bound(Dipolar(5.0, "pme"), wire, mu)
    term = Dipolar(5.0, "pme", mesh=20)
    assert term.mesh == (20, 20, 20)
    term.order = 6  # reassigned: checked again
    with pytest.raises(ValueError, match="order"):
        term.order = 13
    assert term.order == 6


def test_write_lammps_refuses_the_mesh_saying_why(tmp_path):
    atoms = _cobalt(1)
    atoms.calc = SpinLatticeCalculator([Dipolar(3.5, "pme")])
    with pytest.raises(NotImplementedError, match="pppm/dipole/spin"):
        ase_spin.write_lammps(tmp_path / "deck", atoms, timestep=0.1 * units.fs)


def test_suzuki_trotter_refuses_the_mesh_saying_why():
    atoms = _cobalt(1)
    atoms.calc = SpinLatticeCalculator([Exchange(BetheSlater(*CO_BS), rc=4.0),
                                        Dipolar(3.5, "pme", order=6)])
    dyn = ase_spin.SuzukiTrotter(atoms, 0.1 * units.fs)
    with pytest.raises(ValueError, match="mesh convolution"):
        dyn.run(1)


def test_mesh_spacing_follows_the_estimate():
    # ε ∝ (αh)^(p−2): a hundred times the accuracy, (100)^(1/(p−2)) times the spacing
    for order in (5, 8):
        assert mesh_spacing(0.5, 1e-4, order) / mesh_spacing(0.5, 1e-6, order) == pytest.approx(
            100 ** (1 / (order - 2)))
