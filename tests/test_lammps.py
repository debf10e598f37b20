"""Side by side with LAMMPS SPIN on the peers.md scene (skipped without lammps).

Run with the MPI library on the path, e.g.
``LD_LIBRARY_PATH=$VIRTUAL_ENV/lib pytest tests/test_lammps.py``.
"""

import numpy as np
import pytest
from ase.build import bulk

import ase_spin
from lammps_peer import LammpsSpin, lammps_available, lammps_calculator, mpiexec_path

from conftest import CO_BS, CO_LJ, cone_spins

pytestmark = pytest.mark.skipif(not lammps_available(), reason="lammps not importable")
_MPIEXEC = mpiexec_path()


@pytest.mark.parametrize("offset", [False, True])
def test_energy_forces_magnetic_forces_stress_agree_with_lammps(offset):
    rng = np.random.default_rng(5)
    atoms = bulk("Co", "fcc", a=3.54, cubic=True).repeat(4)
    atoms.rattle(0.06, seed=9)
    ase_spin.set_spins(atoms, cone_spins(len(atoms), rng), 1.72)
    atoms.calc = lammps_calculator([
        ase_spin.LennardJones(**CO_LJ, cutoff="shift"),
        ase_spin.Exchange(ase_spin.BetheSlater(*CO_BS), rc=4.0, offset=offset)])
    E = atoms.get_potential_energy()
    Eex = atoms.calc.results["energy_terms"]["exchange"]
    F, S = atoms.get_forces(), atoms.get_stress()
    B = atoms.calc.get_magnetic_forces(atoms)
    lmp = LammpsSpin(atoms, (CO_LJ["epsilon"], CO_LJ["sigma"], CO_LJ["rc"], True),
                     (*CO_BS, 4.0, offset))
    ref = lmp.evaluate()
    lmp.close()
    assert abs(E - ref["energy"]) < 1e-13 * abs(E)
    assert abs(Eex - ref["exchange"]) < 1e-13 * max(1.0, abs(Eex))
    assert np.abs(F - ref["forces"]).max() < 1e-12 * np.abs(F).max()
    assert np.abs(B - ref["magnetic_forces"]).max() < 1e-13 * np.abs(B).max()
    assert np.abs(S - ref["stress"]).max() < 1e-12 * np.abs(S).max()


def test_trajectory_converges_to_the_same_limit_as_lammps():
    """fcc Co (peers.md scene, moment convention, LAMMPS's ħ): both codes' final
    states approach the DOP853 solution at order 2, so they approach each other."""
    from ase import units

    from ase_spin.md.ode import reference_solution
    from ase_spin.scenes import fcc_cobalt

    hbar = ase_spin.HBAR_LAMMPS
    t_fs = 10.0
    xr, _, sr = reference_solution(fcc_cobalt(2, conventions="lammps"), t_fs * units.fs, hbar=hbar)
    rows = []
    for dt in (0.2, 0.1, 0.05):
        atoms = fcc_cobalt(2, conventions="lammps")
        ase_spin.CollectivePRK(atoms, dt * units.fs, hbar=hbar).run(int(round(t_fs / dt)))
        lmp = LammpsSpin(fcc_cobalt(2, conventions="lammps"), (CO_LJ["epsilon"], CO_LJ["sigma"], CO_LJ["rc"], True),
                         (*CO_BS, 4.0, False), timestep_fs=dt)
        lmp.run(int(round(t_fs / dt)))
        xl, _, sl = lmp.state()
        lmp.close()
        so = ase_spin.get_spins(atoms)
        rows.append((np.abs(so - sr).max(), np.abs(sl - sr).max(), np.abs(so - sl).max(),
                     np.abs(atoms.positions - xl).max()))
    rows = np.array(rows)
    assert np.all(rows[:, :3] > 1e-10)  # errors, not round-off
    for k in range(3):  # ours, LAMMPS and their difference: all fall as dt²
        ratios = rows[:-1, k] / rows[1:, k]
        assert np.all((ratios > 3.5) & (ratios < 4.5)), (k, rows)
    assert np.all(rows[1:, 3] < rows[:-1, 3])


