"""Spin terms beyond exchange in the integrators: analytic precession,
convergence to the ODE solution, invariants, one solver for every combination."""

import numpy as np
import pytest
from ase import Atoms, units

from ase_spin import (DMI, G_ELECTRON, HBAR, MU_B, BetheSlater, BiquadraticExchange, Cubic, CollectivePRK, CubicAnisotropy, SpinLatticeCalculator,
                      SuzukiTrotter, UniaxialAnisotropy, Zeeman, get_spins, set_spins)
from ase_spin.md.ode import reference_solution
from ase_spin.scenes import fcc_cobalt, fcc_cobalt_terms

INTEGRATORS = {"collective": CollectivePRK, "splitting": SuzukiTrotter}


def single_spin(terms, s0, mu=1.0):
    atoms = Atoms("Fe", positions=[[0.0, 0.0, 0.0]])
    set_spins(atoms, [s0], [mu])
    atoms.calc = SpinLatticeCalculator(terms)
    return atoms


def rotate(v, axis, angle):
    """v rotated right-handedly about the unit ``axis`` by ``angle`` (Rodrigues)."""
    axis = np.asarray(axis) / np.linalg.norm(axis)
    return (v * np.cos(angle) + np.cross(axis, v) * np.sin(angle)
            + axis * (axis @ v) * (1.0 - np.cos(angle)))


S0 = np.array([np.sin(1.0), 0.0, np.cos(1.0)])  # 57° from the field


@pytest.mark.parametrize("integrator", INTEGRATORS)
@pytest.mark.parametrize("gyromagnetic, mu", [("lammps", 1.0), ("lammps", 2.5),
                                              ("moment", 1.0), ("moment", 2.5)])
def test_larmor_precession(integrator, gyromagnetic, mu):
    """A moment μ in a field H ẑ with the physical Zeeman energy −μ μB s·H
    (g=1) turns right-handedly about ẑ: at the Larmor frequency g_e μB H/ħ
    whatever μ under the moment precession; at μ times μB H/ħ under
    LAMMPS's equation. Order 4 at three step sizes."""
    H = 10.0
    atoms = single_spin([Zeeman(H, [0, 0, 1], g=1.0)], S0, mu)
    omega = (G_ELECTRON if gyromagnetic == "moment" else mu) * MU_B * H / HBAR
    t = 2000 * units.fs  # 3.5 turns at μ = 1
    errors = []
    for n in (25, 50, 100):
        a = atoms.copy()
        a.calc = atoms.calc
        dyn = INTEGRATORS[integrator](a, t / n, gyromagnetic=gyromagnetic, order=4,
                                      lattice="frozen")
        dyn.run(n)
        exact = rotate(S0, [0, 0, 1], omega * t)  # σ = −1: right-handed about B
        errors.append(np.abs(get_spins(a)[0] - exact).max())
    assert 1e-13 < errors[-1] < 1e-6
    assert errors[0] / errors[-1] > 2**4 * 0.8 ** 2  # fourth order


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_anisotropy_along_the_field_shifts_the_frequency(integrator):
    """With E = −K (s·ẑ)² added, s·ẑ = cos θ is conserved and the precession
    rate is (g_e/μ)(μB μ H + 2K cos θ)/ħ (physical conventions)."""
    H, K, mu = 10.0, 4e-4, 2.0
    atoms = single_spin([Zeeman(H, [0, 0, 1]), UniaxialAnisotropy(K, [0, 0, 3])], S0, mu)
    omega = G_ELECTRON / mu * (MU_B * mu * H + 2.0 * K * S0[2]) / HBAR
    t = 10000 * units.fs
    dyn = INTEGRATORS[integrator](atoms, t / 2000, order=6, lattice="frozen")
    dyn.run(2000)
    exact = rotate(S0, [0, 0, 1], omega * t)
    assert omega * t > 20.0  # several turns, 3.5 of them from the anisotropy
    assert np.abs(get_spins(atoms)[0] - exact).max() < 1e-9


