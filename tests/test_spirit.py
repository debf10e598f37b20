"""Side by side with Spirit (spirit-code) on a pure-spin Heisenberg ferromagnet: the
conventions of spirit_peer (energy, precession sign and rate, ħ, γ, each
pair once) are those of Spirit's own core. Skipped when ``spirit`` is not installed
(the test extra installs it on Linux x86-64)."""

import numpy as np
import pytest

from ase_spin.md.ode import reference_solution
from spirit_peer import SpiritHeisenberg, run_collective, spirit_available
from conftest import cone_spins

pytestmark = pytest.mark.skipif(not spirit_available(), reason="spirit is not installed")

T_END = 2.0**-4  # ps: the fastest spin of the cone turns by about 5 rad


def rms(a, b):
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    import os

    cwd = os.getcwd()
    os.chdir(tmp_path_factory.mktemp("spirit"))  # no file named STOP here
    try:
        with SpiritHeisenberg(4) as sc:
            yield sc
    finally:
        os.chdir(cwd)


@pytest.fixture(scope="module")
def start():
    return cone_spins(64, np.random.default_rng(3), 40.0)


def test_energy_and_field_conventions(scene, start):
    """E = −Σ_<ij> J s_i·s_j (each pair once, J in meV) in both codes."""
    atoms = scene.atoms(start)
    ours = atoms.calc.get_potential_energy(atoms) * 1e3
    scene.set_spins(start)
    theirs = scene.energy_meV()  # float32
    assert abs(ours - theirs) <= 2e-7 * abs(ours)
    # and by hand: the three bonds of each site along +x, +y, +z (periodic)
    s = start.reshape(4, 4, 4, 3)  # Spirit's order: x fastest, so the array is [z, y, x]
    by_hand = -scene.J_meV * sum(np.sum(s * np.roll(s, -1, axis=ax)) for ax in range(3))
    assert ours == pytest.approx(by_hand, rel=1e-12)


def test_same_trajectory_as_dt_to_zero(scene, start):
    """Spirit's RK4 and CollectivePRK order 4 both converge at fourth order to one
    DOP853 solution of ds/dt = −(γ/μB)(1/μ) s × B: the equations are the same."""
    atoms = scene.atoms(start)
    o = scene.integrator_options()
    _, _, ref = reference_solution(atoms, T_END * 1000.0 * __import__("ase").units.fs,
                                   hbar=o["hbar"], precession="moment",
                                   gyromagnetic="moment", g=o["g"], frozen_lattice=True)
    moved = rms(start, ref)
    assert moved > 0.2  # the dynamics is not trivial
    errors = []
    for k in (9, 10):
        dt = 2.0**-k
        steps = int(round(T_END / dt))
        theirs, _ = scene.run("RK4", dt, steps, start)
        ours, _, _ = run_collective(scene, start, 4, dt, steps, threads=1)
        errors.append((rms(theirs, ref), rms(ours, ref)))
    (sp0, pr0), (sp1, pr1) = errors
    assert 10 < sp0 / sp1 < 24 and 10 < pr0 / pr1 < 24  # 16: fourth order, both
    assert sp1 < 1e-5 * moved and pr1 < 1e-5 * moved
    # the wrong precession sense is an O(1) difference: the check above can fail
    flipped = scene.atoms(start)
    _, _, wrong = reference_solution(flipped, T_END * 1000.0 * __import__("ase").units.fs,
                                     hbar=o["hbar"], precession="spin",
                                     gyromagnetic="moment", g=o["g"], frozen_lattice=True)
    assert rms(wrong, ref) > 0.1 * moved


def test_second_order_solvers_converge_to_the_same_trajectory(scene, start):
    """Spirit's Heun, Depondt and SIB solvers (second order) on the same equation."""
    steps = {k: int(round(T_END / 2.0**-k)) for k in (11, 12)}
    ours, _, _ = run_collective(scene, start, 6, 2.0**-10, 64, threads=1)  # ≈ 1e-9 accurate
    for solver in ("Heun", "Depondt", "SIB"):
        e = [rms(scene.run(solver, 2.0**-k, steps[k], start)[0], ours) for k in (11, 12)]
        assert 3 < e[0] / e[1] < 5.5, (solver, e)  # 4: second order
        assert e[1] < 1e-3, (solver, e)