def test_suzuki_trotter_follows_lammps_step_for_step():
    """The baseline with LAMMPS's rotation and ħ is LAMMPS's step. LAMMPS metal
    units convert force/mass to acceleration with 1/1.0364269e-4, 5.5e-8 off the
    CODATA value ASE uses: masses scaled by that ratio here, so only the
    algorithms are compared."""
    from ase import units

    from ase_spin.scenes import fcc_cobalt

    hbar = ase_spin.HBAR_LAMMPS
    ratio = (1000.0 * units.fs) ** 2 * 1.0364269e-4
    for lattice in ("moving", "frozen"):
        atoms = fcc_cobalt(3, conventions="lammps")
        velocities = atoms.get_velocities()
        atoms.set_masses(atoms.get_masses() * ratio)
        atoms.set_velocities(velocities)
        ase_spin.SuzukiTrotter(atoms, 0.1 * units.fs, hbar=hbar, lattice=lattice).run(100)
        lmp = LammpsSpin(fcc_cobalt(3, conventions="lammps"), (CO_LJ["epsilon"], CO_LJ["sigma"], CO_LJ["rc"], True),
                         (*CO_BS, 4.0, False), timestep_fs=0.1, lattice=lattice)
        lmp.run(100)
        x, v, s = lmp.state()
        lmp.close()
        assert np.abs(atoms.positions - x).max() < 1e-12
        assert np.abs(ase_spin.get_spins(atoms) - s).max() < 1e-12


def _spin_fix_scene(seed=5):
    """Rattled fcc Co, random spins, unequal moments: what fix precession/spin
    terms must match on (they scale with μ_i)."""
    rng = np.random.default_rng(seed)
    atoms = bulk("Co", "fcc", a=3.54, cubic=True).repeat(3)
    atoms.rattle(0.06, seed=9)
    ase_spin.set_spins(atoms, rng.normal(size=(len(atoms), 3)),
                       rng.uniform(0.8, 2.5, len(atoms)))
    return atoms


#: (ase_spin terms, the LAMMPS fix precession/spin arguments)
SPIN_FIXES = {
    "zeeman": (lambda: [ase_spin.Zeeman(12.5, [0.3, -0.4, 1.0])],
               "zeeman 12.5 0.3 -0.4 1.0"),
    "anisotropy": (lambda: [ase_spin.UniaxialAnisotropy(3e-3, [1.0, 0.5, -0.2])],
                   "anisotropy 0.003 1.0 0.5 -0.2"),
    "easy-plane+zeeman": (lambda: [ase_spin.Zeeman(4.0, [0, 0, 1]),
                                   ase_spin.UniaxialAnisotropy(-2e-3, [0, 0, 1])],
                          "zeeman 4.0 0 0 1 anisotropy -0.002 0 0 1"),
    "cubic": (lambda: [ase_spin.CubicAnisotropy(2e-3, 7e-3, [[1, 1, 0], [-1, 1, 0], [0, 0, 1]])],
              "cubic 0.002 0.007 1 1 0 -1 1 0 0 0 1"),
    "all": (lambda: [ase_spin.Zeeman(3.0, [1, 0, 0]),
                     ase_spin.UniaxialAnisotropy(1e-3, [0, 1, 1]),
                     ase_spin.CubicAnisotropy(-4e-3, 1e-3)],
            "zeeman 3.0 1 0 0 anisotropy 0.001 0 1 1 cubic -0.004 0.001 1 0 0 0 1 0 0 0 1"),
}


def _with_fixes(atoms, extra, **kw):
    atoms.calc = lammps_calculator([
        ase_spin.LennardJones(**CO_LJ, cutoff="shift"),
        ase_spin.Exchange(ase_spin.BetheSlater(*CO_BS), rc=4.0), *extra()])
    return atoms


def _lammps_with_fixes(atoms, args, **kw):
    return LammpsSpin(atoms, (CO_LJ["epsilon"], CO_LJ["sigma"], CO_LJ["rc"], True),
                      (*CO_BS, 4.0, False),
                      fixes=[f"fix 2 all precession/spin {args}", "fix_modify 2 energy yes"],
                      **kw)


