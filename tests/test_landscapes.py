"""Energy landscapes (ase_spin.optimize): the minimisers, the spin–lattice
filter for ASE's optimizers and the geodesic nudged elastic band, against the
Stoner–Wohlfarth macrospin (minima, saddle, barrier K(1 − h)², the astroid),
against relax_spins on a film, and by finite differences."""

import numpy as np
import pytest
from ase import Atoms
from ase.constraints import FixAtoms
from ase.io import read
from ase.optimize import BFGS

import ase_spin
from ase_spin import (DMI, MU_B, Cubic, Exchange, FixSpins, SpinLatticeCalculator,
                      UniaxialAnisotropy, Zeeman, get_spins, relax_spins)
from ase_spin.optimize import GNEB, SpinLBFGS, SpinVP, sphere
from ase_spin.optimize.filter import SpinLatticeFilter, rotation_jacobian
from ase_spin.scenes import cone, fcc_cobalt

K, MU = 1e-3, 2.0  # eV, μB


def macrospin(h, psi=0.0, s=(0.1, 0.0, -1.0)):
    """One moment μ with E = −K s_z² − μ μB H s·ĥ, the field at ψ from the easy
    axis z in the xz plane, reduced field h = μ μB H/(2K)."""
    a = Atoms("Fe", positions=[[0.0, 0.0, 0.0]])
    ase_spin.set_spins(a, np.array(s, float), magnitudes=MU)
    H = 2 * K * h / (MU * MU_B)
    a.calc = SpinLatticeCalculator([UniaxialAnisotropy(K, [0, 0, 1]),
                                    Zeeman(H, [np.sin(psi), 0.0, np.cos(psi)])])
    return a


def film(n=8, seed=0, cone_deg=60.0):
    """A square monolayer with exchange, interfacial DMI, anisotropy and a field."""
    a = 2.5
    ij = np.array([(i, j) for j in range(n) for i in range(n)], dtype=float)
    atoms = Atoms(f"Fe{n * n}", positions=np.column_stack([ij * a, np.zeros(n * n)]),
                  cell=[n * a, n * a, 10.0], pbc=[True, True, False])
    J0 = 0.010 / (1.0 - a / 3.0) ** 3
    ase_spin.set_spins(atoms, cone(n * n, np.random.default_rng(seed), cone_deg),
                       magnitudes=2.2)
    atoms.calc = SpinLatticeCalculator([Exchange(Cubic(J0, 3.0)), DMI(0.003, [0, 0, 1], rc=3.0),
                                        UniaxialAnisotropy(0.0005, [0, 0, 1]),
                                        Zeeman(1.0, [0, 0, 1])])
    return atoms


def torque(atoms):
    B = atoms.calc.get_magnetic_forces(atoms)
    return np.linalg.norm(np.cross(get_spins(atoms), B), axis=1)


@pytest.mark.parametrize("Opt", [SpinLBFGS, SpinVP])
def test_stoner_wohlfarth_minima(Opt):
    """From near −z the spin stops at the metastable minimum s = −z with
    E = −K + 2Kh, from near +z at the ground state E = −K − 2Kh."""
    h = 0.3
    for start, sign in (((0.2, 0.1, -1.0), -1), ((0.2, -0.1, 1.0), 1)):
        a = macrospin(h, s=start)
        opt = Opt(a)
        assert opt.run(fmax=1e-12, steps=500)
        assert get_spins(a)[0] == pytest.approx([0, 0, sign], abs=1e-9)
        assert a.get_potential_energy() == pytest.approx(-K - sign * 2 * K * h, abs=1e-15)
        assert torque(a).max() <= 1e-12


@pytest.mark.parametrize("h,switches", [(0.47, False), (0.53, True)])
def test_astroid_switching_field(h, switches):
    """A field at ψ = 45° to the easy axis: the reversed state survives below
    the astroid's h_sw = (cos^⅔ψ + sin^⅔ψ)^(−3/2) = ½ and is gone above it."""
    psi = np.pi / 4
    h_sw = (np.cos(psi) ** (2 / 3) + np.sin(psi) ** (2 / 3)) ** -1.5
    assert h_sw == pytest.approx(0.5)
    a = macrospin(h, psi, s=(0.0, 0.0, -1.0))
    assert SpinLBFGS(a).run(fmax=1e-10, steps=2000)
    s = get_spins(a)[0]
    field = np.array([np.sin(psi), 0.0, np.cos(psi)])
    assert (s @ field > 0.0) == switches
    # the minimum of E(θ) = −K cos²θ − 2Kh cos(θ − ψ) in the field's plane
    theta = np.arctan2(s[0], s[2])
    dE = 2 * K * np.sin(theta) * np.cos(theta) + 2 * K * h * np.sin(theta - psi)
    assert abs(s[1]) < 1e-9 and abs(dE) < 1e-9