def test_bad_input(scene, start):
    with pytest.raises(ValueError, match="single precision"):
        scene.start("RK4", 1e-3)
    with pytest.raises(ValueError, match="solver must be one of"):
        scene.start("VP", 2.0**-10)
    with pytest.raises(ValueError, match="shape"):
        scene.set_spins(start[:10])
    with pytest.raises(ValueError, match="n must be"):
        SpiritHeisenberg(2)


# -- energy landscapes: minima and minimum energy paths (issue 40) ------------------

FILM = dict(J_meV=10.0, D_meV=3.0, K_meV=1.0, field_T=2.0, mu=2.2)  # dmi_film's


def _largest_torque(atoms):
    import ase_spin

    B = atoms.calc.get_magnetic_forces(atoms)
    return np.linalg.norm(np.cross(ase_spin.get_spins(atoms), B), axis=1).max()


def test_film_hamiltonian_maps_on_spirit(tmp_path, monkeypatch):
    """Exchange + Néel DMI + anisotropy + field on a square lattice: the same
    energy of random spins (Spirit's single-precision value) in both codes, and
    a clear difference with the other DMI chirality (the check can fail)."""
    from spirit_peer import SpiritFilm

    monkeypatch.chdir(tmp_path)
    spins = np.random.default_rng(0).normal(size=(36, 3))
    spins /= np.linalg.norm(spins, axis=1)[:, None]
    with SpiritFilm((6, 6, 1), **FILM) as sc:
        ours = sc.atoms(spins).get_potential_energy() * 1e3
        sc.set_spins(spins)
        assert abs(sc.energy_meV() - ours) <= 2e-7 * abs(ours)
    with SpiritFilm((6, 6, 1), **{**FILM, "D_meV": -3.0}) as sc:
        sc.set_spins(spins)
        assert abs(sc.energy_meV() - ours) > 1.0


def test_minima_agree_with_spirit(tmp_path, monkeypatch):
    """Spirit's LBFGS_OSO and SpinLBFGS reach the same minimum: an open 8 × 8
    film from a cone (the ferromagnet with DMI-canted edges, a stiff minimum)
    and a periodic 12 × 12 film from a skyrmion profile (the isolated skyrmion,
    whose translation is a very soft mode: its spins agree only as τ/κ
    allows)."""
    import ase_spin
    from ase_spin.optimize import SpinLBFGS
    from ase_spin.analysis import topological_charge
    from ase_spin.scenes import cone, neel_skyrmion
    from spirit_peer import SpiritFilm

    monkeypatch.chdir(tmp_path)
    with SpiritFilm((8, 8, 1), (False, False, False), convergence_meV=1e-7, **FILM) as sc:
        start = cone(64, np.random.default_rng(1), 60.0)
        theirs = sc.atoms(sc.minimise(start)[0])
        assert _largest_torque(theirs) < 1e-9  # Spirit's criterion in meV
        atoms = sc.atoms(start)
        assert SpinLBFGS(atoms).run(fmax=1e-10)
        assert abs(atoms.get_potential_energy() - theirs.get_potential_energy()) < 1e-13
        s = ase_spin.get_spins(atoms)
        assert np.abs(s - ase_spin.get_spins(theirs)).max() < 1e-6
        assert s[:, 2].min() < 0.8  # not collinear
    with SpiritFilm((12, 12, 1), convergence_meV=1e-9, **FILM) as sc:
        start = neel_skyrmion(sc.positions, 6.25)
        theirs = sc.atoms(sc.minimise(start)[0])
        atoms = sc.atoms(start)
        assert SpinLBFGS(atoms).run(fmax=1e-12, steps=2000)
        assert abs(atoms.get_potential_energy() - theirs.get_potential_energy()) < 1e-13
        for a in (atoms, theirs):
            assert topological_charge(a) == pytest.approx(-1, abs=1e-9)
        assert np.abs(ase_spin.get_spins(atoms) - ase_spin.get_spins(theirs)).max() < 1e-4


