"""Monte Carlo (ase_spin.MonteCarlo): the exact energy change of single moves
for every spin term, the paramagnet's Langevin function, the Heisenberg
model's T_C from Binder crossings, agreement with the Langevin thermostat,
reproducibility and the refusals."""

import numpy as np
import pytest
from ase import units
from ase.build import bulk

import ase_spin
from ase_spin import (CubicAnisotropy, Dipolar, FixSpins, Langevin, MonteCarlo,
                      ShellExchange, SpinLatticeCalculator, Zeeman)
from ase_spin.analysis import Fluctuations, SpinTemperature, binder_crossing

from conftest import random_spins, structures
from test_term_contract import TERMS

SPIN_TERMS = [(name, make) for name, make in TERMS if make().spin_dependent]
SPIN_TERMS.append(("dipolar-cut", lambda: Dipolar(4.5)))

A_SC = 2.5   # Å
J_SC = 0.01  # eV, nearest neighbours of the simple cubic lattice
#: Chen, Ferrenberg and Landau, PRB 48, 3249 (1993): K_c = J/k_B T_c = 0.693035(37)
TC_HEISENBERG = 1.0 / 0.693035


def heisenberg(L, seed=0):
    atoms = bulk("Fe", "sc", a=A_SC).repeat(L)
    ase_spin.set_spins(atoms, [0, 0, 1], magnitudes=2.0)
    atoms.calc = SpinLatticeCalculator([ShellExchange([(A_SC, J_SC)])])
    return atoms


def co_scene(term, seed=3):
    atoms = bulk("Co", "fcc", a=3.54, cubic=True).repeat(2)
    atoms.rattle(0.05, seed=seed)
    rng = np.random.default_rng(seed)
    ase_spin.set_spins(atoms, random_spins(len(atoms), rng),
                       magnitudes=rng.uniform(0.5, 3.0, len(atoms)))
    atoms.calc = SpinLatticeCalculator([term])
    return atoms


@pytest.mark.parametrize("name,make", SPIN_TERMS, ids=[t[0] for t in SPIN_TERMS])
def test_single_move_energy_is_the_full_energy_difference(name, make):
    """ΔE_i of every spin of a colour, from one pair of passes over the colour
    moved at once, equals E(spin i moved alone) − E for every spin term."""
    atoms = co_scene(make())
    mc = MonteCarlo(atoms, temperature_K=100.0, seed=1)
    s = ase_spin.get_spins(atoms)
    e0 = atoms.get_potential_energy()
    mu = np.linalg.norm(atoms.get_initial_magnetic_moments(), axis=1)
    rng = np.random.default_rng(5)
    assert sum(len(c) for c in mc.colours) == len(atoms)
    for colour in range(min(2, len(mc.colours))):
        atoms_c = mc.colours[colour]
        trial = s.copy()
        trial[atoms_c] = random_spins(len(atoms_c), rng)
        dE = mc.energy_changes(trial, colour)
        for a, i in enumerate(atoms_c[:4]):
            moved = s.copy()
            moved[i] = trial[i]
            ase_spin.set_spins(atoms, moved, magnitudes=mu)
            full = atoms.get_potential_energy() - e0
            assert dE[a] == pytest.approx(full, rel=1e-9, abs=1e-12 * (1 + abs(e0)))
        ase_spin.set_spins(atoms, s, magnitudes=mu)


def test_terms_coupling_one_colour_are_refused():
    """A dipolar coupling of an atom with its own periodic images (a cell
    smaller than the cutoff) depends on its direction: not local, refused,
    the Atoms untouched."""
    atoms = structures()["tiny2"]
    ase_spin.set_spins(atoms, random_spins(2, np.random.default_rng(0)), magnitudes=2.0)
    atoms.calc = SpinLatticeCalculator([Dipolar(6.0)])
    mc = MonteCarlo(atoms, temperature_K=100.0, seed=1)
    spins_before = atoms.get_initial_magnetic_moments().copy()
    with pytest.raises(ValueError, match="local on their pair list"):
        mc.run(1)
    assert np.array_equal(atoms.get_initial_magnetic_moments(), spins_before)


def test_bad_input_is_refused():
    atoms = heisenberg(2)
    for kw, err in [({"temperature_K": -1.0}, ValueError), ({"temperature_K": "300"}, TypeError),
                    ({"temperature_K": 10.0, "cone_angle": 4.0}, ValueError),
                    ({"temperature_K": 10.0, "seed": 1.5}, TypeError),
                    ({"temperature_K": 10.0, "acceptance": 1.0}, ValueError)]:
        with pytest.raises(err):
            MonteCarlo(atoms, **kw)
    atoms.calc = None
    with pytest.raises(TypeError, match="SpinLatticeCalculator"):
        MonteCarlo(atoms, temperature_K=10.0)


def test_overrelaxation_refused_for_nonlinear_terms():
    atoms = co_scene(CubicAnisotropy(0.01))
    mc = MonteCarlo(atoms, temperature_K=100.0, seed=1, overrelaxation=1)
    with pytest.raises(ValueError, match="overrelaxation changed the energy"):
        mc.run(1)