@pytest.mark.parametrize("case", SPIN_FIXES)
def test_single_site_terms_agree_with_lammps(case):
    """Energy (LAMMPS pe with the fix's energy), the fix's own energy, forces,
    magnetic forces and stress at round-off, unequal moments."""
    extra, args = SPIN_FIXES[case]
    atoms = _with_fixes(_spin_fix_scene(), extra)
    E = atoms.get_potential_energy()
    terms = atoms.calc.results["energy_terms"]
    E_fix = sum(v for k, v in terms.items() if k not in ("lennard_jones", "exchange"))
    F, S = atoms.get_forces(), atoms.get_stress()
    B = atoms.calc.get_magnetic_forces(atoms)
    lmp = _lammps_with_fixes(atoms, args)
    ref = lmp.evaluate()
    lammps_fix_energy = lmp.lmp.extract_fix("2", 0, 0)
    lmp.close()
    assert abs(E - ref["energy"]) < 1e-14 * abs(E)
    assert abs(E_fix - lammps_fix_energy) < 1e-14 * max(1.0, abs(E_fix))
    assert np.abs(F - ref["forces"]).max() < 1e-12 * np.abs(F).max()
    assert np.abs(B - ref["magnetic_forces"]).max() < 1e-13 * np.abs(B).max()
    assert np.abs(S - ref["stress"]).max() < 1e-12 * np.abs(S).max()


@pytest.mark.parametrize("case", ["zeeman", "easy-plane+zeeman", "all"])
def test_suzuki_trotter_with_precession_fix_follows_lammps(case):
    """SuzukiTrotter on the per-spin-field path (exchange + single-site terms)
    with LAMMPS's ħ and rotation follows fix nve/spin with fix precession/spin
    step for step (masses scaled as in the exchange-only test)."""
    from ase import units

    from ase_spin.scenes import fcc_cobalt

    extra, args = SPIN_FIXES[case]
    hbar = ase_spin.HBAR_LAMMPS
    ratio = (1000.0 * units.fs) ** 2 * 1.0364269e-4
    for lattice in ("moving", "frozen"):
        atoms = _with_fixes(fcc_cobalt(3, conventions="lammps"), extra)
        velocities = atoms.get_velocities()
        atoms.set_masses(atoms.get_masses() * ratio)
        atoms.set_velocities(velocities)
        ase_spin.SuzukiTrotter(atoms, 0.1 * units.fs, hbar=hbar, lattice=lattice).run(100)
        lmp = _lammps_with_fixes(fcc_cobalt(3, conventions="lammps"), args, timestep_fs=0.1, lattice=lattice)
        lmp.run(100)
        x, v, s = lmp.state()
        lmp.close()
        assert np.abs(atoms.positions - x).max() < 1e-12
        assert np.abs(ase_spin.get_spins(atoms) - s).max() < 1e-12


#: (ase_spin spin pair term, the LAMMPS pair style and its pair_coeff line)
PAIR_TERMS = {
    "dmi": (lambda: ase_spin.DMI(3e-3, [0.3, -0.5, 1.0], rc=3.0),
            ("spin/dmi 3.0", ["pair_coeff * * spin/dmi dmi 3.0 0.003 "
                              + " ".join(repr(x) for x in (np.array([0.3, -0.5, 1.0])
                                                           / np.sqrt(1.34)).tolist())])),
    "neel": (lambda: ase_spin.Neel(ase_spin.BetheSlater(0.0048, 0.234, 1.168),
                                   ase_spin.BetheSlater(0.03, 0.705, 0.652), rc=3.0),
             ("spin/neel 3.0", ["pair_coeff * * spin/neel neel 3.0 0.0048 0.234 1.168 "
                                "0.03 0.705 0.652"])),
    "biquadratic": (lambda: ase_spin.BiquadraticExchange(
        ase_spin.BetheSlater(0.01, 0.2, 1.5), ase_spin.BetheSlater(0.004, -0.3, 1.3), rc=3.0),
        ("spin/exchange/biquadratic 3.0", ["pair_coeff * * spin/exchange/biquadratic "
                                           "biquadratic 3.0 0.01 0.2 1.5 0.004 -0.3 1.3"])),
    "biquadratic-offset": (lambda: ase_spin.BiquadraticExchange(
        ase_spin.BetheSlater(0.01, 0.2, 1.5), ase_spin.BetheSlater(0.004, -0.3, 1.3), rc=3.0,
        offset=True),
        ("spin/exchange/biquadratic 3.0", ["pair_coeff * * spin/exchange/biquadratic "
                                           "biquadratic 3.0 0.01 0.2 1.5 0.004 -0.3 1.3 "
                                           "offset yes"])),
    "dipolar-cut": (lambda: ase_spin.Dipolar(5.0, prefactor=ase_spin.DIPOLAR_LAMMPS),
                    ("spin/dipole/cut 5.0", ["pair_coeff * * spin/dipole/cut 5.0"])),
}


