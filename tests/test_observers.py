"""Observers (ase_spin.analysis): topological charge, sublattice
magnetisation, correlations, fluctuations; the blocking statistics."""

import numpy as np
import pytest
from ase import Atoms, units
from ase.build import bulk

import ase_spin
from ase_spin import (DMI, CollectivePRK, Cubic, Exchange, MonteCarlo, ShellExchange,
                      SpinLatticeCalculator, Zeeman)
from ase_spin.analysis import (Fluctuations, LayerTriangulation, SpinCorrelation,
                               SublatticeMagnetisation, TopologicalCharge,
                               autocorrelation_time, binder_crossing, block_average, jackknife,
                               topological_charge)

A = 2.5


def layer(n, lattice="square"):
    if lattice == "square":
        ij = np.array([(i, j) for j in range(n) for i in range(n)], dtype=float)
        atoms = Atoms(f"Fe{n * n}", positions=np.column_stack([ij * A, np.zeros(n * n)]),
                      cell=[n * A, n * A, 10.0], pbc=[True, True, False])
    else:  # triangular, a hexagonal cell, rattled: Delaunay on any positions
        atoms = Atoms(f"Fe{n * n}", cell=[[n * A, 0, 0], [-n * A / 2, n * A * 3 ** 0.5 / 2, 0],
                                          [0, 0, 10.0]], pbc=True,
                      scaled_positions=[(i / n, j / n, 0.0) for j in range(n) for i in range(n)])
        atoms.rattle(0.05, seed=2)
        atoms.positions[:, 2] = 0.0
    return atoms


def skyrmion(atoms, radius=3 * A, centre=None):
    xy = atoms.positions[:, :2]
    if centre is None:
        centre = atoms.cell.array[:2, :2].sum(axis=0) / 2
    d = xy - centre
    rho = np.linalg.norm(d, axis=1)
    theta = 2.0 * np.arctan2(radius, rho)
    radial = d / np.where(rho > 0, rho, 1.0)[:, None]
    return np.column_stack([np.sin(theta)[:, None] * radial, np.cos(theta)])


@pytest.mark.parametrize("lattice", ["square", "triangular"])
def test_topological_charge_of_a_skyrmion_and_a_ferromagnet(lattice):
    atoms = layer(20, lattice)
    tri = LayerTriangulation(atoms)
    assert len(tri.triangles) == 2 * len(atoms)  # a periodic triangulation: 2 per site
    s = skyrmion(atoms)
    assert tri.charge(s) == pytest.approx(-1.0, abs=1e-10)
    assert tri.charge(-s) == pytest.approx(1.0, abs=1e-10)       # core up, background down
    assert LayerTriangulation(atoms, normal=[0, 0, -1]).charge(s) == pytest.approx(1.0, abs=1e-10)
    assert tri.charge(np.tile([0.3, 0.2, 0.9], (len(atoms), 1))) == 0.0
    rng = np.random.default_rng(1)
    random = rng.normal(size=(len(atoms), 3))
    random /= np.linalg.norm(random, axis=1)[:, None]
    q = tri.charge(random)  # any spins on a closed surface: an integer
    assert q == pytest.approx(round(q), abs=1e-9)
    ase_spin.set_spins(atoms, s)
    assert topological_charge(atoms) == pytest.approx(-1.0, abs=1e-10)


def test_topological_charge_is_kept_by_the_dynamics():
    """A Néel skyrmion (exchange, DMI, field) integrated 300 fs on a frozen
    lattice: Q = −1 at every observed step, to 1e-8."""
    atoms = layer(16)
    ase_spin.set_spins(atoms, skyrmion(atoms), magnitudes=2.2)
    J0 = 0.010 / (1.0 - A / 3.0) ** 3
    atoms.calc = SpinLatticeCalculator([Exchange(Cubic(J0, 3.0)), DMI(0.003, [0, 0, 1], rc=3.0),
                                        Zeeman(2.0, [0, 0, 1])])
    dyn = CollectivePRK(atoms, 1.0 * units.fs, lattice="frozen")
    q = TopologicalCharge(dyn, info=True)
    dyn.attach(q, interval=50)
    dyn.run(300)
    assert len(q.series) == 7
    assert np.allclose(q.series, -1.0, atol=1e-8)
    assert atoms.info["topological_charge"] == q.series[-1]
    assert not np.allclose(ase_spin.get_spins(atoms), skyrmion(atoms))  # it did move


def test_layer_errors():
    atoms = layer(4)
    with pytest.raises(ValueError, match="at least 3"):
        LayerTriangulation(atoms, indices=[0, 1])
    two = atoms + atoms  # two layers on top of each other
    with pytest.raises(ValueError, match="in no triangle"):
        LayerTriangulation(two)