def _band(h, psi=0.0, images=9, climb=True):
    a, b = macrospin(h, psi, s=(0.1, 0.0, -1.0)), macrospin(h, psi, s=(0.1, 0.0, 1.0))
    for x in (a, b):
        SpinLBFGS(x).run(fmax=1e-12, steps=500)
    band = GNEB([a] + [a.copy() for _ in range(images - 2)] + [b], climb=climb)
    band.interpolate()
    return band


def test_gneb_stoner_wohlfarth_barrier():
    """The barrier from the reversed state is K(1 − h)², the climbing image
    sits at the saddle (cos θ = −h, E = K h²) and is the path's maximum."""
    h = 0.3
    band = _band(h)
    assert band.run(fmax=1e-9, steps=3000)
    ci = band.climbing_image
    s = band.S[ci][0]
    assert s[2] == pytest.approx(-h, abs=1e-6)
    assert band.energies[ci] == pytest.approx(K * h**2, abs=1e-12)
    assert band.barrier() == pytest.approx(K * (1 - h) ** 2, rel=1e-8)
    assert band.barrier(reverse=True) == pytest.approx(K * (1 + h) ** 2, rel=1e-8)
    R, E = band.path()
    assert E.max() == pytest.approx(band.energies[ci], abs=1e-12)
    assert band.saddle()[1] == pytest.approx(band.energies[ci], abs=1e-12)
    # the images' Atoms hold the band
    assert np.allclose(get_spins(band.images[ci])[0], s)


def test_gneb_field_at_an_angle():
    """ψ = 30°, h = 0.25: the climbing image reaches the highest point of
    E(θ) on the arc between the two minima (in the field's plane)."""
    h, psi = 0.25, np.radians(30.0)
    band = _band(h, psi, images=11)
    assert band.run(fmax=1e-9, steps=5000)
    theta = np.unwrap([np.arctan2(s[0][0], s[0][2]) for s in band.S])
    grid = np.linspace(theta[0], theta[-1], 200001)
    E = -K * np.cos(grid) ** 2 - 2 * K * h * np.cos(grid - psi)
    assert band.barrier() == pytest.approx(E.max() - E[0], rel=1e-7)
    assert np.abs(band.S[:, 0, 1]).max() < 1e-8  # the path stays in the plane


def test_gneb_without_climbing_stays_below_the_saddle():
    h = 0.3
    band = _band(h, images=6, climb=False)
    assert band.climbing_image is None
    assert band.run(fmax=1e-8, steps=3000)
    assert band.energies.max() < K * h**2
    # the Hermite interpolation's maximum is close to the true one
    assert band.saddle()[1] == pytest.approx(K * h**2, rel=0.05)
    d = band.distances()
    assert d.max() - d.min() < 1e-6 * d.mean()  # springs: equal spacing