def test_skyrmion_collapse_barrier_agrees_with_spirit(tmp_path, monkeypatch):
    """The collapse of an isolated skyrmion into the ferromagnet (periodic
    12 × 12 film), from the same geodesic band of 7 images: Spirit's GNEB
    (VP, climbing image) and ase_spin's GNEB find the same saddle point (energy
    and spins), so the same barrier; the bands' other images need not agree
    (the codes space them differently)."""
    import ase_spin
    from ase_spin.optimize import GNEB, SpinLBFGS
    from ase_spin.analysis import topological_charge
    from ase_spin.scenes import neel_skyrmion
    from spirit_peer import SpiritFilm

    monkeypatch.chdir(tmp_path)
    n = 12
    with SpiritFilm((n, n, 1), convergence_meV=1e-5, **FILM) as sc:
        skyrmion = sc.atoms(neel_skyrmion(sc.positions, 6.25))
        assert SpinLBFGS(skyrmion).run(fmax=1e-10)
        assert topological_charge(skyrmion) == pytest.approx(-1)
        ferromagnet = sc.atoms(np.tile([0.0, 0.0, 1.0], (n * n, 1)))
        band = GNEB([skyrmion] + [skyrmion.copy() for _ in range(5)] + [ferromagnet],
                    climb=True)
        band.interpolate()
        start = band.S.copy()
        assert band.run(fmax=1e-8, steps=3000)
        theirs = sc.gneb(start, climbing=True)
    E = np.array([sc.atoms(s).get_potential_energy() for s in theirs])
    top = int(np.argmax(E))
    ci = band.climbing_image
    assert 0 < top < len(E) - 1
    assert abs(E[top] - band.energies[ci]) < 1e-11
    assert np.abs(theirs[top] - band.S[ci]).max() < 1e-4
    assert band.barrier() == pytest.approx(E[top] - E[0], abs=1e-11)
    assert band.barrier() > 5e-3  # a real barrier (eV), not a flat path


def test_htst_prefactor_agrees_with_spirit(tmp_path, monkeypatch):
    """Harmonic transition-state theory for the reversal of an open chain of
    four spins (exchange, DMI, anisotropy; no field, where Spirit's velocity
    matrix is complete): the Hessians' eigenvalues at the minimum and the
    saddle and the prefactor agree with Spirit's HTST to its single
    precision."""
    import ase_spin
    from ase_spin.optimize import GNEB, HTST, SpinLBFGS
    from spirit_peer import SpiritFilm

    monkeypatch.chdir(tmp_path)
    with SpiritFilm((4, 1, 1), (False, False, False), **{**FILM, "field_T": 0.0}) as sc:
        ends = []
        for sz in (-1.0, 1.0):
            a = sc.atoms(np.tile([0.05, 0.02, sz], (4, 1)))
            assert SpinLBFGS(a).run(fmax=1e-13, steps=5000)
            ends.append(a)
        band = GNEB([ends[0]] + [ends[0].copy() for _ in range(5)] + [ends[1]], climb=True)
        band.interpolate()
        assert band.run(fmax=1e-13, steps=20000)
        saddle = band.images[band.climbing_image]
        ours = HTST(ends[0], saddle).rate()
        prefactor, modes_min, modes_sp = sc.htst(ase_spin.get_spins(ends[0]),
                                                 ase_spin.get_spins(saddle))
    assert ours.zero_modes == (0, 0)
    assert np.abs(ours.minimum_modes * 1e3 - modes_min).max() < 1e-6 * modes_min.max()
    assert np.abs(ours.saddle_modes * 1e3 - modes_sp).max() < 1e-6 * modes_sp.max()
    assert ours.prefactor() == pytest.approx(prefactor, rel=1e-6)