def test_sublattice_magnetisation_of_an_antiferromagnet():
    """Two sublattices by tag, antiparallel: m_A = −m_B exactly; a
    non-magnetic species is left out; with Monte Carlo at low T |m_α| ≈ 1."""
    atoms = bulk("Fe", "sc", a=A).repeat((4, 4, 4))
    parity = np.indices((4, 4, 4)).reshape(3, -1).T.sum(axis=1) % 2
    atoms.set_tags(parity)
    ase_spin.set_spins(atoms, np.where(parity[:, None] == 0, [0, 0, 1], [0, 0, -1]),
                       magnitudes=2.0)
    atoms.calc = SpinLatticeCalculator([ShellExchange([(A, -0.01)])])
    mc = MonteCarlo(atoms, temperature_K=5.0, seed=0)
    obs = SublatticeMagnetisation(mc, by="tags")
    mc.attach(obs)
    mc.run(20)
    m = obs.series
    assert m.shape == (21, 2, 3)
    assert np.allclose(m[0], [[0, 0, 1], [0, 0, -1]])
    assert np.allclose(m[:, 0], -m[:, 1], atol=0.05)
    for e in obs.magnitudes(discard=5):
        assert 0.95 < e.value < 1.0
    with pytest.raises(ValueError, match="one label per atom"):
        SublatticeMagnetisation(mc, by=[0, 1])


def test_correlations_and_fluctuations_of_the_paramagnet():
    """Independent spins (no coupling, T > 0, no field): C(r) = 0 and ξ = 0
    within errors, χ = N⟨m²⟩/k_BT = 1/(k_B T) per spin (m a 3-vector), U = 4/9, C_V = 0."""
    atoms = bulk("Fe", "sc", a=A).repeat(6)
    ase_spin.set_spins(atoms, [0, 0, 1], magnitudes=1.0)
    atoms.calc = SpinLatticeCalculator([Zeeman(0.0, [0, 0, 1])])
    mc = MonteCarlo(atoms, temperature_K=50.0, seed=1, cone_angle=np.pi, adapt_sweeps=0)
    mc.run(5)
    corr = SpinCorrelation(mc, rmax=1.5 * A)
    fl = Fluctuations(mc)
    mc.attach(corr)
    mc.attach(fl)
    mc.run(400)
    r, C, dC = corr.correlation_function(discard=1)
    assert np.allclose(r, [A, A * 2 ** 0.5])
    assert np.all(np.abs(C) < 4 * dC + 1e-12)
    chi = fl.susceptibility(absolute=False, discard=1)
    assert abs(chi.value - 1 / (units.kB * 50.0)) < 4 * chi.error
    u = fl.binder_cumulant(discard=1)
    assert abs(u.value - 4 / 9) < 4 * u.error
    assert fl.specific_heat(discard=1).value == 0.0
    xi = corr.correlation_length(discard=1)
    assert xi.value < 4 * xi.error + 0.3


def test_observers_every_step_compute_no_calculator_results():
    """An observer at every step of a Langevin run publishes no calculator
    results (no forces or virial computed for it) and measures the same as
    when results are published: a plain function attached beside it is what
    makes the integrator publish them, once per step it is due."""
    from ase_spin import Langevin

    def run(with_function):
        atoms = bulk("Fe", "sc", a=A).repeat(4)
        ase_spin.set_spins(atoms, [0, 0, 1], magnitudes=2.0)
        atoms.calc = SpinLatticeCalculator([ShellExchange([(A, 0.01)])])
        dyn = Langevin(atoms, 2 * units.fs, temperature_K=300, spin_damping=1.0, friction=0.0,
                       lattice="frozen", rng=np.random.default_rng(3))
        published = []
        publish = dyn.publish_results
        dyn.publish_results = lambda: (published.append(dyn.nsteps), publish())[1]
        fl, sub = Fluctuations(dyn), SublatticeMagnetisation(dyn, by=np.arange(len(atoms)) % 2)
        dyn.attach(fl, interval=1)
        dyn.attach(sub, interval=1)
        if with_function:
            dyn.attach(lambda: atoms.get_forces(), interval=2)
        dyn.run(6)
        return published, fl.series, sub.series

    published, fl, sub = run(False)
    assert published == []
    published, fl2, sub2 = run(True)
    assert published == [0, 2, 4, 6]
    assert np.array_equal(fl, fl2) and np.array_equal(sub, sub2)


