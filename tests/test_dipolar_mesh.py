"""The dipolar Ewald sum on a mesh (``Dipolar(method="pme")``, smooth
particle-mesh Ewald): it converges to the k-vector Ewald sum as the mesh is
refined (at the B-spline order's rate), the accuracy knob chooses a mesh
that keeps its promise, its derivatives are those of its energy (finite
differences), it does not depend on where the atoms sit on the mesh beyond
the accuracy, slabs, the prepared operators, a short spin–lattice run, its
refusals, and its export as LAMMPS's ``pppm/dipole/spin`` (agreement to both
methods' accuracies, skipped without lammps)."""

import warnings

import numba
import numpy as np
import pytest
from ase import units
from conftest import CO_BS, CO_LJ
from lammps_peer import EV_PER_FM, LammpsSpin, lammps_available
from test_dipolar import DIPOLAR_LAMMPS_KSPACE, _bound, _cobalt, _film, _scene, _unit

import ase_spin
from ase_spin import (
    DIPOLAR_CODATA,
    DIPOLAR_LAMMPS,
    BetheSlater,
    CollectivePRK,
    Dipolar,
    Exchange,
    LennardJones,
    SpinLatticeCalculator,
    Want,
    set_spins,
)
from ase_spin._jit import threads
from ase_spin._jit.reductions import stencil_groups
from ase_spin._jit.threads import chunks
from ase_spin.scenes import fcc_cobalt
from ase_spin.terms.dipolar import LAMMPS_PPPM_MAX_ORDER
from ase_spin.terms.dipolar_kspace import ewald_parameters, slab_geometry
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


def _kspace_lines(tmp_path, atoms, term):
    """The ``kspace_*`` lines of write_lammps's deck of ``term``."""
    files = ase_spin.write_lammps(tmp_path / "deck", atoms, hamiltonian=[term],
                                  timestep=0.1 * units.fs)
    return [line for line in files.input.read_text().splitlines()
            if line.startswith("kspace_")]


def test_write_lammps_exports_the_mesh_as_pppm(tmp_path):
    """pppm/dipole/spin with our α, mesh and order; an order above LAMMPS's
    highest becomes that one on the mesh chosen for it at the same accuracy
    (a given mesh kept), with a warning naming both; slabs; and the
    orthogonal boxes LAMMPS's dipolar k-space styles ask for."""
    atoms = _cobalt(2)
    term = Dipolar(4.0, "pme", accuracy=1e-4, order=6, prefactor=DIPOLAR_LAMMPS)
    alpha, _ = term.splitting()
    K = term.mesh_size(atoms.cell.array)
    assert _kspace_lines(tmp_path, atoms, term) == [
        "kspace_style pppm/dipole/spin 0.0001",
        f"kspace_modify gewald {alpha!r} mesh {K[0]} {K[1]} {K[2]} order 6"]
    term = Dipolar(4.0, "pme", accuracy=1e-4, prefactor=DIPOLAR_LAMMPS)  # order 8
    with pytest.warns(UserWarning, match="order 8 on the mesh .*order 7 on the mesh"):
        lines = _kspace_lines(tmp_path, atoms, term)
    K7 = Dipolar(4.0, "pme", accuracy=1e-4, order=LAMMPS_PPPM_MAX_ORDER).mesh_size(
        atoms.cell.array)
    assert K7 != term.mesh_size(atoms.cell.array)  # a mesh for order 7, not order 8's
    assert lines[1].endswith(f"mesh {K7[0]} {K7[1]} {K7[2]} order 7")
    with pytest.warns(UserWarning, match="as given"):
        lines = _kspace_lines(tmp_path, atoms, Dipolar(4.0, "pme", mesh=(20, 24, 30), order=9,
                                                       prefactor=DIPOLAR_LAMMPS))
    assert lines[1].endswith("mesh 20 24 30 order 7")
    film = _film(4, 2.5, 2.0, vacuum=3.0)
    set_spins(film, np.tile([0.0, 0.0, 1.0], (4, 1)), 2.0)
    term = Dipolar(3.0, "pme", accuracy=1e-4, order=5, slab=4.0, prefactor=DIPOLAR_LAMMPS)
    lines = _kspace_lines(tmp_path, film, term)
    K = term.mesh_size(slab_geometry(film.cell.array, 4.0)[0])
    assert f"mesh {K[0]} {K[1]} {K[2]} order 5" in lines[1]
    assert lines[2] == "kspace_modify slab 4.0"
    with pytest.raises(NotImplementedError, match="pppm/dipole/spin takes orthogonal"):
        _kspace_lines(tmp_path, _scene("triclinic")[0], Dipolar(5.0, "pme", order=5,
                                                                 prefactor=DIPOLAR_LAMMPS))