def _with_pair(atoms, make):
    atoms.calc = lammps_calculator([
        ase_spin.LennardJones(**CO_LJ, cutoff="shift"),
        ase_spin.Exchange(ase_spin.BetheSlater(*CO_BS), rc=4.0), make()])
    return atoms


def _lammps_with_pair(atoms, pair, **kw):
    lmp = LammpsSpin(atoms, (CO_LJ["epsilon"], CO_LJ["sigma"], CO_LJ["rc"], True),
                     (*CO_BS, 4.0, False), pairs=[pair], **kw)
    lmp.lmp.command(f"compute extra all pair {pair[0].split()[0]}")
    return lmp


@pytest.mark.parametrize("case", PAIR_TERMS)
def test_spin_pair_terms_agree_with_lammps(case):
    """The term's own energy (LAMMPS compute pair), total energy and magnetic
    forces at round-off with unequal moments; forces and stress too, except
    for DMI and Néel, whose mechanical forces in LAMMPS are not −∂E/∂r
    (docs/terms.md), and the stress of spin/dipole/cut, whose virial is not
    ∂E/∂ε."""
    make, pair = PAIR_TERMS[case]
    atoms = _with_pair(_spin_fix_scene(), make)
    E = atoms.get_potential_energy()
    name = atoms.calc.hamiltonian.term_names[-1]
    E_term = atoms.calc.results["energy_terms"][name]
    F, S = atoms.get_forces(), atoms.get_stress()
    B = atoms.calc.get_magnetic_forces(atoms)
    lmp = _lammps_with_pair(atoms, pair)
    ref = lmp.evaluate()
    lammps_term = lmp.lmp.numpy.extract_compute("extra", 0, 0)
    lmp.close()
    assert abs(E_term - lammps_term) < 1e-13 * max(1.0, abs(E_term))
    assert abs(E - ref["energy"]) < 1e-13 * abs(E)
    assert np.abs(B - ref["magnetic_forces"]).max() < 1e-13 * np.abs(B).max()
    if case not in ("dmi", "neel"):
        assert np.abs(F - ref["forces"]).max() < 1e-12 * np.abs(F).max()
    if case not in ("dmi", "neel", "dipolar-cut"):
        assert np.abs(S - ref["stress"]).max() < 1e-12 * np.abs(S).max()


def test_neel_forces_are_the_derivative_of_lammps_neel_energy():
    """LAMMPS's spin/neel lattice force is not −∂E/∂r of its own energy; ours
    is: central differences of LAMMPS's energy give our force to ~1e-9 eV/Å
    while LAMMPS's own force differs by ~2e-5 eV/Å (measured)."""
    make, pair = PAIR_TERMS["neel"]
    atoms = _with_pair(_spin_fix_scene(), make)
    F = atoms.get_forces()
    h = 1e-5
    for a, x in ((0, 0), (7, 2)):
        energies = []
        for sign in (1.0, -1.0):
            moved = atoms.copy()
            moved.positions[a, x] += sign * h
            lmp = _lammps_with_pair(moved, pair)
            energies.append(lmp.evaluate()["energy"])
            lmp.close()
        assert abs(F[a, x] + (energies[0] - energies[1]) / (2 * h)) < 1e-8


@pytest.mark.parametrize("case, lattice", [("dmi", "frozen"), ("biquadratic", "moving"),
                                           ("biquadratic", "frozen"), ("dipolar-cut", "moving")])
def test_suzuki_trotter_with_spin_pair_terms_follows_lammps(case, lattice):
    """SuzukiTrotter with exchange + DMI, biquadratic exchange or spin/dipole/cut
    follows fix nve/spin step for step (DMI on a frozen lattice only: LAMMPS's DMI lattice
    forces differ from −∂E/∂r)."""
    from ase import units

    from ase_spin.scenes import fcc_cobalt

    make, pair = PAIR_TERMS[case]
    hbar = ase_spin.HBAR_LAMMPS
    ratio = (1000.0 * units.fs) ** 2 * 1.0364269e-4
    atoms = _with_pair(fcc_cobalt(3, conventions="lammps"), make)
    velocities = atoms.get_velocities()
    atoms.set_masses(atoms.get_masses() * ratio)
    atoms.set_velocities(velocities)
    ase_spin.SuzukiTrotter(atoms, 0.1 * units.fs, hbar=hbar, lattice=lattice).run(100)
    lmp = _lammps_with_pair(fcc_cobalt(3, conventions="lammps"), pair, timestep_fs=0.1, lattice=lattice)
    lmp.run(100)
    x, v, s = lmp.state()
    lmp.close()
    assert np.abs(atoms.positions - x).max() < 1e-12
    assert np.abs(ase_spin.get_spins(atoms) - s).max() < 1e-12