def test_correlation_length_grows_towards_tc():
    """Heisenberg sc above T_C: ξ at 1.2 T_C is larger than at 2.5 T_C, and
    C(a) falls with r."""
    xis = []
    for f in (2.5, 1.2):
        atoms = bulk("Fe", "sc", a=A).repeat(6)
        ase_spin.set_spins(atoms, [0, 0, 1], magnitudes=1.0)
        atoms.calc = SpinLatticeCalculator([ShellExchange([(A, 0.01)])])
        mc = MonteCarlo(atoms, temperature_K=f * 1.443 * 0.01 / units.kB, seed=2,
                        overrelaxation=1)
        mc.run(100)
        corr = SpinCorrelation(mc, rmax=2.1 * A)
        mc.attach(corr)
        mc.run(300)
        r, C, _ = corr.correlation_function()
        assert C[0] > C[1] > 0
        xis.append(corr.correlation_length())
    assert xis[1].value > xis[0].value + 3 * np.hypot(xis[0].error, xis[1].error)


def test_blocking_finds_the_error_of_a_correlated_series():
    """An AR(1) series x_t = ρ x_{t−1} + noise: the true error of the mean is
    √((1+ρ)/(1−ρ)) times the naive one; blocking finds it within 20 %."""
    rng = np.random.default_rng(0)
    rho, n = 0.9, 2 ** 16
    noise = rng.normal(size=n)
    x = np.empty(n)
    x[0] = noise[0]
    for t in range(1, n):
        x[t] = rho * x[t - 1] + noise[t]
    est = block_average(x)
    sigma = 1 / np.sqrt(1 - rho ** 2)
    true = sigma * np.sqrt((1 + rho) / (1 - rho) / n)
    assert est.error == pytest.approx(true, rel=0.2)
    assert est.error > 3 * x.std() / np.sqrt(n)
    j = jackknife(np.mean, x, blocks=64)
    assert j.value == pytest.approx(x.mean())
    assert j.error == pytest.approx(true, rel=0.3)


def ar1(phi, n, rng, replicas=None):
    """AR(1) series x_t = φ x_{t−1} + noise, started in its stationary
    distribution; (n,) or (replicas, n)."""
    shape = (n,) if replicas is None else (replicas, n)
    noise = rng.normal(size=shape)
    x = np.empty(shape)
    x[..., 0] = noise[..., 0] / np.sqrt(1 - phi ** 2)
    for t in range(1, n):
        x[..., t] = phi * x[..., t - 1] + noise[..., t]
    return x


def test_autocorrelation_time_of_an_ar1_series():
    """AR(1) with φ = 0.8: τ_int = (1 + φ)/(2(1 − φ)) = 4.5 samples. Over 40
    independent series the estimates scatter about 4.5 by about their reported
    error (the Madras–Sokal error is honest), the mean within 3 errors of the
    mean; τ_int agrees with the blocking error, var(mean) = 2 τ var/n; white
    noise gives 1/2; a short series warns; bad input is refused."""
    phi, n = 0.8, 2 ** 13
    exact = (1 + phi) / (2 * (1 - phi))
    x = ar1(phi, n, np.random.default_rng(1), replicas=40)
    est = [autocorrelation_time(row) for row in x]
    values = np.array([e.value for e in est])
    errors = np.array([e.error for e in est])
    assert abs(values.mean() - exact) < 3 * values.std(ddof=1) / np.sqrt(len(values))
    assert values.std(ddof=1) == pytest.approx(errors.mean(), rel=0.35)
    assert 0.05 < errors.mean() / exact < 0.15

    long = ar1(phi, 2 ** 16, np.random.default_rng(2))
    tau = autocorrelation_time(long)
    blocked = block_average(long)
    tau_blocking = 0.5 * (blocked.error / (long.std() / np.sqrt(len(long)))) ** 2
    assert tau_blocking == pytest.approx(tau.value, rel=0.25)

    white = np.random.default_rng(3).normal(size=4096)
    assert autocorrelation_time(white).value == pytest.approx(0.5, abs=0.05)

    with pytest.warns(UserWarning, match="too short"):
        autocorrelation_time(ar1(0.99, 200, np.random.default_rng(4)))
    with pytest.raises(ValueError, match="1D"):
        autocorrelation_time(x[:2])
    with pytest.raises(ValueError, match="constant"):
        autocorrelation_time(np.ones(10))
    with pytest.raises(ValueError, match="c must be"):
        autocorrelation_time(white, c=0)


def test_binder_crossing_of_lines():
    T = np.array([1.0, 1.1, 1.2, 1.3])
    U = {4: 0.6 - 0.2 * (T - 1.15), 8: 0.6 - 0.5 * (T - 1.15), 16: 0.6 - 0.9 * (T - 1.15)}
    est, pairs = binder_crossing(T, U, {L: np.full(4, 1e-3) for L in U})
    assert est.value == pytest.approx(1.15, abs=1e-9)
    assert np.allclose(pairs, 1.15)
    assert 0 < est.error < 0.01
    with pytest.raises(ValueError, match="do not cross"):
        binder_crossing(T, {4: T, 8: T + 1})