def _lammps_pppm(atoms, kspace, dt_fs=0.01):
    """LAMMPS with ``spin/dipole/long 1.0`` (no pair within 1 Å: the k-space
    part alone) and the ``kspace`` lines: its energy, forces and stress at
    ``run 0``, and its k-space field across the spins. LAMMPS keeps that
    field in ``fm_long``, which no compute reads; one ``fix nve/spin`` step
    on a frozen lattice rotates each spin about it (constant through the
    step: no pair within the cutoff) by Cayley steps, s' − s = dt ω × m
    with m = (s + s')/2 to O((ω dt)²) (≈ 1e-9 here), so m × (s' − s)/dt|m|²
    is ω across m; times ħ, B = ħω across m (eV)."""
    lmp = LammpsSpin(atoms, (0.0, 2.0, 3.0, False), (0.0, 0.0, 1.0, 3.0, False),
                     timestep_fs=dt_fs, lattice="frozen", kspace=kspace,
                     pairs=[("spin/dipole/long 1.0", ["pair_coeff * * spin/dipole/long 1.0"])])
    try:
        out = lmp.evaluate()
        lmp.run(1)  # "pre no": the step's spin sweeps use run 0's fm_long
        n = len(atoms)
        after = np.ctypeslib.as_array(lmp.lmp.gather_atoms("sp", 1, 4)).reshape(n, 4)[:, :3]
    finally:
        lmp.close()
    before = ase_spin.get_spins(atoms)
    m = 0.5 * (before + after)
    out["field"] = (np.cross(m, after - before) / (dt_fs * 1e-3)
                    / np.einsum("ij,ij->i", m, m)[:, None] * EV_PER_FM)
    out["across"] = m / np.linalg.norm(m, axis=1)[:, None]
    return out


def _ours(atoms, term, across):
    """Energy, forces, stress and the magnetic forces' components across the
    unit vectors ``across`` of ``term``."""
    atoms.calc = SpinLatticeCalculator([term])
    B = atoms.calc.get_magnetic_forces(atoms)
    return {"energy": atoms.get_potential_energy(), "forces": atoms.get_forces(),
            "stress": atoms.get_stress(),
            "field": B - np.einsum("ij,ij->i", B, across)[:, None] * across}


def _apart(a, b):
    """Relative differences of energy, forces, field and the stress's
    diagonal (each against b's largest component)."""
    return np.array([abs(a["energy"] - b["energy"]) / abs(b["energy"])]
                    + [np.abs(a[k] - b[k]).max() / np.abs(b[k]).max()
                       for k in ("forces", "field")]
                    + [np.abs(a["stress"][:3] - b["stress"][:3]).max()
                       / np.abs(b["stress"][:3]).max()])


def _pppm_agreement(tmp_path, accuracies, order):
    """(ours − Ewald, LAMMPS − Ewald, LAMMPS − ours) per accuracy (rows of
    _apart), LAMMPS's deck written by write_lammps; α = 0.35 fixed (the
    pair cutoff, 1 Å, leaves no real-space pair), the reference the Ewald
    sum at 1e-14; and the ratio of LAMMPS's field to ours over μ_i."""
    atoms = _cobalt(2)
    alpha = 0.35
    rows, ratios = [], []
    for accuracy in accuracies:
        term = Dipolar(1.0, "pme", alpha=alpha, accuracy=accuracy, order=order,
                       prefactor=DIPOLAR_LAMMPS_KSPACE)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the k-space prefactor is not the pair styles'
            kspace = _kspace_lines(tmp_path, atoms, term)
        theirs = _lammps_pppm(atoms, kspace)
        ours = _ours(atoms, term, theirs["across"])
        ref = _ours(atoms, Dipolar(1.0, "ewald", alpha=alpha, accuracy=1e-14,
                                   prefactor=DIPOLAR_LAMMPS_KSPACE), theirs["across"])
        # the moment μ_i LAMMPS leaves out
        theirs["field"] = theirs["field"] * np.linalg.norm(atoms.get_initial_magnetic_moments(),
                                                           axis=1)[:, None]
        ratios.append(np.abs(theirs["field"]).max() / np.abs(ours["field"]).max())
        rows.append([_apart(ours, ref), _apart(theirs, ref), _apart(theirs, ours)])
    return np.array(rows), np.array(ratios)


def _check_pppm_agreement(rows, accuracies):
    for (ours, theirs, apart), accuracy in zip(rows, accuracies):
        # forces, the slowest to converge, to 2× the accuracy; the rest to it
        for errors in (ours, theirs, apart):
            assert errors[1] < 2 * accuracy and max(errors[[0, 2, 3]]) < accuracy
    # and they close in on each other as the accuracy tightens (not by luck):
    # energy, forces and field at least √ of the accuracies' ratio closer
    ratio = accuracies[-1] / accuracies[0]
    assert np.all(rows[-1, 2, :3] < rows[0, 2, :3] * ratio**0.5)


