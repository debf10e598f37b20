"""Langevin: canonical statistics of spins and lattice, T = 0 relaxation, invariants,
reproducibility, errors.

Statistical tests use fixed seeds. Each compares a mean with its exact value
within Z standard errors, the standard error estimated from the run itself:
across independent spins (non-interacting spins are independent samples, their
time averages iid) or by batch means over blocks much longer than the
correlation time. Z = 5 (a false failure once in ~2·10⁶ per comparison);
each test also checks that its standard error is small enough for the
comparison to mean something.
"""

import io

import numpy as np
import pytest
from ase import Atoms, units
from ase.build import bulk
from ase.md.langevin import Langevin as AseLangevin
from scipy import integrate

import ase_spin
from ase_spin import (G_ELECTRON, HBAR, MU_B, Exchange, BetheSlater, Langevin, LennardJones,
                      SpinLatticeCalculator, UniaxialAnisotropy, Zeeman, relax_spins,
                      set_spins)
from ase_spin.md.langevin import NOISY_TOL, LangevinLogger
from ase_spin.scenes import fcc_cobalt

Z = 5.0


def gas(mus, seed=0):
    """Independent spins: atoms 10 Å apart, no pair term; random directions."""
    n = len(mus)
    atoms = Atoms(f"H{n}", positions=np.column_stack([np.arange(n) * 10.0, np.zeros(n),
                                                        np.zeros(n)]),
                  cell=[10.0 * n, 10.0, 10.0], pbc=False)
    v = np.random.default_rng(seed).normal(size=(n, 3))
    set_spins(atoms, v, magnitudes=mus)
    return atoms


def langevin_function(x):
    return 1.0 / np.tanh(x) - 1.0 / x


def reads_the_state(observer):
    """``observer``, declared to read only the state through the integrator
    (``needs_results = False``): the steps it sees compute no calculator
    results or frames for it, and take the same path as unobserved steps."""
    observer.needs_results = False
    return observer


def spin_time_averages(dyn, steps, *functions, interval=1):
    """Per-spin time averages of f(s) for each f, sampled every ``interval``
    steps (the steps between samples then share their baths)."""
    acc = [0.0 for _ in functions]
    count = [0]

    def sample():
        s = dyn._state.s
        count[0] += 1
        for k, f in enumerate(functions):
            acc[k] = acc[k] + f(s)

    dyn.attach(reads_the_state(sample), interval=interval)
    dyn.run(steps)
    dyn.observers.pop()
    return [a / count[0] for a in acc]


def check_mean(per_sample, exact, what, max_se):
    """Mean of iid per-sample values against ``exact`` within Z standard errors."""
    per_sample = np.asarray(per_sample)
    se = per_sample.std(ddof=1, axis=0) / np.sqrt(per_sample.shape[0])
    assert np.all(se < max_se), (what, se)
    assert np.all(np.abs(per_sample.mean(axis=0) - exact) < Z * se), \
        (what, per_sample.mean(axis=0), exact, se)


@pytest.mark.parametrize("gyromagnetic", ["lammps", "moment"])
def test_single_spin_in_a_field_is_boltzmann(gyromagnetic):
    """Spins in a Zeeman field (g = 1, x = μ μ_B H/k_B T = 0.5, 2, 5 from three
    moments in one field): ⟨s·ĥ⟩ = coth x − 1/x, and the distribution of
    u = s·ĥ is P(u) ∝ exp(x u): the CDF transform F(u) is uniform, tested as
    the fraction of time in each of 8 bins of F, per spin. 256 independent
    spins per x; the standard error is the spread of the per-spin averages."""
    T = 20.0
    kT = units.kB * T
    xs = np.array([0.5, 2.0, 5.0])
    per = 256
    mus = np.repeat(xs, per)  # x = μ with H = k_B T/μ_B
    atoms = gas(mus)
    atoms.calc = SpinLatticeCalculator([Zeeman(kT / MU_B, [0, 0, 1], g=1.0)])
    rate = 1.0 if gyromagnetic == "lammps" else 2.0 / mus
    omega = float((rate * mus * kT).max()) / HBAR  # fastest Larmor frequency
    dyn = Langevin(atoms, 0.1 / omega, T, spin_damping=1.0, friction=0.0,
                   gyromagnetic=gyromagnetic, lattice="frozen", rng=11)
    dyn.run(500)
    x_of = np.repeat(xs, per)[:, None]
    edges = np.linspace(0.0, 1.0, 9)

    def cdf_bins(s):
        u = s[:, 2:3]
        F = np.expm1(x_of * (u + 1.0)) / np.expm1(2.0 * x_of)
        return (F >= edges[None, :-1]) & (F < edges[None, 1:])

    u_mean, bins = spin_time_averages(dyn, 6000, lambda s: s[:, 2], cdf_bins)
    for k, x in enumerate(xs):
        rows = slice(k * per, (k + 1) * per)
        check_mean(u_mean[rows], langevin_function(x), f"<s.h> at x={x}", 0.01)
        check_mean(bins[rows], np.full(8, 1 / 8), f"bins at x={x}", 0.01)
    assert np.abs(np.linalg.norm(dyn._state.s, axis=1) - 1.0).max() < 1e-14


def test_uniaxial_anisotropy_against_its_integral():
    """⟨(s·n)²⟩ = ∫u² e^{K u²/kT} du / ∫e^{K u²/kT} du for an easy axis and an
    easy plane (K/k_B T = 2 and −1.5); 256 independent spins each."""
    T = 30.0
    kT = units.kB * T
    per = 256
    ratios = np.array([2.0, -1.5])
    Ks = np.repeat(ratios * kT, per)
    atoms = gas(np.ones(2 * per), seed=3)
    atoms.numbers[per:] = 2  # two species, one K each
    atoms.calc = SpinLatticeCalculator([UniaxialAnisotropy(
        {"H": ratios[0] * kT, "He": ratios[1] * kT}, [0.0, 0.6, 0.8])])
    n = np.array([0.0, 0.6, 0.8])
    omega = 2.0 * float(np.abs(Ks).max()) / HBAR
    dyn = Langevin(atoms, 0.1 / omega, T, spin_damping=1.0, friction=0.0,
                   lattice="frozen", rng=5)
    dyn.run(500)
    (c2,) = spin_time_averages(dyn, 6000, lambda s: (s @ n) ** 2)
    for k, r in enumerate(ratios):
        num = integrate.quad(lambda u: u * u * np.exp(r * u * u), -1, 1)[0]
        den = integrate.quad(lambda u: np.exp(r * u * u), -1, 1)[0]
        check_mean(c2[k * per:(k + 1) * per], num / den, f"<(s.n)^2> K/kT={r}", 0.01)