def _largest_torque(atoms):
    B = atoms.calc.get_magnetic_forces(atoms)
    return np.linalg.norm(np.cross(ase_spin.get_spins(atoms), B), axis=1).max()


def _open_film():
    """An 8 × 8 DMI film with open edges (periodic along z only), spins in a
    60° cone: its minimum is the ferromagnet with the edge spins canted by the
    DMI, a non-collinear and well-conditioned minimum (field and anisotropy)."""
    from ase_spin.scenes import cone, dmi_film

    atoms = dmi_film(8, spins=cone(64, np.random.default_rng(1), 60.0))
    atoms.pbc = [False, False, True]
    return atoms


@pytest.mark.parametrize("style", ["spin/lbfgs", "spin"])
def test_spin_minimisers_reach_the_lammps_minimum(style):
    """Exchange + DMI + anisotropy + Zeeman on a frozen lattice, written for
    LAMMPS by write_lammps: LAMMPS's min_style spin/lbfgs (LBFGS-OSO) and spin
    (damped precession) and ase_spin's SpinLBFGS and SpinVP stop at the same
    minimum (torques ≤ 1e-10 eV under both codes' criterion, the same max
    |s × B| in eV)."""
    from lammps_peer import lammps_minimise

    from ase_spin.optimize import SpinLBFGS, SpinVP

    ref = lammps_minimise(_open_film(), style, ftol=1e-10)
    assert ref.criterion == "force tolerance"
    theirs = _open_film()
    ase_spin.set_spins(theirs, ref.spins, magnitudes=2.2)
    assert _largest_torque(theirs) < 1e-9  # LAMMPS tests the fields before its last step
    E_theirs = theirs.get_potential_energy()
    assert abs(E_theirs - ref.energy) < 1e-13  # one Hamiltonian in both codes
    assert ase_spin.get_spins(theirs)[:, 2].min() < 0.8  # canted edges: not collinear
    for Opt in (SpinLBFGS, SpinVP):
        atoms = _open_film()
        assert Opt(atoms).run(fmax=1e-10, steps=5000)
        assert abs(atoms.get_potential_energy() - E_theirs) < 1e-13
        assert np.abs(ase_spin.get_spins(atoms) - ref.spins).max() < 1e-6


def test_skyrmion_minimum_agrees_with_lammps():
    """A periodic 12 × 12 DMI film from a Néel skyrmion profile: LAMMPS's
    spin/lbfgs and SpinLBFGS, both to 1e-12 eV, relax it to the same isolated
    skyrmion (Q = −1, the same energy and spins). Its translation on the
    lattice is a very soft mode, so the spins agree only as far as τ/κ along
    it."""
    from lammps_peer import lammps_minimise

    from ase_spin.optimize import SpinLBFGS
    from ase_spin.analysis import topological_charge
    from ase_spin.scenes import dmi_film, neel_skyrmion

    def scene():
        atoms = dmi_film(12)
        ase_spin.set_spins(atoms, neel_skyrmion(atoms.positions, 6.25), magnitudes=2.2)
        return atoms

    ref = lammps_minimise(scene(), "spin/lbfgs", ftol=1e-12)
    atoms = scene()
    assert SpinLBFGS(atoms).run(fmax=1e-12, steps=2000)
    assert topological_charge(atoms, ref.spins) == pytest.approx(-1.0, abs=1e-9)
    assert topological_charge(atoms) == pytest.approx(-1.0, abs=1e-9)
    assert abs(atoms.get_potential_energy() - ref.energy) < 1e-13
    assert np.abs(ase_spin.get_spins(atoms) - ref.spins).max() < 1e-5