@pytest.mark.skipif(not lammps_available(), reason="lammps not importable")
def test_pme_reciprocal_part_agrees_with_lammps_pppm(tmp_path):
    """Our mesh and LAMMPS's pppm/dipole/spin (P3M: its optimal influence
    function and ik differentiation) on the same mesh, order 5 and α, its
    deck written by write_lammps: both within the accuracy of the Ewald sum,
    so within it of each other, the closer the finer the mesh. LAMMPS's
    k-space field lacks the moment μ_i (1.72 here) that its pair styles'
    fields carry: its spins precess 1/μ_i as fast as they should."""
    accuracies = [1e-3, 1e-4]
    rows, ratios = _pppm_agreement(tmp_path, accuracies, 5)
    _check_pppm_agreement(rows, accuracies)
    np.testing.assert_allclose(ratios, 1.0, rtol=1e-3)  # once μ_i is put back


@pytest.mark.skipif(not lammps_available(), reason="lammps not importable")
def test_pme_agrees_with_lammps_pppm_to_tighter_accuracies(tmp_path):
    """As test_pme_reciprocal_part_agrees_with_lammps_pppm, at LAMMPS's highest
    order (7) down to 1e-6 (the field's measure has a floor of ~2e-8)."""
    accuracies = [1e-3, 1e-4, 1e-5, 1e-6]
    rows, _ = _pppm_agreement(tmp_path, accuracies, 7)
    _check_pppm_agreement(rows, accuracies)


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


@pytest.mark.parametrize("nkeys,reach", [(5, 1), (7, 3), (10, 3), (12, 3), (13, 3), (160, 7),
                                         (161, 9)])
def test_stencil_groups_of_one_parity_write_disjoint_planes(nkeys, reach):
    """The threaded spread's cut (``stencil_groups``): rows sorted by plane k
    cut into one group (fewer than 2·reach planes) or an even number of
    groups of whole planes, and the planes k − reach … k (mod nkeys) that the
    rows of two groups of one parity write are disjoint."""
    keys = np.sort(np.random.default_rng(0).integers(0, nkeys, 600))
    bounds = stencil_groups(keys, nkeys, reach)
    n = len(bounds) - 1
    assert bounds[0] == 0 and bounds[-1] == len(keys) and np.all(np.diff(bounds) >= 0)
    assert (n == 1) == (nkeys < 2 * reach) and (n == 1 or n % 2 == 0)
    groups = [keys[bounds[g]:bounds[g + 1]] for g in range(n)]
    for a, b in zip(groups, groups[1:]):
        assert not set(a) & set(b)  # whole planes
    written = [{(k - j) % nkeys for k in g for j in range(reach + 1)} for g in groups]
    for a in range(n):
        for b in range(a + 2, n, 2):
            assert not written[a] & written[b], (a, b)


@pytest.mark.alone
@pytest.mark.slow
@pytest.mark.skipif(chunks() < 2, reason="numba has one thread here")
def test_threaded_mesh_kernels_give_the_same_bits_with_one_thread_or_all(monkeypatch):
    """From threads.SERIAL_BELOW atoms the spread (groups of planes), the
    gather, the spectral sums and the real-space pair passes run threaded
    over fixed chunks: energy, forces, stress, magnetic forces and per-atom
    energies are the same to the bit with one thread or all, and agree with
    the serial twins (a small system's) to round-off."""
    def evaluate(nthreads):
        atoms = fcc_cobalt(8)
        atoms.rattle(0.05, seed=3)
        atoms.calc = SpinLatticeCalculator([Dipolar(4.0, "pme", accuracy=1e-4)])
        previous = numba.get_num_threads()
        numba.set_num_threads(nthreads)
        try:
            return (atoms.get_potential_energy(), atoms.get_forces(), atoms.get_stress(),
                    atoms.calc.get_magnetic_forces(atoms), atoms.get_potential_energies())
        finally:
            numba.set_num_threads(previous)

    assert len(fcc_cobalt(8)) >= threads.SERIAL_BELOW
    one, every = evaluate(1), evaluate(chunks())
    for a, b in zip(one, every):
        assert np.array_equal(a, b)
    monkeypatch.setattr(threads, "SERIAL_BELOW", 10**9)
    for a, b in zip(one, evaluate(chunks())):
        np.testing.assert_allclose(b, a, rtol=1e-12, atol=1e-12 * np.abs(a).max())