def test_moment_precession_rates_scale_as_one_over_mu():
    """Two sublattices, moments 1 and 7 μB, in the same exchange field: under
    the moment precession their spins turn at rates in ratio 7; under LAMMPS's
    equation at equal rates."""
    def initial_rates(gyromagnetic):
        atoms = fcc_cobalt(2, temperature_K=0.0)
        mu = np.where(np.arange(len(atoms)) % 2 == 0, 1.0, 7.0)
        s = get_spins(atoms)
        set_spins(atoms, s, mu)
        B = atoms.calc.get_magnetic_forces(atoms)
        dyn = CollectivePRK(atoms, 1e-4 * units.fs, gyromagnetic=gyromagnetic,
                            lattice="frozen")
        dyn.run(1)
        rate = np.linalg.norm(get_spins(atoms) - s, axis=1) / np.linalg.norm(
            np.cross(s, B), axis=1)
        return rate[mu == 1.0], rate[mu == 7.0]

    one, seven = initial_rates("moment")
    np.testing.assert_allclose(one / seven.mean(), 7.0, rtol=1e-3)
    one, seven = initial_rates("lammps")
    np.testing.assert_allclose(one / seven.mean(), 1.0, rtol=1e-3)


def scene_terms(cubic=True):
    """Exchange, a field, uniaxial anisotropy and DMI; with ``cubic``, also the
    terms whose field on s_i depends on s_i beyond (s_i·n): cubic anisotropy
    and biquadratic exchange."""
    terms = [*fcc_cobalt_terms(), Zeeman([0.0, 20.0, 50.0]),
             UniaxialAnisotropy(2e-3, [1.0, 0.0, 1.0]), DMI(4e-3, [0.0, 0.3, 1.0], rc=2.7)]
    if cubic:
        terms += [CubicAnisotropy(-3e-3, 2e-3),
                  BiquadraticExchange(Cubic(0.01, 2.7), BetheSlater(3e-3, 0.0, 1.4885), rc=2.7)]
    return terms


def mixed_scene(temperature_K=300, cubic=True, conventions="physical"):
    atoms = fcc_cobalt(2, temperature_K=temperature_K)
    mu = np.random.default_rng(3).uniform(1.0, 2.5, len(atoms))
    set_spins(atoms, get_spins(atoms), mu)
    atoms.calc = SpinLatticeCalculator(scene_terms(cubic), conventions=conventions)
    return atoms


def state(atoms):
    return atoms.positions.copy(), atoms.get_momenta(), get_spins(atoms)


def state_error(a, b):
    return max(float(np.abs(x - y).max()) for x, y in zip(a, b))


@pytest.mark.parametrize("integrator, order, gyromagnetic",
                         [("collective", 2, "lammps"), ("collective", 4, "moment"),
                          ("collective", 6, "lammps"), ("splitting", 2, "moment")])
def test_exchange_zeeman_anisotropies_converge_to_ode_solution(integrator, order, gyromagnetic):
    """Moving lattice, unequal moments. The splitting without the cubic term:
    see the next test."""
    t_end = 20 * units.fs
    cubic = integrator == "collective"
    ref = reference_solution(mixed_scene(cubic=cubic), t_end, hbar=HBAR,
                             gyromagnetic=gyromagnetic)
    hs, errors = [], []
    for n in ((20, 40, 80) if order < 6 else (16, 32, 64)):
        atoms = mixed_scene(cubic=cubic)
        INTEGRATORS[integrator](atoms, t_end / n, order=order,
                                gyromagnetic=gyromagnetic).run(n)
        hs.append(t_end / n)
        errors.append(state_error(state(atoms), ref))
    slope = np.polyfit(np.log(hs), np.log(errors), 1)[0]
    assert errors[-1] > 1e-12
    assert abs(slope - order) < 0.25, errors