def batch_means(series, blocks=20):
    """Mean and its standard error from ``blocks`` consecutive block means."""
    series = np.asarray(series)
    m = series[: len(series) // blocks * blocks].reshape(blocks, -1, *series.shape[1:])
    means = m.mean(axis=1)
    return means.mean(axis=0), means.std(ddof=1, axis=0) / np.sqrt(blocks)


def sublattice_temperatures(wrong_variance=False):
    """Spin temperatures (estimates, standard errors) of the μ = 1 and μ = 7
    sublattices of the test below; ``wrong_variance``: one noise variance for
    every spin (the mean rate's) instead of each spin's own."""
    from ase_spin.md import baths as langevin  # its half steps draw the noise

    atoms = bulk("Co", "fcc", a=3.54, cubic=True).repeat(2)
    mus = np.where(np.arange(len(atoms)) % 2 == 0, 1.0, 7.0)
    set_spins(atoms, [0, 0, 1], magnitudes=mus)
    atoms.calc = SpinLatticeCalculator([Exchange(BetheSlater(0.0446928, 0.003496, 1.4885),
                                                 rc=4.0)])
    T = 500.0
    dyn = Langevin(atoms, 0.5 * units.fs, T, spin_damping=0.5, friction=0.0,
                   gyromagnetic="moment", lattice="frozen", rng=2)
    amplitude = langevin.noise_amplitude
    if wrong_variance:
        langevin.noise_amplitude = lambda d: np.full_like(d, amplitude(np.mean(d)))
    try:
        dyn.run(300)
        num, den = [], []
        small = mus == 1.0

        def sample():
            s = dyn._state.s
            B = dyn.get_magnetic_forces()
            c = (np.cross(s, B) ** 2).sum(axis=1)
            d = np.einsum("ij,ij->i", s, B)
            num.append([c[small].sum(), c[~small].sum()])
            den.append([d[small].sum(), d[~small].sum()])

        dyn.attach(reads_the_state(sample), interval=1)
        dyn.run(5000)
    finally:
        langevin.noise_amplitude = amplitude
    num, den = np.array(num), np.array(den)
    blocks = 20  # ratio estimator per block
    k = len(num) // blocks
    t_blocks = (num[: k * blocks].reshape(blocks, k, 2).sum(axis=1)
                / den[: k * blocks].reshape(blocks, k, 2).sum(axis=1)) / (2 * units.kB)
    return t_blocks.mean(axis=0), t_blocks.std(ddof=1, axis=0) / np.sqrt(blocks)


def test_mixed_moments_each_sublattice_at_the_bath_temperature():
    """Moments 1 and 7 μB on alternating fcc sites, exchange-coupled, frozen
    lattice, gyromagnetic="moment" (precession rates differ 7×): each
    sublattice's spin temperature Σ|s×B|²/(2k_B Σ s·B) (the equilibrium
    identity ⟨|s×B|²⟩ = 2k_B T ⟨s·B⟩, per spin) equals the bath's (500 K), each
    from its own time series; standard errors by batch means (20 blocks of 250
    steps, the correlation time ~10 steps). With one variance for all spins
    (LAMMPS issue 5097's situation) the same check fails: the sublattices
    come out at different temperatures."""
    T = 500.0
    t, se = sublattice_temperatures()
    assert np.all(se < 0.03 * T), se
    assert np.all(np.abs(t - T) < Z * se), (t, se)
    t, se = sublattice_temperatures(wrong_variance=True)
    assert abs(t[0] - t[1]) > Z * np.hypot(*se), (t, se)


def lj_crystal():
    atoms = bulk("Co", "fcc", a=3.54, cubic=True).repeat(2)
    atoms.rattle(0.02, seed=1)
    atoms.calc = SpinLatticeCalculator([LennardJones(epsilon=0.4, sigma=2.2742, rc=4.7,
                                                     cutoff="shift")])
    return atoms


@pytest.mark.filterwarnings("ignore:The implementation of `fixcm=True`:FutureWarning")
def test_lattice_temperature_velocities_and_ase_langevin():
    """No spins: kinetic temperature ⟨2K/(3N k_B)⟩ = T (3N − 3)/(3N) with fixcm;
    velocities v·√(m/k_B T) have variance (N−1)/N and Gaussian kurtosis 3;
    ⟨E_pot⟩ agrees with ASE's own Langevin on the same crystal (difference
    within Z combined standard errors); total momentum stays zero."""
    T = 300.0
    fr = 0.1 / units.fs  # correlation time of the kinetic energy ~ 1/(2γ) = 2.5 steps
    h = 2.0 * units.fs
    res = {}
    for name in ("ours", "ase"):
        atoms = lj_crystal()
        if name == "ours":
            dyn = Langevin(atoms, h, T, spin_damping=0.0, friction=fr, rng=3)
        else:
            dyn = AseLangevin(atoms, h, temperature_K=T, friction=fr, fixcm=True,
                              rng=np.random.RandomState(3))
        dyn.run(100)
        ek, ep, v = [], [], []

        def sample(dyn=dyn, atoms=atoms):
            ek.append(atoms.get_kinetic_energy())
            ep.append(dyn.get_potential_energy() if name == "ours"
                      else atoms.get_potential_energy())
            v.append(atoms.get_velocities() * np.sqrt(atoms.get_masses()[:, None]
                                                      / (units.kB * T)))

        dyn.attach(sample, interval=1)
        dyn.run(1200)
        res[name] = (np.array(ek), np.array(ep), np.array(v))
    ek, ep, v = res["ours"]
    n = 32
    tkin, se = batch_means(2 * ek / (3 * n * units.kB))
    assert se < 0.02 * T
    assert abs(tkin - T * (3 * n - 3) / (3 * n)) < Z * se, (tkin, se)
    var, se_var = batch_means((v ** 2).reshape(len(v), -1).mean(axis=1))
    assert abs(var - (n - 1) / n) < Z * se_var, (var, se_var)
    k4, se_k4 = batch_means((v ** 4).reshape(len(v), -1).mean(axis=1))
    assert abs(k4 / var ** 2 - 3.0) < Z * (se_k4 / var ** 2 + 6 * se_var / var), k4
    mine, se1 = batch_means(res["ours"][1])
    theirs, se2 = batch_means(res["ase"][1])
    assert abs(mine - theirs) < Z * np.hypot(se1, se2), (mine, theirs, se1, se2)
    assert np.hypot(se1, se2) < 0.01 * abs(mine)


def analytic_damped_precession(s0, Bvec, rate, lam, t, sigma):
    """The LLG solution in a fixed field: tan(θ/2) = tan(θ₀/2) e^{−λωt/(1+λ²)},
    φ = φ₀ − σ ω t/(1+λ²), ω = r|B|/ħ, about B = |B| ẑ."""
    omega = rate * np.linalg.norm(Bvec) / HBAR
    th0 = np.arccos(s0[2])
    ph0 = np.arctan2(s0[1], s0[0])
    th = 2 * np.arctan(np.tan(th0 / 2) * np.exp(-lam * omega * t / (1 + lam**2)))
    ph = ph0 - sigma * omega * t / (1 + lam**2)
    return np.array([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)])


@pytest.mark.parametrize("precession", ["moment", "spin"])
@pytest.mark.parametrize("gyromagnetic", ["lammps", "moment"])
def test_zero_temperature_damped_precession_second_order(precession, gyromagnetic):
    """T = 0, λ = 0.1: one spin (μ = 2) in a field relaxes along the analytic
    LLG path; error at t against h, h/2, h/4 falls at order 2."""
    mu = 2.0
    H = 50.0
    lam = 0.1
    s0 = np.array([np.sin(2.5), 0.0, np.cos(2.5)])
    rate = 1.0 if gyromagnetic == "lammps" else G_ELECTRON / mu
    Bvec = np.array([0, 0, MU_B * mu * H])  # the physical Zeeman energy −μ μB s·H
    omega = rate * np.linalg.norm(Bvec) / HBAR
    t_end = 20.0 / omega
    errors = []
    for n in (100, 200, 400):
        atoms = gas([mu])
        set_spins(atoms, s0)
        atoms.calc = SpinLatticeCalculator([Zeeman(H, [0, 0, 1])])
        dyn = Langevin(atoms, t_end / n, 0.0, spin_damping=lam, friction=0.0,
                       precession=precession, gyromagnetic=gyromagnetic, lattice="frozen",
                       rng=0)
        dyn.run(n)
        exact = analytic_damped_precession(s0, Bvec, rate, lam, t_end, dyn.sigma)
        errors.append(np.abs(ase_spin.get_spins(atoms)[0] - exact).max())
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all(np.abs(orders - 2.0) < 0.1), (errors, orders)
    assert errors[-1] < 1e-2


def co_scene(n=2):
    atoms = fcc_cobalt(n, temperature_K=300.0, cone_deg=40.0)
    atoms.calc = SpinLatticeCalculator(ase_spin.scenes.fcc_cobalt_terms()
                                       + [Zeeman(5.0, [0, 0, 1]),
                                          UniaxialAnisotropy(1e-3, [1, 0, 0])])
    return atoms