def _chain(sz, n=4, field=5.0, psi_deg=30.0, D=0.0, J=0.010, K=0.001, a=2.5):
    """An open chain of n spins along x (2.2 μB, spacing a): nearest-neighbour
    exchange J (Bethe–Slater, J(a) = J), interfacial DMI D (D_ij = D e_ij × ẑ),
    uniaxial anisotropy K along z, a field (T) at ψ from z in the xz plane;
    spins near ±z (``sz``), relaxed to 1e-13 eV. Strong exchange (J ≫ K) keeps
    the chain's reversal coherent without DMI: a macrospin of n·K."""
    from ase import Atoms

    from ase_spin.optimize import SpinLBFGS

    atoms = Atoms(f"Fe{n}", positions=[[i * a, 0.0, 0.0] for i in range(n)],
                  cell=[n * a + 10.0, 10.0, 10.0], pbc=[False, True, True])
    ase_spin.set_spins(atoms, np.tile([0.05, 0.02, sz], (n, 1)), magnitudes=2.2)
    psi, rc = np.radians(psi_deg), 1.2 * a
    terms = [ase_spin.Exchange(ase_spin.BetheSlater(J * np.e / 4.0, 0.0, a), rc=rc),
             ase_spin.UniaxialAnisotropy(K, [0.0, 0.0, 1.0]),
             ase_spin.Zeeman(field, [np.sin(psi), 0.0, np.cos(psi)])]
    if D:
        terms.append(ase_spin.DMI(D, [0.0, 0.0, 1.0], rc=rc))
    atoms.calc = ase_spin.SpinLatticeCalculator(terms)
    assert SpinLBFGS(atoms).run(fmax=1e-13, steps=5000)
    return atoms


def _chain_band(images, **scene):
    """The geodesic band between the chain's metastable state (near −z, first)
    and its ground state (near +z), as ase_spin's GNEB interpolates it."""
    from ase_spin.optimize import GNEB

    first, last = _chain(-1.0, **scene), _chain(1.0, **scene)
    band = GNEB([first] + [first.copy() for _ in range(images - 2)] + [last], climb=True)
    band.interpolate()
    return band


def _stoner_wohlfarth_barrier(n=4, field=5.0, psi_deg=30.0, K=0.001, mu=2.2):
    """n × the macrospin barrier from its metastable minimum: E(θ) = −K cos²θ
    − μ μB H cos(θ − ψ), the highest point between the minima near θ = π and 0."""
    from scipy.optimize import minimize_scalar

    psi, muH = np.radians(psi_deg), mu * ase_spin.MU_B * field

    def E(t):
        return -K * np.cos(t) ** 2 - muH * np.cos(t - psi)

    opts = {"xatol": 1e-13}
    low = minimize_scalar(E, bounds=(np.pi / 2, 3 * np.pi / 2), method="bounded", options=opts)
    top = minimize_scalar(lambda t: -E(t), bounds=(0.0, np.pi), method="bounded",
                          options=opts)
    return n * (E(top.x) - low.fun)


@pytest.mark.skipif(_MPIEXEC is None, reason="no mpiexec")
def test_gneb_barrier_agrees_with_lammps_neb_spin():
    """An open chain of four spins (exchange, anisotropy, a field at 30° to
    the easy axis) reversing from its metastable state, from the same
    geodesic band of three images: LAMMPS's neb/spin (min_style spin,
    climbing image; discrete_factor 4, the largest stable step: 2 diverges)
    and ase_spin's GNEB, both to a GNEB force of 1e-9 eV (the largest row,
    both codes' criterion), stop at the same saddle, and the barrier is the
    macrospin's Stoner–Wohlfarth barrier of 4K. A residual force g leaves the
    saddle energy off by about N g²/(2|λ|) and the spins by √N g/|λ|, λ ≈
    1e-3 eV/rad² the softest curvature there: bounds of 1e-12 eV and 1e-5."""
    from lammps_peer import lammps_neb

    band = _chain_band(3)
    theirs = lammps_neb(band.images, ftol=1e-9, steps=(100, 2000), every=50,
                        modify=["min_modify discrete_factor 4.0"])
    assert theirs.criteria == ["force tolerance", "force tolerance"]
    assert theirs.climbing == 1
    assert band.run(fmax=1e-9, steps=20000)
    ci = band.climbing_image
    assert ci == 1
    # LAMMPS's saddle, evaluated by ase_spin (one Hamiltonian in both codes)
    saddle = band.images[0].copy()
    saddle.calc = band.images[0].calc
    ase_spin.set_spins(saddle, theirs.spins[ci], magnitudes=2.2)
    assert abs(saddle.get_potential_energy() - band.energies[ci]) < 1e-12
    assert np.abs(theirs.spins[ci] - band.S[ci]).max() < 1e-5
    assert np.abs(theirs.spins[[0, -1]] - band.S[[0, -1]]).max() < 1e-9  # the ends stay
    # what neb/spin prints (8 significant digits)
    assert theirs.barrier == pytest.approx(band.barrier(), rel=1e-7)
    assert theirs.energies == pytest.approx(band.energies, rel=1e-7)
    # both are the macrospin's: the reversal is coherent
    assert band.barrier() == pytest.approx(_stoner_wohlfarth_barrier(), rel=1e-10)
    assert np.abs(band.S[ci] - band.S[ci][0]).max() < 1e-6