def test_splitting_drops_to_first_order_with_cubic_anisotropy():
    """The sequential sweeps rotate spin i about B_i(s_i) taken at the start of
    its rotation. Exact for exchange, a field and a uniaxial anisotropy along
    it (the rotation keeps s·n), it is only a first-order step when the field
    depends on s_i otherwise (cubic anisotropy; a field and an easy axis along
    different axes, docs/benchmarks.md), and the forward–backward sweep is no
    longer symmetric: LAMMPS's fix nve/spin (which SuzukiTrotter follows step
    for step, tests/test_lammps.py) converges at first order there. The
    collective step stays second order on the same scene."""
    t_end = 20 * units.fs
    ref = reference_solution(mixed_scene(conventions="lammps"), t_end)
    slopes = {}
    for name, integrator in INTEGRATORS.items():
        hs, errors = [], []
        for n in (80, 160, 320):
            atoms = mixed_scene(conventions="lammps")
            integrator(atoms, t_end / n).run(n)
            hs.append(t_end / n)
            errors.append(state_error(state(atoms), ref))
        slopes[name] = np.polyfit(np.log(hs), np.log(errors), 1)[0]
    assert abs(slopes["collective"] - 2.0) < 0.1, slopes
    assert slopes["splitting"] < 1.4, slopes


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_one_solver_for_every_combination(integrator):
    """Exchange alone runs the fused kernel; adding a zero field sends the same
    dynamics through the per-operator path: same trajectory to round-off."""
    a, b = fcc_cobalt(2, temperature_K=300), fcc_cobalt(2, temperature_K=300)
    b.calc = SpinLatticeCalculator([*fcc_cobalt_terms(), Zeeman([0.0, 0.0, 0.0])])
    for atoms in (a, b):
        INTEGRATORS[integrator](atoms, 0.5 * units.fs).run(40)
    assert state_error(state(a), state(b)) < 1e-13


def test_spin_lengths_energy_and_reversibility():
    """Unequal moments, every term, physical precession: spin lengths kept to
    round-off; the energy error over 500 fs is the method's own O(h²) error
    (4 times smaller at h/2, not a drift that round-off or a lost symmetry
    would add at any step); 2000 steps back return to the start."""
    bands = {}
    for h in (0.25, 0.125):
        atoms = mixed_scene()
        dyn = CollectivePRK(atoms, h * units.fs, gyromagnetic="moment")
        e0 = dyn.get_total_energy()
        start = state(atoms)
        energies = []
        for _ in range(100):
            dyn.run(round(5.0 / h))
            energies.append(dyn.get_total_energy() - e0)
        assert np.abs(np.linalg.norm(dyn._state.s, axis=1) - 1.0).max() < 1e-13
        bands[h] = np.abs(energies).max()
    assert bands[0.25] < 1e-3 and 3.0 < bands[0.25] / bands[0.125] < 5.0, bands
    back = CollectivePRK(atoms, -0.125 * units.fs, gyromagnetic="moment")
    back.run(4000)
    assert state_error(state(atoms), start) < 1e-9


def test_single_site_scene_builds_no_neighbour_list():
    atoms = fcc_cobalt(2, temperature_K=300)
    atoms.calc = SpinLatticeCalculator([Zeeman(3.0, [0, 1, 0]),
                                        UniaxialAnisotropy(1e-3, [0, 0, 1])])
    dyn = CollectivePRK(atoms, 1.0 * units.fs)
    dyn.run(10)
    assert atoms.calc.evaluator.neighbors is None
    assert np.isfinite(dyn.get_total_energy())


@pytest.mark.slow
@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_spin_lengths_over_1e5_steps(integrator):
    """Every term of the mixed scene (the splitting without the terms it takes
    at first order only), moving lattice, 10⁵ steps: CollectivePRK keeps
    |s_i| = 1 to 1e-13 (the reflection form with compensated sums). The
    splitting's Cayley rotations, like LAMMPS's, are norm-preserving only up
    to the rounding of each rotation, which walks: 1.4e-13 measured here."""
    atoms = mixed_scene(cubic=integrator == "collective")
    dyn = INTEGRATORS[integrator](atoms, 0.25 * units.fs, gyromagnetic="moment")
    dyn.run(100_000)
    error = np.abs(np.linalg.norm(dyn._state.s, axis=1) - 1.0).max()
    assert error < (1e-13 if integrator == "collective" else 1e-12), error