def spin_length_run(steps):
    atoms = co_scene()
    dyn = Langevin(atoms, 0.5 * units.fs, 600.0, spin_damping=0.3, friction=0.02 / units.fs,
                   rng=7)
    worst = 0.0
    for _ in range(steps // 250):
        dyn.run(250)
        worst = max(worst, float(np.abs(np.linalg.norm(dyn._state.s, axis=1) - 1).max()))
    return worst


def test_spin_lengths_stay_at_roundoff():
    """|s_i| = 1 to 1e-13 over 1 000 stochastic steps (10⁵ with -m slow), fcc Co
    with exchange, Zeeman and anisotropy, both baths on."""
    assert spin_length_run(1000) < 1e-13


@pytest.mark.slow
def test_spin_lengths_stay_at_roundoff_long():
    assert spin_length_run(100_000) < 1e-13


def unit(moments):
    """The spins of moments (rows of unit length)."""
    return moments / np.linalg.norm(moments, axis=1, keepdims=True)


def test_reproducible_from_rng_and_restart(tmp_path):
    """Same seed: identical runs (whatever observes them: tests/
    test_reproducibility.py). Restart from a trajectory's last frame with the
    rng state saved (``dyn.rng.bit_generator.state``) reproduces the
    uninterrupted run (to the midpoint iteration's tolerance on unit spins,
    NOISY_TOL = 1e-10, after 60 steps: the restart has no predictor history,
    so its solves stop elsewhere within it); another seed differs."""
    from ase.io import read

    def make(seed):
        atoms = co_scene()
        dyn = Langevin(atoms, 0.5 * units.fs, 400.0, spin_damping=0.2,
                       friction=0.01 / units.fs, rng=seed)
        return atoms, dyn

    a1, d1 = make(4)
    d1.run(120)
    a2, d2 = make(4)
    d2.run(120)
    assert np.array_equal(a1.positions, a2.positions)
    assert np.array_equal(a1.get_initial_magnetic_moments(), a2.get_initial_magnetic_moments())
    a3, d3 = make(5)
    d3.run(120)
    assert np.abs(a3.get_initial_magnetic_moments() - a1.get_initial_magnetic_moments()).max() > 1e-3

    a4, d4 = make(4)
    traj = str(tmp_path / "run.traj")
    d4 = Langevin(a4, 0.5 * units.fs, 400.0, spin_damping=0.2, friction=0.01 / units.fs,
                  rng=4, trajectory=traj, loginterval=60)
    d4.run(60)
    state = d4.rng.bit_generator.state
    back = read(traj, -1)
    back.calc = SpinLatticeCalculator(co_scene().calc.hamiltonian.terms)
    rng = np.random.default_rng()
    rng.bit_generator.state = state
    d5 = Langevin(back, 0.5 * units.fs, 400.0, spin_damping=0.2, friction=0.01 / units.fs,
                  rng=rng)
    d5.run(60)
    assert np.abs(back.positions - a1.positions).max() < 1e-10
    # the tolerance is on unit spins (the midpoint solve's), not on moments
    assert np.abs(unit(back.get_initial_magnetic_moments())
                  - unit(a1.get_initial_magnetic_moments())).max() < NOISY_TOL


def test_bath_energy_makes_a_conserved_quantity():
    """E_tot − E_bath stays within the collective step's own energy error (as an
    NVE run's spread on the same scene) while E_tot itself wanders by far more;
    the log carries Ebath and Econs."""
    atoms = co_scene()
    log = io.StringIO()
    dyn = Langevin(atoms, 0.5 * units.fs, 2000.0, spin_damping=0.3,
                   friction=0.05 / units.fs, rng=1, logfile=log, loginterval=50)
    cons, tot = [], []
    dyn.attach(lambda: (cons.append(dyn.get_conserved_energy()),
                        tot.append(dyn.get_total_energy())), interval=10)
    dyn.run(1000)
    cons, tot = np.array(cons), np.array(tot)
    assert np.ptp(tot) > 50 * np.ptp(cons), (np.ptp(tot), np.ptp(cons))
    nve = ase_spin.CollectivePRK(co_scene(), 0.5 * units.fs)
    e = []
    nve.attach(lambda: e.append(nve.get_total_energy()), interval=10)
    nve.run(400)
    assert np.ptp(cons) < 20 * max(np.ptp(e), 1e-6)
    lines = log.getvalue().splitlines()
    assert "Ebath[eV]" in lines[0] and len(lines) == 22
    last = [float(x) for x in lines[-1].split()]
    assert abs(last[-2] - dyn.get_bath_energy()) < 1e-2
    assert abs(last[-1] - dyn.get_conserved_energy()) < 1e-2


def test_baths_off_is_collective_prk():
    """spin_damping = 0 and friction = 0: CollectivePRK, step for step."""
    a, b = co_scene(), co_scene()
    Langevin(a, 0.5 * units.fs, 300.0, spin_damping=0.0, friction=0.0, rng=1).run(30)
    ase_spin.CollectivePRK(b, 0.5 * units.fs).run(30)
    assert np.array_equal(a.positions, b.positions)
    assert np.array_equal(a.get_initial_magnetic_moments(), b.get_initial_magnetic_moments())


def test_two_temperatures():
    """Spin bath at 50 K, lattice bath at 600 K, parts uncoupled (LJ lattice,
    Zeeman spins, μ = 2): each part at its own bath — the spin temperature by
    its estimator (exact in expectation for any T here), the lattice kinetic
    temperature ×3N/(3N − 3) (fixcm); batch-means standard errors."""
    atoms = lj_crystal()
    set_spins(atoms, np.random.default_rng(2).normal(size=(32, 3)), magnitudes=2.0)
    atoms.calc = SpinLatticeCalculator(list(lj_crystal().calc.hamiltonian.terms)
                                       + [Zeeman(200.0, [0, 0, 1])])
    dyn = Langevin(atoms, 2.0 * units.fs, 600.0, spin_temperature_K=50.0, spin_damping=1.0,
                   friction=0.1 / units.fs, rng=9)
    dyn.run(100)
    num, den, tl = [], [], []

    def sample():
        s = dyn._state.s
        B = dyn.get_magnetic_forces()
        num.append((np.cross(s, B) ** 2).sum())
        den.append(np.einsum("ij,ij->", s, B))
        tl.append(dyn.get_temperature())

    dyn.attach(reads_the_state(sample), interval=1)
    dyn.run(1200)
    blocks = 20
    k = len(num) // blocks
    ts = (np.reshape(num[: k * blocks], (blocks, k)).sum(axis=1)
          / np.reshape(den[: k * blocks], (blocks, k)).sum(axis=1)) / (2 * units.kB)
    ts_m, ts_se = ts.mean(), ts.std(ddof=1) / np.sqrt(blocks)
    tl_m, tl_se = batch_means(tl)
    assert ts_se < 3.0 and tl_se < 30.0, (ts_se, tl_se)
    assert abs(ts_m - 50.0) < Z * ts_se, (ts_m, ts_se)
    assert abs(tl_m - 600.0 * 31 / 32) < Z * tl_se, (tl_m, tl_se)


class SumsLog(LangevinLogger):
    """The log line, also keeping every line's sums (N, D) of the spin
    temperature (a log line: the integrator publishes no frame for it)."""

    def __init__(self, dyn, **kwargs):
        super().__init__(dyn, io.StringIO(), **kwargs)
        self.sums = []
        self.nurdin = []  # 2 Σ s·B: the denominator without the curvature

    def spin_temperature(self, dyn):
        self.sums.append(dyn.get_spin_temperature_sums())
        self.nurdin.append(2.0 * np.einsum("ij,ij->", dyn._state.s,
                                           dyn.get_magnetic_forces()))
        return super().spin_temperature(dyn)

    def column(self, name):
        lines = self.logfile.getvalue().splitlines()
        k = lines[0].split().index(name)
        return np.array([float(line.split()[k]) for line in lines[1:]])


def logged_spin_temperature(n, T, steps, seed=3, interval=5):
    """fcc Co (its exchange; frozen lattice) with the spin bath at T: after
    equilibration, a log line every ``interval`` steps (the default window of
    Ts, SPIN_TEMPERATURE_WINDOW lines). Returns the log (SumsLog)."""
    atoms = fcc_cobalt(n, temperature_K=0.0, cone_deg=10.0, seed=seed)
    dyn = Langevin(atoms, 0.5 * units.fs, T, spin_damping=0.5, friction=0.0,
                   lattice="frozen", rng=seed)
    dyn.run(1000)
    log = SumsLog(dyn)
    dyn.attach(log, interval=interval)
    dyn.run(steps)
    return log


@pytest.mark.parametrize("T", [600.0, 2200.0])
def test_spin_temperature_of_the_log_is_the_bath_temperature(T):
    """108 spins of fcc Co (T_C ≈ 1 070 K at this size, docs/thermostats.md)
    with the spin bath at T below and above T_C: the log's Ts (the ratio of
    the sums N, D averaged over its last 10 lines) agrees with T within Z
    standard errors, taken from the spread of the values of independent
    windows (every 10th line); so does the run's ratio of averages
    ΣN/(k_B ΣD) (standard error from batch means of the ratio). Every
    written Ts, above T_C too, is positive and near T (within a factor 2: a
    window of 10 lines 5 steps apart spreads by ~15 % at 2 200 K), and a nan
    (a window whose denominator its fluctuation could cancel) is rare."""
    from ase_spin.md.logger import SPIN_TEMPERATURE_WINDOW as W

    log = logged_spin_temperature(3, T, 6000)
    ts = log.column("Ts[K]")
    assert len(ts) == 1200
    windows = ts[W - 1::W]  # each of W lines of its own
    assert np.isnan(windows).sum() <= 1
    windows = windows[~np.isnan(windows)]
    mean, se = windows.mean(), windows.std(ddof=1) / np.sqrt(len(windows))
    assert se < 0.02 * T, (mean, se)
    assert abs(mean - T) < Z * se, (mean, se)
    num, den = np.array(log.sums).T
    blocks = 20
    k = len(num) // blocks
    ratio = (num[:k * blocks].reshape(blocks, k).sum(axis=1)
             / den[:k * blocks].reshape(blocks, k).sum(axis=1)) / units.kB
    r_mean, r_se = ratio.mean(), ratio.std(ddof=1) / np.sqrt(blocks)
    assert r_se < 0.02 * T and abs(r_mean - T) < Z * r_se, (r_mean, r_se)
    written = ts[~np.isnan(ts)]
    assert np.isnan(ts).mean() < 0.02
    assert (written > T / 2).all() and (written < 2 * T).all(), (written.min(), written.max())


def test_spin_temperature_above_tc_is_never_negative_nor_huge():
    """32 spins far above T_C (2 200 K): one sample's N/(k_B D) (LAMMPS's
    estimator) goes negative and to tens of thousands of K, as the issue
    reported; the log's Ts is written only as a positive number near T, never
    above √(ΣN)/(6 k_B) of its window, else nan (seldom)."""
    from ase_spin.md.logger import SPIN_TEMPERATURE_WINDOW as W

    T = 2200.0
    log = logged_spin_temperature(2, T, 3000)
    num, den = np.array(log.sums).T
    single = num / (units.kB * den)
    assert (single < 0).sum() > 10 and single.max() > 10 * T  # what the issue saw
    ts = log.column("Ts[K]")
    written = ~np.isnan(ts)
    assert 0.7 < written.mean() < 1.0
    assert (ts[written] > T / 2).all() and (ts[written] < 2 * T).all(), (
        ts[written].min(), ts[written].max())
    window_n = np.array([num[max(0, k - W + 1):k + 1].sum() for k in range(len(num))])
    assert (ts[written] <= np.sqrt(window_n[written]) / (6 * units.kB)).all()
    # and the run's ratio of averages is T
    assert abs(num.sum() / (units.kB * den.sum()) - T) < 0.1 * T


def test_spin_temperature_with_anisotropy_takes_its_curvature():
    """Independent spins in a uniaxial anisotropy (K/k_B T = 2, easy axis; −1.5,
    easy plane): ⟨N⟩/⟨D⟩ = k_B T only with D = ∇²E, which for a field that
    depends on its own spin is 2 s·B less Σ_t t·∂B/∂s t; Nurdin's 2 Σ s·B
    alone is off by far more than the standard error."""
    T = 30.0
    kT = units.kB * T
    per = 128
    ratios = np.array([2.0, -1.5])
    atoms = gas(np.ones(2 * per), seed=3)
    atoms.numbers[per:] = 2
    atoms.calc = SpinLatticeCalculator([UniaxialAnisotropy(
        {"H": ratios[0] * kT, "He": ratios[1] * kT}, [0.0, 0.6, 0.8])])
    omega = 2.0 * float(np.abs(ratios).max() * kT) / HBAR
    dyn = Langevin(atoms, 0.1 / omega, T, spin_damping=1.0, friction=0.0,
                   lattice="frozen", rng=5)
    dyn.run(500)
    log = SumsLog(dyn)
    dyn.attach(log, interval=5)
    dyn.run(3000)
    num, den = np.array(log.sums).T
    ratio = (num.reshape(20, -1).sum(axis=1) / den.reshape(20, -1).sum(axis=1)) / units.kB
    mean, se = ratio.mean(), ratio.std(ddof=1) / np.sqrt(20)
    assert se < 0.02 * T and abs(mean - T) < Z * se, (mean, se)
    wrong = num.sum() / (units.kB * np.sum(log.nurdin))
    assert abs(wrong - T) > max(0.1 * T, 10 * se), (wrong, se)


def test_relax_spins_finds_the_ferromagnet():
    """fcc Co (ferromagnetic exchange) from a 60° cone: relax_spins reaches
    torques ≤ 1e-8 eV with every spin parallel (|M| = 1, the ground state),
    positions untouched; not reaching fmax raises and leaves the spins."""
    atoms = fcc_cobalt(2, temperature_K=0.0, cone_deg=60.0)
    pos = atoms.positions.copy()
    n = relax_spins(atoms, fmax=1e-8)
    assert 0 < n < 2000
    s = ase_spin.get_spins(atoms)
    assert 1.0 - np.linalg.norm(s.mean(axis=0)) < 1e-12
    assert np.array_equal(atoms.positions, pos)
    a = fcc_cobalt(2, temperature_K=0.0, cone_deg=60.0)
    before = a.get_initial_magnetic_moments().copy()
    with pytest.raises(RuntimeError, match="fmax"):
        relax_spins(a, fmax=1e-12, steps=3)
    assert np.array_equal(a.get_initial_magnetic_moments(), before)


def _torque(atoms):
    B = atoms.calc.get_property("magnetic_forces", atoms)
    return np.linalg.norm(np.cross(ase_spin.get_spins(atoms), B), axis=1).max()


def test_relax_spins_warns_about_no_timestep_it_chose():
    """Its own timestep (0.2 rad per step for the fastest spin) draws no
    TimestepWarning (its probe used to warn about a timestep of 1 ASE unit);
    the count is the step of the first passing check (1, 2, 4, ..., 32, then
    multiples of 32), where the torque is within fmax."""
    from ase_spin.md.errors import TimestepWarning
    from ase_spin.md.relax import RELAX_CHECK

    import warnings
    atoms = fcc_cobalt(2, temperature_K=0.0, cone_deg=90.0,
                       extra=[UniaxialAnisotropy(0.01, [1.0, 0.0, 0.0])])
    with warnings.catch_warnings():
        warnings.simplefilter("error", TimestepWarning)
        n = relax_spins(atoms, fmax=1e-7)
    assert n in (1, 2, 4, 8, 16) or n % RELAX_CHECK == 0, n
    assert 0 < n < 5000
    assert _torque(atoms) <= 1e-7
    assert relax_spins(atoms, fmax=1e-7) == 0  # relaxed already: no step
    # a timestep given is checked as any integrator's
    b = fcc_cobalt(2, temperature_K=0.0, cone_deg=60.0)
    with pytest.warns(TimestepWarning, match="precesses"):
        relax_spins(b, fmax=1e-4, timestep=8 * units.fs, solver="anderson")


def test_relax_spins_steps_cost_what_langevin_steps_cost(monkeypatch):
    """No full evaluation per step: the passes over the spin terms of a
    relaxation are those of a Langevin run of as many steps (its steps in
    blocks), plus two per torque check (the block's last closing bath, not
    merged with the next opening one: its fields before and after, the latter
    what the check reads) and one at the start."""
    from ase_spin.hamiltonian import Evaluator
    from ase_spin.md.baths import BathHalfSteps

    counts = {"evaluate": 0, "fields": 0}
    evaluate, fields = Evaluator.evaluate, BathHalfSteps._spin_energy_fields

    def counting_evaluate(self, *args, **kwargs):
        counts["evaluate"] += 1
        return evaluate(self, *args, **kwargs)

    def counting_fields(self, *args, **kwargs):
        counts["fields"] += 1
        return fields(self, *args, **kwargs)

    monkeypatch.setattr(Evaluator, "evaluate", counting_evaluate)
    monkeypatch.setattr(BathHalfSteps, "_spin_energy_fields", counting_fields)
    atoms = fcc_cobalt(2, temperature_K=0.0, cone_deg=60.0)
    n = relax_spins(atoms, fmax=1e-6)
    relax = dict(counts)
    checks = sum(1 for k in range(1, n + 1) if k in (1, 2, 4, 8, 16) or k % 32 == 0)
    counts.update(evaluate=0, fields=0)
    b = fcc_cobalt(2, temperature_K=0.0, cone_deg=60.0)
    dyn = Langevin(b, 0.1 * units.fs, 0.0, spin_damping=1.0, friction=0.0, lattice="frozen")
    dyn.run(n)
    assert relax["evaluate"] == 0  # (a Langevin's set-up takes one: its timestep check)
    assert relax["fields"] <= counts["fields"] + 2 * checks + 1, (relax, counts, n, checks)


@pytest.mark.parametrize("kwargs, match", [
    (dict(spin_damping=-0.1, friction=0.0), "spin_damping"),
    (dict(spin_damping=0.1, friction=-1.0), "friction"),
    (dict(spin_damping=0.1, friction=0.0, spin_temperature_K=-5.0), "spin_temperature_K"),
    (dict(spin_damping=float("nan"), friction=0.0), "spin_damping"),
])
def test_bad_parameters_are_refused(kwargs, match):
    atoms = co_scene()
    before = atoms.get_initial_magnetic_moments().copy()
    with pytest.raises(ValueError, match=match):
        Langevin(atoms, 0.5 * units.fs, 300.0, **kwargs)
    with pytest.raises(ValueError, match="temperature_K"):
        Langevin(atoms, 0.5 * units.fs, -1.0, spin_damping=0.1, friction=0.0)
    with pytest.raises(ValueError, match="positive timestep"):
        Langevin(atoms, -0.5 * units.fs, 1.0, spin_damping=0.1, friction=0.0)
    with pytest.raises(TypeError, match="rng"):
        Langevin(atoms, 0.5 * units.fs, 1.0, spin_damping=0.1, friction=0.0, rng="seed")
    assert np.array_equal(atoms.get_initial_magnetic_moments(), before)


def test_set_temperature_takes_effect_mid_run():
    """Spins in a field at 500 K, then set_temperature(0): with damping they
    relax onto the field (no noise left in the step)."""
    atoms = gas(np.full(8, 2.0))
    atoms.calc = SpinLatticeCalculator([Zeeman(200.0, [0, 0, 1])])
    dyn = Langevin(atoms, 2.0 * units.fs, 500.0, spin_damping=1.0, friction=0.0,
                   lattice="frozen", rng=1)
    dyn.run(20)
    assert ase_spin.get_spins(atoms)[:, 2].min() < 0.99
    dyn.set_temperature(0.0)
    dyn.run(400)
    assert ase_spin.get_spins(atoms)[:, 2].min() > 1.0 - 1e-9
    with pytest.raises(ValueError, match="temperature_K"):
        dyn.set_temperature(-3.0)


def stationary_bias(omega_h, per=1024, steps=1500, amplitude=None, dimer_j=0.0, x=2.0,
                    interval=1):
    """Stationary ⟨s·ĥ⟩ (and ⟨s₁·s₂⟩ for exchange-coupled pairs, ``dimer_j`` =
    J/k_B T) of independent spins in a Zeeman field (x = μH/k_B T, λ = 1; x = 0:
    no field term) at the step h = ``omega_h``/ω, ω the largest precession rate
    (x + J/k_B T)k_B T/ħ: (biases against the exact values, their standard
    errors from the spread of the per-spin time averages), sampled every
    ``interval`` steps. ``amplitude``: replaces the noise amplitude."""
    from ase_spin import Cubic
    from ase_spin.md import baths as langevin  # its half steps draw the noise

    T = 20.0
    kT = units.kB * T
    n = 2 * per if dimer_j else per
    atoms = gas(np.full(n, x if x else 1.0), seed=4)  # μ = x μ_B, or 1 without field
    terms = [Zeeman(kT / MU_B, [0, 0, 1], g=1.0)] if x else []
    if dimer_j:  # pairs 2 Å apart, 10 Å from the next pair; J(2 Å) = J
        atoms.positions[1::2, 0] = atoms.positions[0::2, 0] + 2.0
        terms.append(Exchange(Cubic(dimer_j * kT * 27.0, 3.0)))
    atoms.calc = SpinLatticeCalculator(terms)
    omega = (x + dimer_j) * kT / HBAR
    saved = langevin.noise_amplitude
    if amplitude is not None:
        langevin.noise_amplitude = amplitude
    try:
        # rate 1 (LAMMPS's precession): ω above is the precession rate
        dyn = Langevin(atoms, omega_h / omega, T, spin_damping=1.0, friction=0.0,
                       lattice="frozen", rng=3, max_iter=1000, gyromagnetic="lammps")
        dyn.run(200)
        u, c = spin_time_averages(dyn, steps, lambda s: s[:, 2],
                                  lambda s: np.einsum("ij,ij->i", s[0::2], s[1::2]),
                                  interval=interval)
    finally:
        langevin.noise_amplitude = saved
    if not dimer_j:
        exact = langevin_function(x)
        return u.mean() - exact, u.std(ddof=1) / np.sqrt(n)
    eu, ec = dimer_averages(x, dimer_j)
    return (np.array([u.mean() - eu, c.mean() - ec]),
            np.array([u.std(ddof=1) / np.sqrt(n), c.std(ddof=1) / np.sqrt(per)]))


def dimer_averages(x, j, n=80, m=64):
    """Exact ⟨s₁·ẑ⟩ and ⟨s₁·s₂⟩ for E/k_B T = −x(u₁ + u₂) − j s₁·s₂ (Gauss–Legendre in
    u₁, u₂; the relative azimuth on a uniform grid, exact for the periodic integrand)."""
    u, w = np.polynomial.legendre.leggauss(n)
    phi = np.arange(m) * 2 * np.pi / m
    U1, U2, P = np.meshgrid(u, u, phi, indexing="ij")
    c = U1 * U2 + np.sqrt((1 - U1**2) * (1 - U2**2)) * np.cos(P)
    f = (w[:, None, None] * w[None, :, None]) * np.exp(x * (U1 + U2) + j * c - (2 * x + j))
    return (f * U1).sum() / f.sum(), (f * c).sum() / f.sum()


def falls_at_order_above(b1, se1, b2, se2, order):
    """The bias at h (b1) is resolved and the one at h/2 (b2) is below |b1|/2^order
    by more than Z combined standard errors allow for."""
    return abs(b1) > Z * se1 and abs(b2) < abs(b1) / 2**order + Z * np.hypot(se1, se2)


@pytest.mark.filterwarnings("ignore::ase_spin.md.errors.TimestepWarning")
def test_weak_second_order_single_spin():
    """Stationary bias of ⟨s·ĥ⟩ (x = 2) at ωh = 2.4 and 1.2 (large steps, so
    that the bias is resolved: ~4 % of ⟨s·ĥ⟩ at 2.4): it falls by more than
    2^1.5 (measured ≈ 7, docs/thermostats.md); with the noise variance of a
    first-order step, σ² = 2Dτ, the same check fails. Standard errors from
    1024 independent spins, 1500 steps each."""
    b1, se1 = stationary_bias(2.4)
    b2, se2 = stationary_bias(1.2)
    assert se1 < 1e-3 and se2 < 1e-3
    assert falls_at_order_above(b1, se1, b2, se2, 1.5), (b1, se1, b2, se2)
    plain = lambda d: np.sqrt(2.0 * d)  # noqa: E731
    p1, pe1 = stationary_bias(2.4, amplitude=plain)
    p2, pe2 = stationary_bias(1.2, amplitude=plain)
    assert not falls_at_order_above(p1, pe1, p2, pe2, 1.5), (p1, p2)


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore::ase_spin.md.errors.TimestepWarning")
def test_weak_second_order_interacting_pairs():
    """Exchange-coupled pairs in a field (x = 1, J/k_B T = 2): the stationary
    bias of ⟨s₁·s₂⟩ at ωh = 1.6 and 0.8 falls by more than 2^1.5 (measured
    3.9, docs/thermostats.md; the damping about the fields frozen at the
    bath's start alone gives 2.6 and a ⟨s·ĥ⟩ bias that grows)."""
    b1, se1 = stationary_bias(1.6, per=2048, steps=2000, dimer_j=2.0, x=1.0)
    b2, se2 = stationary_bias(0.8, per=2048, steps=2000, dimer_j=2.0, x=1.0)
    assert np.all(se1 < 1e-3) and np.all(se2 < 1e-3)
    assert falls_at_order_above(b1[1], se1[1], b2[1], se2[1], 1.5), (b1, se1, b2, se2)


def test_noisy_default_tolerance_changes_nothing_a_run_can_show():
    """With a bath at T > 0 the default midpoint tolerance is NOISY_TOL (1e-10),
    round-off otherwise, and an explicit ``tol`` is kept. The loose default
    follows the round-off run (same seed) to far below the noise: positions and
    within 1e-10 Å, spins within 1e-9 after 200 steps (measured: 3e-13, 7e-11),
    E_tot − E_bath within 1e-5 of its own spread (measured 2e-7), in fewer
    sweeps."""

    def make(**kw):
        return Langevin(co_scene(), 0.5 * units.fs, 600.0, spin_damping=0.3,
                        friction=0.02 / units.fs, rng=3, **kw)

    assert make().tol == NOISY_TOL == 1e-10
    assert make(tol=1e-13).tol == 1e-13
    cold = Langevin(co_scene(), 0.5 * units.fs, 0.0, spin_damping=0.3, friction=0.0)
    assert cold.tol == 1e-15
    loose, tight = make(), make(tol=1e-15)
    econs = {id(d): [] for d in (loose, tight)}
    for d in (loose, tight):
        d.attach(lambda d=d: econs[id(d)].append(d.get_conserved_energy()), interval=10)
        d.run(200)
    a, b = loose.atoms, tight.atoms
    assert np.abs(a.positions - b.positions).max() < 1e-10
    assert np.abs(a.get_initial_magnetic_moments()
                  - b.get_initial_magnetic_moments()).max() < 1e-9
    ea, eb = np.array(econs[id(loose)]), np.array(econs[id(tight)])
    assert np.abs(ea - eb).max() < 1e-5 * np.ptp(eb), (np.abs(ea - eb).max(), np.ptp(eb))
    assert loose.total_iterations < tight.total_iterations



def test_noisy_auto_solver_takes_locally_exact_sweeps():
    """With a bath at T > 0, ``solver="auto"`` solves with locally exact
    sweeps (as CollectivePRK's), where the noise leaves the midpoint predictor
    further off than two Jacobi sweeps make up for: the same steps as Jacobi's
    to the tolerance (1e-10, 30 steps), in fewer sweeps, with no switch to
    Anderson."""

    def make(solver):
        return Langevin(fcc_cobalt(3, temperature_K=300.0, conventions="lammps"), 0.1 * units.fs, 300.0,
                        spin_damping=0.1, friction=0.01 / units.fs, rng=2, solver=solver)

    auto, jacobi = make("auto"), make("jacobi")
    for d in (auto, jacobi):
        d.run(30)
    assert not auto._state.modes
    assert auto.total_iterations < 0.8 * jacobi.total_iterations, (auto.total_iterations,
                                                                   jacobi.total_iterations)
    assert np.abs(auto.atoms.positions - jacobi.atoms.positions).max() < 1e-10
    assert np.abs(unit(auto.atoms.get_initial_magnetic_moments())
                  - unit(jacobi.atoms.get_initial_magnetic_moments())).max() < 1e-9


@pytest.mark.parametrize("nthreads_kernel", ["parallel", "serial"])
def test_bath_kernels_equal_the_spin_by_spin_formulas(nthreads_kernel):
    """bath_block and damp_from (a branch-free SIMD loop plus a one-by-one loop
    for large damping angles, zero fields and non-magnetic rows) give the same
    bits as the per-spin flows _damped and _diffused applied one spin at a time,
    bath_block leaving its input as it was; with w = 1 it damps about
    2B − B0, to the bit; damp_from with the predictor's kick the same spins,
    the kick, and B kept."""
    from ase_spin.md.kernels import bath as lg
    from ase_spin.md.gaussian import normal
    rng = np.random.default_rng(3)
    n = 600  # three blocks, the last one partial
    s = rng.normal(size=(n, 3))
    s /= np.linalg.norm(s, axis=1)[:, None]
    s[4] = [1.0, 0.0, 0.0]  # both tangent bases of _diffused
    s[5] = [0.0, 1.0, 0.0]
    B = rng.normal(size=(n, 3))
    B[7] = 0.0  # no field: no damping
    k1 = rng.uniform(0.0, 0.02, n)
    k1[[9, 300]] = 0.5  # large angles: the expm1 form
    k1[10] = 0.0
    k2 = rng.uniform(0.0, 0.02, n)
    k2[[11, 599]] = 2.0
    sigma = rng.uniform(0.0, 0.1, n)
    sigma[12] = 0.0
    magnetic = np.ones(n, dtype=bool)
    magnetic[13] = False
    s[13] = 0.0
    key = np.uint64(12345)
    bath = getattr(lg.bath_block, nthreads_kernel)
    damp = getattr(lg.damp_from, nthreads_kernel)
    start = s.copy()
    got, before = np.full_like(s, 7.0), np.full_like(s, 7.0)
    bath(start, got, before, B, B, 0.0, k1, sigma, key, k2, magnetic)
    np.testing.assert_array_equal(start, s)
    # w = 1: the field 2B − B0 formed row by row, the same bits as stored
    Bbar, B0 = rng.normal(size=(2, n, 3))
    Bbar[7], B0[7] = 1.0, 2.0  # a zero field F there still
    got1, before1 = np.full_like(s, 7.0), np.full_like(s, 7.0)
    bath(start, got1, before1, Bbar, B0, 1.0, k1, sigma, key, k2, magnetic)
    F = 2.0 * Bbar - B0
    got2, before2 = np.full_like(s, 7.0), np.full_like(s, 7.0)
    bath(start, got2, before2, F, F, 0.0, k1, sigma, key, k2, magnetic)
    np.testing.assert_array_equal(got1, got2)
    np.testing.assert_array_equal(before1, before2)
    damped = np.full_like(s, 7.0)
    none = np.empty((0, 3))
    damp(s, B, k1, magnetic, damped, none, np.empty(0), none, none)
    # with the predictor's kick: the same damped spins, and the kick, B kept
    y0, c = rng.normal(size=(n, 3)), rng.uniform(0.0, 0.1, n)
    damped2, kick, keep = (np.full_like(s, 7.0) for _ in range(3))
    damp(s, B, k1, magnetic, damped2, y0, c, kick, keep)
    np.testing.assert_array_equal(damped2, damped)
    np.testing.assert_array_equal(keep, B)
    np.testing.assert_allclose(kick, (damped - y0) + c[:, None] * np.cross(damped, B),
                               rtol=0, atol=1e-15)
    want, want_before, want_damped = s.copy(), np.full_like(s, 7.0), np.full_like(s, 7.0)
    for i in np.flatnonzero(magnetic):
        bx, by, bz, b = lg._direction(B, i)
        x, y, z = lg._damped(*s[i], bx, by, bz, k1[i] * b)
        x, y, z = lg._diffused(x, y, z, sigma[i], normal(key, 2 * i), normal(key, 2 * i + 1))
        want_before[i] = x, y, z
        want[i] = lg._damped(x, y, z, bx, by, bz, k2[i] * b)
        want_damped[i] = lg._damped(*s[i], bx, by, bz, k1[i] * b)
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(before, want_before)
    np.testing.assert_array_equal(damped, want_damped)
    assert np.all(got[13] == 0.0) and np.all(before[13] == 7.0)
    assert np.abs(got1 - got).max() > 1e-3  # (another field: other spins)
    np.testing.assert_allclose(np.linalg.norm(got[magnetic], axis=1), 1.0, atol=4e-16)


def energy_at(atoms, spins):
    """The calculator's potential energy of ``atoms`` with its spins set to the
    unit vectors ``spins`` (moments' lengths kept), the Atoms left as they are."""
    mu = np.linalg.norm(atoms.get_initial_magnetic_moments(), axis=1)
    probe = atoms.copy()
    probe.calc = atoms.calc
    probe.set_initial_magnetic_moments(mu[:, None] * spins)
    return probe.get_potential_energy()


@pytest.mark.parametrize("exchange_alone", [False, True])
def test_bath_energy_is_the_energy_change_of_the_bath(exchange_alone):
    """The spin bath's energy (exchange from −x·Cδ − ½ δ·Cδ in one pass
    after the move, the single-site terms from their energies at y) equals
    E(y) − E(x) evaluated afresh by the calculator at the spins before (x) and
    after (y) the bath, positions fixed: the opening half alone (with a field
    and an anisotropy), and, with exchange alone, both halves between two
    steps (the closing half's energy is counted by the next opening half, x
    the spins before the closing half) — and that closing half's energy alone
    as :meth:`get_bath_energy` reads it in between."""
    from ase_spin.scenes import field_anisotropy_terms
    extra = () if exchange_alone else field_anisotropy_terms()
    atoms = fcc_cobalt(2, extra=extra)
    dyn = Langevin(atoms, 0.5 * units.fs, 1500.0, spin_damping=0.4, friction=0.0, rng=5)
    dyn.run(3)
    st = dyn._state
    assert (st.bath_from is not None) == exchange_alone
    x = (st.bath_from if exchange_alone else st.s).copy()
    if exchange_alone:  # the closing half's energy, as read between two steps
        read = dyn.get_bath_energy() - dyn.bath_energy_spin
        exact = energy_at(atoms, st.s) - energy_at(atoms, x)
        assert abs(read) > 1e-4 and abs(read - exact) < 1e-12 * len(atoms), (read, exact)
    before = dyn.bath_energy_spin
    dyn._opening_bath()
    y = st.s.copy()
    assert np.abs(y - x).max() > 1e-3  # the bath did move the spins
    change = dyn.bath_energy_spin - before
    exact = energy_at(atoms, y) - energy_at(atoms, x)
    assert abs(change) > 1e-3
    assert abs(change - exact) < 1e-12 * len(atoms), (change, exact)


def test_field_at_a_steps_end_from_its_midpoint_fields(monkeypatch):
    """With exchange the only spin term, the closing bath half takes the field
    at the step's end x from the solve's midpoint fields, 2 B̄ − B(y₀) (no
    pass over the pairs): within O(h²) of B(x) (B̄ alone is O(h) off: 2.1e-2
    at 0.5 fs here)."""
    from conftest import general_path_only
    general_path_only(monkeypatch)
    errors = []
    for dt in (0.5, 0.25):
        atoms = fcc_cobalt(2)  # exchange alone among the spin terms
        dyn = Langevin(atoms, dt * units.fs, 1500.0, spin_damping=0.4, friction=0.0, rng=5)
        dyn.run(3)
        st = dyn._state
        dyn._step(count=True)
        x = st.bath_from  # the spins at the step's end, before the closing half
        assert x is not None
        end = 2.0 * st.field_buffer - st.B_y0  # as bath_block forms it (w = 1)
        exact = np.zeros_like(x)
        st.ops[0].field(x, exact)
        errors.append(np.abs(end - exact).max() / np.abs(exact).max())
    assert 0.0 < errors[0] < 8e-3 and errors[0] / errors[1] > 2.4, errors


@pytest.mark.filterwarnings("ignore::ase_spin.md.errors.TimestepWarning")
def test_pairs_sampled_with_the_end_field_from_the_midpoint(monkeypatch):
    """Exchange-coupled pairs, no field (exchange the only spin term), sampled
    every 4th step: every step takes the field at its end from its midpoint
    fields (Langevin._closing_bath). ⟨s₁·s₂⟩ (exact: coth j − 1/j, j = J/k_B T
    = 2) and ⟨s₁·ẑ⟩ (0) have the biases of the same run with that field from a
    pass over the pairs, within Z standard errors, at ωh = 0.4 (where the
    scheme's own bias in ⟨s₁·s₂⟩ is −0.007: docs/thermostats.md); 1024 pairs,
    3000 steps."""
    b, se = stationary_bias(0.4, per=1024, steps=3000, dimer_j=2.0, x=0.0, interval=4)
    monkeypatch.setattr(Langevin, "_end_field_from_midpoint", False)
    b_pass, se_pass = stationary_bias(0.4, per=1024, steps=3000, dimer_j=2.0, x=0.0,
                                      interval=4)
    assert np.all(se < 1e-3) and np.all(se_pass < 1e-3), (se, se_pass)
    assert np.all(np.abs(b - b_pass) < Z * np.hypot(se, se_pass)), (b, b_pass, se)
    assert np.all(np.abs(b) < 0.015), b  # (second order: −0.018 at ωh = 0.8, x = 1)


def test_midpoint_predictor_sees_the_bath_moves():
    """The predictor's field B(y₀) + C k carries the neighbours' moves that the
    noise makes unpredictable from the last steps: 3 midpoint sweeps a step at
    300 K and 0.1 fs, where extrapolation alone needed 4 (docs/thermostats.md)."""
    atoms = fcc_cobalt(3)
    dyn = Langevin(atoms, 0.1 * units.fs, 300.0, spin_damping=0.1,
                   friction=0.01 / units.fs, rng=2)
    dyn.run(30)
    sweeps, steps = dyn.total_iterations, dyn.total_steps
    dyn.run(40)
    assert (dyn.total_iterations - sweeps) / (dyn.total_steps - steps) <= 3.1


@pytest.mark.parametrize("twin", ["parallel", "serial"])
def test_predictor_kernel_equals_the_spin_by_spin_formula(twin):
    """predict_midpoint (blocks of SIMD lanes) gives the bits of the per-spin
    formula: the frozen-field (Cayley) midpoint plus the extrapolated
    remainders, normalised; rows without spin 0."""
    from ase_spin.md.kernels import bath as lg
    rng = np.random.default_rng(4)
    n = 530
    s = rng.normal(size=(n, 3))
    s /= np.linalg.norm(s, axis=1)[:, None]
    s[[3, 300]] = 0.0
    B = rng.normal(size=(n, 3))
    c = rng.uniform(0.0, 0.2, n)
    R = [1e-4 * rng.normal(size=(n, 3)) for _ in range(4)]
    coef = np.array([3.0, -3.0, 1.0, 0.0])
    out, known = np.full_like(s, 7.0), np.full_like(s, 7.0)
    getattr(lg.predict_midpoint, twin)(s, B, c, *R, coef, out, known)
    for i in range(n):
        if not s[i].any():
            assert not out[i].any() and not known[i].any()
            continue
        k = lg._frozen_field_midpoint(*s[i], *B[i], c[i])
        v = [k[a] + (coef[0] * R[0][i, a] + coef[1] * R[1][i, a] + coef[2] * R[2][i, a]
                     + coef[3] * R[3][i, a]) for a in range(3)]
        np.testing.assert_array_equal(known[i], k)
        np.testing.assert_array_equal(out[i], lg._unit(*v))
    # the frozen-field midpoint is the unit solution of W ∝ s + c W × B
    spin = np.flatnonzero(s.any(axis=1))
    W = known[spin]
    rhs = s[spin] + c[spin, None] * np.cross(W, B[spin])
    np.testing.assert_allclose(np.linalg.norm(W, axis=1), 1.0, atol=4e-16)
    np.testing.assert_allclose(np.cross(W, rhs), 0.0, atol=1e-15)
    assert np.all(np.einsum("ij,ij->i", W, rhs) > 0.0)


@pytest.mark.parametrize("half", [True, False])
def test_linear_field_and_form_on_half_and_full_lists(half):
    """kernels.linear_field_and_form: out += C u, d·C d and x·C d in one pass,
    equal to the exchange operator's own field (C u, C d) on either pair list."""
    from ase_spin._jit import threads
    from ase_spin.md import kernels
    atoms = fcc_cobalt(2)
    ev, _ = atoms.calc.bound_evaluator(atoms)
    (op,) = ev.spin_operators(atoms.positions, half=half)
    pairs, c = op.linear_pairs()
    assert pairs.half == half
    rng = np.random.default_rng(1)
    u, y, x = rng.normal(size=(3, len(atoms), 3))
    d = y - x
    out = np.ones((len(atoms), 3))
    form, cross = kernels.linear_field_and_form(threads.count(), pairs.row, pairs.j, c,
                                                pairs.half, u, y, x, out)
    Cu, Cd = np.zeros_like(u), np.zeros_like(d)
    op.field(u, Cu)
    op.field(d, Cd)
    np.testing.assert_allclose(out, 1.0 + Cu, rtol=0, atol=1e-14)
    assert abs(form - np.einsum("ij,ij->", d, Cd)) < 1e-12 * abs(form)
    assert abs(cross - np.einsum("ij,ij->", x, Cd)) < 1e-12 * np.abs(x).sum() * np.abs(Cd).max()


def _early_run(monkeypatch, early, friction, steps, fail_at=None):
    """A Langevin run on the general path (fcc Co, 32 atoms, exchange alone),
    with the closing bath half's spin move done with each step's end forces
    (``early``, the default) or after them; ``fail_at``: the n-th opening bath
    raises. Returns the Atoms' arrays, the bath energies, the rng state, and
    how many steps did the early work."""
    from conftest import general_path_only
    from ase_spin.terms import exchange

    calls = [0]
    with monkeypatch.context() as m:
        general_path_only(m)
        if not early:
            for name in ("_end_forces", "_round_forces", "_finish_round", "_drop_round"):
                m.setattr(Langevin, name, getattr(ase_spin.CollectivePRK, name))
        forces_and_field = exchange.ExchangeOperator.forces_and_field
        finish = Langevin._finish_round

        def spy(self, *args):
            calls[0] += 1
            return forces_and_field(self, *args)

        def spy_finish(self, pending):  # the bath begun in the pass of the last round
            calls[0] += len(pending) > 1
            return finish(self, pending)

        m.setattr(exchange.ExchangeOperator, "forces_and_field", spy)
        if early:
            m.setattr(Langevin, "_finish_round", spy_finish)
        opening = Langevin._opening_bath
        openings = [0]

        def fail(self):
            openings[0] += 1
            if openings[0] == fail_at:
                raise RuntimeError("a step that fails")
            return opening(self)

        m.setattr(Langevin, "_opening_bath", fail)
        atoms = fcc_cobalt(2, temperature_K=300)
        dyn = Langevin(atoms, 0.2 * units.fs, 300.0, spin_damping=0.2,
                       friction=friction / units.fs, rng=11)
        try:
            dyn.run(steps)
        except RuntimeError:
            assert fail_at is not None
        out = [atoms.positions.copy(), atoms.get_momenta(), ase_spin.get_spins(atoms),
               np.array([dyn.bath_energy_lattice, dyn.bath_energy_spin])]
        return out, dyn.rng.bit_generator.state, calls[0]


@pytest.mark.parametrize("friction", [0.0, 0.01])
def test_bath_begun_with_the_end_forces_changes_no_bit(monkeypatch, friction):
    """With exchange alone, the closing bath half's spin move m = N D s̃ and
    the fields B(m) are made with the step's end forces, in their pass over
    the pairs (Langevin._end_forces, ExchangeOperator.forces_and_field; or,
    begun in the last outer round's pass with the forces at q too,
    Langevin._round_forces, ExchangeOperator.forces_here_and_there, the keys
    put back when that round does not settle the step): the run is the same
    to the bit as with that work done after them (the keys drawn in the same
    order, lattice then spins); and a step that fails puts the rng back to
    the step's start and counts the last closing half's bath energy, as
    without it."""
    got, state, calls = _early_run(monkeypatch, True, friction, 12)
    want, want_state, none = _early_run(monkeypatch, False, friction, 12)
    assert calls == 12 and none == 0  # every step, the last one too
    for a, b in zip(got, want):
        np.testing.assert_array_equal(a, b)
    assert state == want_state
    # the 7th step fails in its opening bath, after the 6th's closing half
    got, state, calls = _early_run(monkeypatch, True, friction, 12, fail_at=7)
    want, want_state, _ = _early_run(monkeypatch, False, friction, 12, fail_at=7)
    assert calls == 6
    for a, b in zip(got, want):
        np.testing.assert_array_equal(a, b)
    assert state == want_state


def test_a_failed_step_keeps_the_bath_energy_of_the_step_before(monkeypatch):
    """With exchange alone the closing bath half's spin energy is counted by
    the next opening half (or when read): a step that fails after it has
    taken that energy over leaves the bath energy as it read before the step,
    as do a reading in between and a change of the Atoms (the state let go)."""
    atoms = fcc_cobalt(2, temperature_K=300)
    dyn = Langevin(atoms, 0.2 * units.fs, 300.0, spin_damping=0.2,
                   friction=0.01 / units.fs, rng=11)
    dyn.run(6)
    assert dyn._state.bath_from is not None
    before = dyn.get_bath_energy()
    assert before != dyn.bath_energy_lattice + dyn.bath_energy_spin
    state = dyn.rng.bit_generator.state
    opening = Langevin._opening_bath

    def fail(self):
        opening(self)  # the pending energy taken over, then the step fails
        raise RuntimeError("a step that fails")

    monkeypatch.setattr(Langevin, "_opening_bath", fail)
    with pytest.raises(RuntimeError):
        dyn.run(1)
    monkeypatch.setattr(Langevin, "_opening_bath", opening)
    assert dyn.rng.bit_generator.state == state and dyn.nsteps == 6
    assert abs(dyn.get_bath_energy() - before) < 1e-13 * len(atoms)
    dyn.run(2)
    assert dyn._state.bath_from is not None
    before = dyn.get_bath_energy()
    set_spins(atoms, ase_spin.get_spins(atoms))  # the Atoms changed: a new state
    assert abs(dyn.get_bath_energy() - before) < 1e-13 * len(atoms)
    assert dyn._state.bath_from is None


@pytest.mark.parametrize("extra", [False, True], ids=["exchange", "field_anisotropy"])
def test_interrupt_anywhere_in_a_step_continues_the_run(extra):
    """A KeyboardInterrupt at the k-th line executed in ase_spin during a step
    (every 29th k until the step completes, tests/fuzz.py's campaign): the
    Atoms, nsteps, the generator and the bath energy are all before the step
    or all after it, and running on reaches the uninterrupted run (to the
    midpoint iteration's tolerance: the predictor's history is lost with the
    step), its bath energy too. With exchange alone the closing half's energy
    is counted late (bath_from) and its move made with the end forces: an
    interrupt between the two halves must neither drop nor double it."""
    from fuzz import langevin_interrupt_campaign

    result = langevin_interrupt_campaign(extra, stride=29)
    assert result["mixed"] == 0 and result["points"] > 20, result
    assert result["worst"] <= 10 * NOISY_TOL, result  # (the bath energy's too, in eV)


def test_bath_parameters_changed_between_runs_take_effect_and_are_checked():
    """λ changed between runs: the steps to come precess at r_i/(1+λ²) of the
    new λ — the run continues as a new Langevin with that λ from the same
    Atoms and generator would. NaN, infinite or negative λ, γ, k_B T set as
    attributes are refused (they would switch a bath off without a word), and
    the integrator keeps its values."""
    def make(damping, rng):
        atoms = co_scene()
        return atoms, Langevin(atoms, 0.5 * units.fs, 300.0, spin_damping=damping,
                               friction=0.01 / units.fs, rng=rng)

    atoms, dyn = make(0.05, 3)
    dyn.run(5)
    dyn.spin_damping = 0.5
    state = dyn.rng.bit_generator.state
    copy = atoms.copy()
    copy.calc = SpinLatticeCalculator(atoms.calc.hamiltonian.terms)
    rng = np.random.default_rng()
    rng.bit_generator.state = state
    fresh = Langevin(copy, 0.5 * units.fs, 300.0, spin_damping=0.5, friction=0.01 / units.fs,
                     rng=rng)
    dyn.run(5)
    fresh.run(5)
    assert dyn._state.rate[0] == fresh._state.rate[0]
    np.testing.assert_allclose(atoms.get_initial_magnetic_moments(),
                               copy.get_initial_magnetic_moments(), rtol=0, atol=1e-9)
    for name, value in [("spin_damping", np.nan), ("spin_damping", -0.1), ("fr", np.inf),
                        ("fr", -1.0), ("temp", np.nan), ("spin_temp", -0.01)]:
        kept = getattr(dyn, name)
        with pytest.raises(ValueError, match="finite|>= 0"):
            setattr(dyn, name, value)
        assert getattr(dyn, name) == kept