def test_reproducible_with_a_seed_and_pinned_spins_stay():
    runs = []
    for _ in range(2):
        atoms = heisenberg(3)
        atoms.set_constraint(FixSpins([0, 5]))
        mc = MonteCarlo(atoms, temperature_K=150.0, seed=42, overrelaxation=1)
        mc.run(20)
        runs.append(atoms.get_initial_magnetic_moments().copy())
    assert np.array_equal(runs[0], runs[1])
    assert np.allclose(runs[0][[0, 5]], [0, 0, 2.0])
    assert not np.allclose(runs[0][1], [0, 0, 2.0])


def _langevin_function(x):
    return 1.0 / np.tanh(x) - 1.0 / x


def test_paramagnet_in_a_field_follows_the_langevin_function():
    """Free moments μ in a field H: ⟨s·Ĥ⟩ = L(μ μB H/k_B T), for two
    moments at once (sites do not interact: one colour), within 4 σ; the
    cone adapts to acceptance near 0.5; the spin temperature is T."""
    atoms = bulk("Fe", "sc", a=3.0).repeat((10, 10, 4))
    mu = np.where(np.arange(len(atoms)) % 2 == 0, 1.0, 3.0)
    ase_spin.set_spins(atoms, [1, 0, 0], magnitudes=mu)
    H, T = 50.0, 15.0
    atoms.calc = SpinLatticeCalculator([Zeeman(H, [0, 0, 1])])
    mc = MonteCarlo(atoms, temperature_K=T, seed=7, adapt_sweeps=50)
    mc.run(100)
    assert abs(mc.acceptance - 0.5) < 0.1
    sz = []
    temperature = SpinTemperature(mc)
    mc.attach(lambda: sz.append([ase_spin.get_spins(atoms)[mu == m, 2].mean() for m in (1, 3)]))
    mc.attach(temperature)
    mc.run(400)
    sz = np.array(sz)
    for k, m in enumerate((1.0, 3.0)):
        mean, err = ase_spin.block_average(sz[:, k])
        expected = _langevin_function(m * ase_spin.MU_B * H / (units.kB * T))
        assert abs(mean - expected) < 4 * err + 1e-4, (m, mean, err, expected)
    ts = temperature.temperature()
    assert abs(ts.value - T) < 4 * ts.error


def _binder_curves(sizes, temperatures, sweeps, discard, seed=0):
    U, dU, M = {}, {}, {}
    for L in sizes:
        U[L], dU[L], M[L] = [], [], []
        for k, T in enumerate(temperatures):
            atoms = heisenberg(L)
            mc = MonteCarlo(atoms, temperature_K=T, seed=seed + 1000 * L + k,
                            overrelaxation=2, adapt_sweeps=discard)
            mc.run(discard)
            obs = Fluctuations(mc)
            mc.attach(obs, interval=1)
            mc.run(sweeps)
            u = obs.binder_cumulant(discard=1)
            U[L].append(u.value)
            dU[L].append(u.error)
            M[L].append(obs.magnetisation(discard=1).value)
    return U, dU, M


def test_heisenberg_curie_temperature_coarse():
    """Binder cumulants of L = 4 and 6 cross near T_C = 1.443 J/k_B (Chen,
    Ferrenberg and Landau) within 5 % (the 1 % check with larger sizes is
    slow); |M| falls with T."""
    tc = TC_HEISENBERG * J_SC / units.kB
    temperatures = tc * np.array([0.92, 1.0, 1.08])
    U, dU, M = _binder_curves((4, 6), temperatures, sweeps=1000, discard=100)
    estimate, _ = binder_crossing(temperatures, U, dU)
    assert abs(estimate.value / tc - 1) < 0.05, (estimate, tc)
    assert M[6][0] > M[6][1] > M[6][2]


@pytest.mark.slow
def test_heisenberg_curie_temperature_within_one_percent():
    tc = TC_HEISENBERG * J_SC / units.kB
    temperatures = tc * np.array([0.98, 1.0, 1.02])
    U, dU, _ = _binder_curves((8, 12, 16), temperatures, sweeps=6000, discard=200)
    estimate, pairs = binder_crossing(temperatures, U, dU)
    assert abs(estimate.value / tc - 1) < 0.01 + 2 * estimate.error / tc, (estimate, pairs, tc)
    assert abs(estimate.value / tc - 1) < 0.01


def test_monte_carlo_and_langevin_agree():
    """The same small Heisenberg magnet (64 spins, 0.6 T_C) sampled by Monte
    Carlo and by the Langevin thermostat on a frozen lattice: ⟨E⟩ and ⟨|M|⟩
    agree within 4 combined standard errors."""
    T = 0.6 * TC_HEISENBERG * J_SC / units.kB
    atoms = heisenberg(4)
    mc = MonteCarlo(atoms, temperature_K=T, seed=3)
    mc.run(200)
    obs_mc = Fluctuations(mc)
    mc.attach(obs_mc, interval=2)
    mc.run(4000)
    atoms = heisenberg(4)
    dyn = Langevin(atoms, 2.0 * units.fs, temperature_K=T, spin_damping=0.5, friction=0.0,
                   lattice="frozen", rng=4)
    dyn.run(300)
    obs_md = Fluctuations(dyn)
    dyn.attach(obs_md, interval=4)
    dyn.run(8000)
    for what in ("energy", "magnetisation"):
        a, b = getattr(obs_mc, what)(), getattr(obs_md, what)()
        assert abs(a.value - b.value) < 4 * np.hypot(a.error, b.error), (what, a, b)