@pytest.mark.slow
@pytest.mark.skipif(_MPIEXEC is None, reason="no mpiexec")
def test_gneb_band_agrees_with_lammps_neb_spin_with_dmi():
    """Six spins with DMI (3 meV; the chain cants, the reversal is no longer
    coherent), five images, LAMMPS's own settings (discrete_factor 10):
    every image of both bands agrees (the non-climbing ones are placed by the
    springs, k/ħ in LAMMPS's units), the saddle's energy to the bound of the
    test above."""
    from lammps_peer import lammps_neb

    band = _chain_band(5, n=6, D=0.003)
    theirs = lammps_neb(band.images, ftol=1e-9, steps=(2000, 20000), every=100)
    assert theirs.criteria == ["force tolerance", "force tolerance"]
    assert band.run(fmax=1e-9, steps=20000)
    ci = band.climbing_image
    assert theirs.climbing == ci
    atoms = band.images[0].copy()
    atoms.calc = band.images[0].calc
    E = []
    for s in theirs.spins:
        ase_spin.set_spins(atoms, s, magnitudes=2.2)
        E.append(atoms.get_potential_energy())
    assert abs(E[ci] - band.energies[ci]) < 1e-12
    assert np.abs(np.array(E) - band.energies).max() < 1e-9
    assert np.abs(theirs.spins - band.S).max() < 1e-5
    assert np.ptp(band.S[ci][:, 0]) > 0.01  # not coherent
    assert theirs.barrier == pytest.approx(band.barrier(), rel=1e-6)


@pytest.mark.slow
@pytest.mark.skipif(_MPIEXEC is None, reason="no mpiexec")
def test_skyrmion_collapse_barrier_agrees_with_lammps_neb_spin():
    """The collapse of the periodic 12 × 12 film's skyrmion into the
    ferromagnet (the scene of test_spirit.py's GNEB check), seven images from
    the same geodesic band, both codes to 1e-7 eV: the same saddle (a
    stationary point with soft translations of the collapsing core, so the
    spins agree to 1e-4 only, its energy to 1e-10 eV) and barrier."""
    from lammps_peer import lammps_neb

    from ase_spin.optimize import GNEB, SpinLBFGS
    from ase_spin.scenes import dmi_film, neel_skyrmion

    skyrmion = dmi_film(12)
    ase_spin.set_spins(skyrmion, neel_skyrmion(skyrmion.positions, 6.25), magnitudes=2.2)
    assert SpinLBFGS(skyrmion).run(fmax=1e-10)
    band = GNEB([skyrmion] + [skyrmion.copy() for _ in range(5)] + [dmi_film(12)], climb=True)
    band.interpolate()
    theirs = lammps_neb(band.images, ftol=1e-7, steps=(2000, 20000), every=100, timeout=1800)
    assert theirs.criteria == ["force tolerance", "force tolerance"]
    assert band.run(fmax=1e-7, steps=5000)
    ci = band.climbing_image
    assert theirs.climbing == ci
    saddle = band.images[0].copy()
    saddle.calc = band.images[0].calc
    ase_spin.set_spins(saddle, theirs.spins[ci], magnitudes=2.2)
    assert abs(saddle.get_potential_energy() - band.energies[ci]) < 1e-10
    assert np.abs(theirs.spins[ci] - band.S[ci]).max() < 1e-4
    assert theirs.barrier == pytest.approx(band.barrier(), rel=1e-6)
    assert band.barrier() > 5e-3