def test_minimisers_agree_with_relax_spins_in_far_fewer_evaluations():
    """A DMI film: LBFGS-OSO and VP reach relax_spins's minimum (energy and
    spins), in far fewer evaluations than damped precession takes steps."""
    ref = film()
    steps = relax_spins(ref, fmax=1e-9)
    E_ref, s_ref = ref.get_potential_energy(), get_spins(ref)
    for Opt, most in ((SpinLBFGS, steps // 10), (SpinVP, steps // 3)):
        a = film()
        opt = Opt(a)
        assert opt.run(fmax=1e-9, steps=most)
        assert opt.evaluations == opt.nsteps + 1
        assert a.get_potential_energy() == pytest.approx(E_ref, abs=1e-12)
        assert np.abs(get_spins(a) - s_ref).max() < 1e-5
        assert torque(a).max() <= 1e-9


def test_pinned_spins_and_observers(tmp_path):
    """FixSpins holds its spins bitwise; observers and the trajectory see the
    spins after each step with their energy; an existing trajectory is not
    overwritten; bad input is refused."""
    a = film(n=6)
    a.set_constraint(FixSpins([0, 5]))
    before = a.arrays["initial_magmoms"][[0, 5]].copy()
    seen = []
    opt = SpinLBFGS(a, trajectory=tmp_path / "opt.traj", logfile=tmp_path / "opt.log")
    opt.attach(lambda: seen.append(a.get_potential_energy()))
    assert opt.run(fmax=1e-8, steps=500)
    assert np.array_equal(a.arrays["initial_magmoms"][[0, 5]], before)
    t = torque(a)
    assert t[[0, 5]].max() > 1e-4 and np.delete(t, [0, 5]).max() <= 1e-8
    frames = read(tmp_path / "opt.traj", ":")
    assert len(frames) == len(seen) == opt.nsteps + 1
    assert frames[-1].get_potential_energy() == pytest.approx(seen[-1], abs=0)
    assert np.array_equal(frames[-1].arrays["initial_magmoms"], a.arrays["initial_magmoms"])
    assert len((tmp_path / "opt.log").read_text().splitlines()) == opt.nsteps + 2
    with pytest.raises(FileExistsError):
        SpinLBFGS(a, trajectory=tmp_path / "opt.traj")
    with pytest.raises(ValueError, match="fmax"):
        opt.run(fmax=-1.0)
    with pytest.raises(ValueError, match="maxmove"):
        SpinVP(a, maxmove=0.0)
    a.calc = None
    with pytest.raises(TypeError, match="SpinLatticeCalculator"):
        SpinLBFGS(a)


def test_minimiser_notices_changed_atoms():
    """Spins set between runs are taken up: the run starts from them."""
    a = macrospin(0.3)
    opt = SpinLBFGS(a)
    assert opt.run(fmax=1e-10)
    ase_spin.set_spins(a, [0.1, 0.0, 1.0])
    assert opt.run(fmax=1e-10)
    assert get_spins(a)[0] == pytest.approx([0, 0, 1], abs=1e-9)


def test_geodesic_helpers():
    rng = np.random.default_rng(3)
    a = sphere.rotate(np.tile([0.0, 0.0, 1.0], (50, 1)), rng.normal(size=(50, 3)))
    b = sphere.rotate(a, rng.normal(size=(50, 3)))
    for t in (0.0, 0.3, 1.0):
        s = sphere.slerp(a, b, t)
        assert np.allclose(sphere.angles(a, s), t * sphere.angles(a, b), atol=1e-12)
        assert np.allclose(sphere.norms(s), 1.0, atol=1e-15)
    assert np.allclose(sphere.slerp(a, b, 1.0), b, atol=1e-12)
    half = sphere.slerp(a, -a, 0.5)  # antiparallel: a quarter turn about some ⟂ axis
    assert np.allclose(sphere.dot(half, a), 0.0, atol=1e-12)


def test_filter_forces_are_minus_the_gradient():
    """The filter's spin rows are −∂E/∂φ (central differences at φ ≠ 0), and
    its fmax reads them back as torques."""
    a = fcc_cobalt(1, temperature_K=0.0, cone_deg=60.0,
                   extra=[UniaxialAnisotropy(0.01, [1, 0, 0])])
    f = SpinLatticeFilter(a)
    x = f.get_positions()
    x[4:] += np.random.default_rng(1).normal(scale=0.7, size=(4, 3))
    f.set_positions(x)
    F = f.get_forces()
    eps = 1e-5
    for row in (0, 5, 7):
        for c in range(3):
            xp, xm = x.copy(), x.copy()
            xp[row, c] += eps
            xm[row, c] -= eps
            f.set_positions(xp)
            ep = f.get_potential_energy()
            f.set_positions(xm)
            em = f.get_potential_energy()
            assert F[row, c] == pytest.approx(-(ep - em) / (2 * eps), abs=1e-7)
    f.set_positions(x)
    J = rotation_jacobian(f.phi)
    assert np.allclose(np.einsum("nji,nj->ni", J, f.torques()), F[4:])
    assert np.allclose(f.spin_rows_as_torques(F[4:]), sphere.norms(f.torques()))


def test_joint_spin_lattice_relaxation_with_ase_optimizers():
    """fcc Co with LJ, distance-dependent exchange and anisotropy, rattled,
    spins in a 70° cone: BFGS on the filter reaches forces and torques below
    fmax, lower than relaxing the spins alone or the lattice alone; FixAtoms
    holds its atom."""
    def scene():
        a = fcc_cobalt(1, temperature_K=0.0, cone_deg=70.0,
                       extra=[UniaxialAnisotropy(0.01, [1, 0, 0])])
        a.rattle(0.05, seed=1)
        return a

    spins_only, lattice_only = scene(), scene()
    SpinLBFGS(spins_only).run(fmax=1e-6)
    BFGS(lattice_only, logfile=None).run(fmax=1e-4)
    a = scene()
    a.set_constraint(FixAtoms([0]))
    p0 = a.positions[0].copy()
    assert BFGS(SpinLatticeFilter(a), logfile=None).run(fmax=1e-4, steps=500)
    assert np.abs(a.get_forces()).max() < 1e-4 and torque(a).max() < 1e-4
    assert np.array_equal(a.positions[0], p0)
    E = a.get_potential_energy()
    assert E < spins_only.get_potential_energy() - 0.1
    assert E < lattice_only.get_potential_energy() - 0.1


def test_spin_lattice_band():
    """A band whose images carry positions: a dimer with distance-dependent
    exchange, one spin pinned up, the other turning from up to down against
    a strong anisotropy. The bond length differs between the two states
    (magnetostriction) and changes along the path; the end images stay, the
    climbing image's GNEB force vanishes, FixAtoms holds its atom."""
    from ase_spin import BetheSlater, LennardJones

    def dimer(sz):
        a = Atoms("Fe2", positions=[[0, 0, 0], [2.45, 0.1, 0.0]])
        ase_spin.set_spins(a, [[0.0, 0, 1.0], [0.1, 0.05, sz]], magnitudes=2.0)
        a.calc = SpinLatticeCalculator([
            LennardJones(epsilon=0.4, sigma=2.2742, rc=4.7, cutoff="shift"),
            Exchange(BetheSlater(J1=0.0446928, J2=0.003496, J3=1.4885), rc=4.0),
            UniaxialAnisotropy(0.05, [0, 0, 1])])
        a.set_constraint([FixAtoms([0]), FixSpins([0])])
        return a

    ends = []
    for sz in (1.0, -1.0):
        a = dimer(sz)
        assert BFGS(SpinLatticeFilter(a), logfile=None).run(fmax=1e-6, steps=1000)
        ends.append(a)
    assert get_spins(ends[1])[1, 2] < -0.99
    d = [a.get_distance(0, 1) for a in ends]
    assert abs(d[0] - d[1]) > 1e-3  # the bond length depends on the spin order
    images = [ends[0]] + [ends[0].copy() for _ in range(5)] + [ends[1]]
    band = GNEB(images, climb=True, lattice=True)
    band.interpolate()
    e_ends = band.energies[[0, -1]].copy()
    assert band.run(fmax=1e-5, steps=5000)
    assert np.array_equal(band.energies[[0, -1]], e_ends)
    assert band.fmax() <= 1e-5
    ci = band.climbing_image
    assert np.array_equal(band.Q[ci][0], ends[0].positions[0])  # FixAtoms
    assert band.barrier() > 0.0
    r = np.linalg.norm(band.Q[:, 1] - band.Q[:, 0], axis=1)
    straight = d[0] + (d[1] - d[0]) * band.reaction_coordinate() / band.reaction_coordinate()[-1]
    assert np.abs(r - straight).max() > 1e-4  # not the linear interpolation: relaxed
    assert band.images[ci].get_distance(0, 1) == pytest.approx(r[ci])


def test_htst_macrospin_prefactor_is_the_resonance_frequency():
    """Stoner–Wohlfarth with the field at 30° (h = 0.25): the HTST prefactor
    of the escape from the reversed state is ω₀/2π, ω₀ = (g/μħ)·√(E_θθ E_φφ)
    the resonance frequency at the minimum (the curvatures in the field's plane,
    E_θθ = 2K cos 2θ + 2Kh cos(θ − ψ), and out of it, E_φφ = 2K cos²θ +
    2Kh cos(θ − ψ)); the barrier is the band's; k = ν e^{−ΔE/k_BT}."""
    from ase import units

    from ase_spin.optimize import HTST

    h, psi = 0.25, np.radians(30.0)
    band = _band(h, psi, images=11)
    assert band.run(fmax=1e-10, steps=5000)
    res = HTST(band.images[0], band.images[band.climbing_image]).rate()
    assert res.zero_modes == (0, 0)
    assert res.barrier == pytest.approx(band.barrier(), rel=1e-9)
    assert res.saddle_modes[0] < 0.0 < res.saddle_modes[1]
    s = get_spins(band.images[0])[0]
    theta = np.arctan2(s[0], s[2])
    curvatures = (2 * K * np.cos(2 * theta) + 2 * K * h * np.cos(theta - psi),
                  2 * K * np.cos(theta) ** 2 + 2 * K * h * np.cos(theta - psi))
    assert np.sort(res.minimum_modes) == pytest.approx(np.sort(curvatures), rel=1e-8)
    conv = band.images[0].calc.hamiltonian.conventions
    omega = np.sqrt(np.prod(curvatures)) * conv.g / MU / conv.hbar  # rad per ASE time
    assert res.prefactor() == pytest.approx(omega / (2 * np.pi) * units.s, rel=1e-9)
    T = 20.0
    assert res.rate(T) == pytest.approx(res.prefactor() * np.exp(-res.barrier / (units.kB * T)),
                                        rel=1e-12)


def test_htst_zero_modes_and_bad_saddles():
    """The field along the easy axis: the saddle is a circle (a zero mode),
    which needs its volume; its only stable mode is that zero mode, so the
    precession carries no flux over the saddle (k = 0: the axial component is
    conserved). A minimum given as the saddle is refused."""
    from ase_spin.optimize import HTST

    h = 0.3
    band = _band(h, images=9)
    assert band.run(fmax=1e-10, steps=3000)
    saddle = band.images[band.climbing_image]
    htst = HTST(band.images[0], saddle)
    with pytest.raises(ValueError, match="zero modes"):
        htst.rate()
    sin_theta = np.sqrt(1 - h**2)
    res = htst.rate(volumes=(1.0, 2 * np.pi * sin_theta))
    assert res.zero_modes == (0, 1)
    assert res.rate(50.0) == 0.0
    with pytest.raises(ValueError, match="temperature"):
        res.prefactor()
    with pytest.raises(ValueError, match="negative curvatures"):
        HTST(band.images[0], band.images[0]).rate()
    top = macrospin(h, s=get_spins(saddle)[0])
    with pytest.raises(ValueError, match="negative curvatures"):
        HTST(top, saddle).rate(volumes=(1.0, 1.0))
    off = saddle.copy()
    off.arrays["initial_magmoms"] = MU * sphere.rotate(get_spins(saddle), [[1e-3, 0.0, 0.0]])
    with pytest.raises(ValueError, match="saddle's largest torque"):
        HTST(band.images[0], off).rate(volumes=(1.0, 1.0))


def test_dmi_film_holds_a_metastable_skyrmion():
    """The scene of the comparisons and the example: the ferromagnet is a
    stationary state; the Néel profile of the chirality the DMI favours (χ = +1
    has the lower DMI energy) relaxes to a skyrmion (Q = −1) above the
    ferromagnet."""
    from ase_spin.analysis import topological_charge
    from ase_spin.scenes import dmi_film, neel_skyrmion

    n = 12
    fm = dmi_film(n)
    assert torque(fm).max() == 0.0 and topological_charge(fm) == 0.0
    dmi = {}
    for chi in (1, -1):
        a = dmi_film(n)
        ase_spin.set_spins(a, neel_skyrmion(a.positions, 6.25, chirality=chi), magnitudes=2.2)
        a.get_potential_energy()
        dmi[chi] = a.calc.results["energy_terms"]["dmi"]
    assert dmi[1] < 0.0 < dmi[-1]
    a = dmi_film(n)
    ase_spin.set_spins(a, neel_skyrmion(a.positions, 6.25), magnitudes=2.2)
    assert SpinLBFGS(a).run(fmax=1e-9, steps=2000)
    assert topological_charge(a) == pytest.approx(-1.0, abs=1e-9)
    assert a.get_potential_energy() > fm.get_potential_energy() + 0.01
