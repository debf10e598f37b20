"""CollectivePRK: convergence to the ODE solution, invariants, ASE integration, errors."""

import io
import re

import numpy as np
import pytest
from ase import units
from ase.constraints import FixAtoms
from ase.io import read
from ase.md.verlet import VelocityVerlet

import ase_spin
from ase_spin import CollectivePRK, Cubic, Exchange, LennardJones, SpinLatticeCalculator
from ase_spin.md import IntegrationError, SpinConvergenceError
from ase_spin.md.compositions import COMPOSITIONS
from ase_spin.md.ode import reference_solution
from ase_spin.scenes import fcc_cobalt, paper_chain

CHAIN = dict(hbar=1.0, precession="spin")


def state(atoms):
    return atoms.positions.copy(), atoms.get_momenta(), ase_spin.get_spins(atoms)


def run(atoms, h, steps, **kw):
    dyn = CollectivePRK(atoms, h, **kw)
    dyn.run(steps)
    return dyn


def state_error(a, b):
    return max(float(np.abs(x - y).max()) for x, y in zip(a, b))


def fitted_order(hs, errors):
    return np.polyfit(np.log(hs), np.log(errors), 1)[0]


@pytest.fixture(scope="module")
def chain_reference():
    return reference_solution(paper_chain(), 1.0, **CHAIN)


@pytest.mark.parametrize("order, exponents", [(2, (4, 5, 6, 7)), (4, (4, 5, 6)), (6, (4, 5, 6))])
def test_chain_converges_to_ode_solution(chain_reference, order, exponents):
    """The paper's chain, its own equations of motion (σ = +1, ħ = 1), T = 1:
    the whole state (positions, momenta, spins) converges at the method's order."""
    hs, errors = [], []
    for e in exponents:
        h = 2.0**-e
        atoms = paper_chain()
        run(atoms, h, 2**e, order=order, **CHAIN)
        hs.append(h)
        errors.append(state_error(state(atoms), chain_reference))
    assert errors[-1] > 1e-12  # still above the reference's own accuracy
    assert abs(fitted_order(hs, errors) - order) < 0.15, errors


def test_printed_sign_is_not_the_paper_dynamics(chain_reference):
    """The spin update with the opposite precession converges elsewhere: the
    equations of motion fix the sign (the paper's printed scheme (4) has it flipped)."""
    atoms = paper_chain()
    run(atoms, 2.0**-6, 64, hbar=1.0, precession="moment")
    assert state_error(state(atoms), chain_reference) > 1e-2


@pytest.mark.parametrize("precession", ["moment", "spin"])
@pytest.mark.parametrize("order", [2, 4])
def test_fcc_converges_to_ode_solution(precession, order):
    """A small 3D crystal with thermal velocities and a spin cone, physical ħ."""
    t_end = 20 * units.fs
    ref = reference_solution(fcc_cobalt(2, temperature_K=300), t_end, hbar=ase_spin.HBAR,
                             precession=precession)
    hs, errors = [], []
    for n in (20, 40, 80):
        atoms = fcc_cobalt(2, temperature_K=300)
        run(atoms, t_end / n, n, precession=precession, order=order)
        hs.append(t_end / n)
        errors.append(state_error(state(atoms), ref))
    assert errors[-1] > 1e-12
    assert abs(fitted_order(hs, errors) - order) < 0.2, errors


def test_precession_conventions_are_time_reverses_of_each_other():
    """Frozen lattice: the moment convention equals the spin convention run with −h."""
    a, b = fcc_cobalt(2), fcc_cobalt(2)
    run(a, 0.5 * units.fs, 10, precession="moment", lattice="frozen")
    run(b, -0.5 * units.fs, 10, precession="spin", lattice="frozen")
    assert np.abs(ase_spin.get_spins(a) - ase_spin.get_spins(b)).max() < 1e-13


def test_spin_lengths_and_momentum_kept():
    atoms = fcc_cobalt(2, temperature_K=1000)
    p0 = atoms.get_momenta().sum(axis=0)
    dyn = CollectivePRK(atoms, 1.0 * units.fs)
    for _ in range(4):
        dyn.run(50)
        moments = atoms.get_initial_magnetic_moments()
        assert np.abs(np.linalg.norm(moments, axis=1) - 1.72).max() < 1e-13 * 1.72
        assert np.abs(dyn._state.s.__pow__(2).sum(axis=1) - 1).max() < 2e-15 * 50
    assert np.abs(atoms.get_momenta().sum(axis=0) - p0).max() < 1e-12


def _spin_length_error(steps):
    atoms = paper_chain()
    dyn = CollectivePRK(atoms, 2.0**-6, **CHAIN)
    dyn.run(steps)
    return float(np.abs(np.linalg.norm(dyn._state.s, axis=1) - 1.0).max())


def test_spin_lengths_over_many_steps_short():
    assert _spin_length_error(10_000) < 1e-13


def test_spin_lengths_fcc_fast_precession():
    """Large spin increments per step (hω ≈ 0.27 at 0.5 fs). Written as
    s̃ = s + c W × B̄, the end point inherits the iteration's last residual, whose
    sign is consistent: spins shrank by 4.6e-13 in these 10⁴ steps. As the
    reflection of s about the midpoint it keeps |s| to round-off."""
    atoms = fcc_cobalt(2, temperature_K=300)
    dyn = CollectivePRK(atoms, 0.5 * units.fs)
    dyn.run(10_000)
    assert np.abs(np.linalg.norm(dyn._state.s, axis=1) - 1.0).max() < 1e-13


@pytest.mark.slow
def test_spin_lengths_over_1e5_steps():
    assert _spin_length_error(100_000) < 1e-13


def _energy_drift(steps, h):
    """Slope of a line fitted to the energy error, and the error's spread."""
    atoms = paper_chain()
    dyn = CollectivePRK(atoms, h, **CHAIN)
    e0 = dyn.get_total_energy()
    times, energies = [], []

    def record():
        times.append(dyn.get_time())
        energies.append(dyn.get_total_energy() - e0)

    dyn.attach(record, interval=10)
    dyn.run(steps)
    times, energies = np.array(times), np.array(energies)
    slope, _ = np.polyfit(times, energies, 1)
    return slope * times[-1], float(np.std(energies)), float(np.abs(energies).max())


def test_no_energy_drift_short():
    drift, spread, worst = _energy_drift(20_000, 2.0**-6)
    assert worst < 1e-2  # bounded, O(h²)
    assert abs(drift) < 0.5 * spread + 1e-12


@pytest.mark.slow
def test_no_energy_drift_1e5_steps():
    drift, spread, worst = _energy_drift(100_000, 2.0**-6)
    assert worst < 1e-2
    assert abs(drift) < 0.5 * spread + 1e-12


@pytest.mark.parametrize("order", [2, 6])
def test_time_reversible(order):
    atoms = fcc_cobalt(2, temperature_K=500)
    start = state(atoms)
    dyn = CollectivePRK(atoms, 1.0 * units.fs, order=order)
    dyn.run(30)
    assert state_error(state(atoms), start) > 1e-3
    dyn.dt = -dyn.dt
    dyn.run(30)
    assert state_error(state(atoms), start) < 1e-11


def test_energy_conserved_fcc_thermal_cone():
    """fcc Co at 300 K with a spin cone: the energy error stays small and falls
    as h² (it is the method's, not a drift)."""
    worst = {}
    for dt in (0.5, 1.0):
        atoms = fcc_cobalt(3, temperature_K=300)
        dyn = CollectivePRK(atoms, dt * units.fs)
        e0, ekin = dyn.get_total_energy(), dyn.get_kinetic_energy()
        errors = []
        dyn.attach(lambda: errors.append(dyn.get_total_energy() - e0), interval=5)
        dyn.run(int(100 / dt))
        worst[dt] = np.abs(errors).max()
    assert worst[0.5] < 5e-4 * ekin
    assert 3.0 < worst[1.0] / worst[0.5] < 5.5
    assert np.isclose(dyn.get_potential_energy(), atoms.get_potential_energy(), rtol=0,
                      atol=1e-10)


def test_observables_match_calculator():
    atoms = fcc_cobalt(2)
    dyn = CollectivePRK(atoms, 1.0 * units.fs)
    dyn.run(3)
    assert np.isclose(dyn.get_potential_energy(), atoms.get_potential_energy(), atol=1e-11)
    terms = atoms.calc.results["energy_terms"]
    for name, value in dyn.get_energy_terms().items():
        assert np.isclose(value, terms[name], atol=1e-11)
    B = atoms.calc.get_magnetic_forces(atoms)
    assert np.abs(dyn.get_magnetic_forces() - B).max() < 1e-12
    s = ase_spin.get_spins(atoms)
    ts = (np.cross(s, B) ** 2).sum() / (2 * units.kB * (s * B).sum())
    assert np.isclose(dyn.get_spin_temperature(), ts, rtol=1e-12)
    assert np.allclose(dyn.get_magnetization(), s.mean(axis=0), atol=1e-15)
    assert np.isclose(dyn.get_temperature(), atoms.get_temperature(), rtol=1e-12)


def test_no_calculator_calls_and_one_lattice_evaluation_per_step(monkeypatch):
    atoms = fcc_cobalt(2)
    calls = {"calculate": 0, "lattice": 0}
    calc = atoms.calc
    original = calc.calculate

    def counting(*a, **k):
        calls["calculate"] += 1
        return original(*a, **k)

    monkeypatch.setattr(calc, "calculate", counting)
    dyn = CollectivePRK(atoms, 1.0 * units.fs, logfile=io.StringIO())
    dyn.run(1)  # set-up
    ev = dyn.ev
    lattice = ev.lattice

    def counting_lattice(*a, **k):
        calls["lattice"] += 1
        return lattice(*a, **k)

    monkeypatch.setattr(ev, "lattice", counting_lattice)
    dyn.run(10)
    assert calls == {"calculate": 0, "lattice": 10}
    assert dyn.geometry_evaluations <= 3 and dyn.iterations > 0


def test_log_lines():
    atoms = fcc_cobalt(2)
    log = io.StringIO()
    dyn = CollectivePRK(atoms, 1.0 * units.fs, logfile=log, loginterval=2)
    dyn.run(4)
    lines = log.getvalue().splitlines()
    assert lines[0].split() == ["Time[ps]", "Etot[eV]", "Epot[eV]", "Ekin[eV]", "Emag[eV]",
                                "T[K]", "|M|", "Ts[K]", "iter"]
    assert len(lines) == 1 + 3  # steps 0, 2, 4
    # every column ends under the end of its header name
    ends = [m.end() for m in re.finditer(r"\S+", lines[0])]
    for line in lines[1:]:
        assert [m.end() for m in re.finditer(r"\S+", line)][1:] == ends[1:]
    last = [float(x) for x in lines[-1].split()]
    assert np.isclose(last[0], 0.004)
    # energies to 1e-9 eV: enough to follow the conservation of Etot
    assert len(lines[-1].split()[1].split(".")[1]) == 9
    assert abs(last[2] - atoms.get_potential_energy()) < 6e-10
    assert abs(last[1] - dyn.get_total_energy()) < 6e-10
    assert abs(last[4] - atoms.calc.results["energy_terms"]["exchange"]) < 6e-10
    assert np.isclose(last[6], np.linalg.norm(ase_spin.get_spins(atoms).mean(axis=0)),
                      atol=1e-5)
    assert last[8] == dyn.iterations
    # Ts: the ratio of the sums N, D averaged over the lines so far (the window)
    logger = next(f for f, *_ in dyn.observers if isinstance(f, ase_spin.SpinMDLogger))
    N, D = np.sum(logger.spin_temperature_samples, axis=0)
    assert len(logger.spin_temperature_samples) == 3
    assert abs(last[7] - N / (units.kB * D)) < 0.06
    for bad in (0, 2.5, True, "10"):
        with pytest.raises(ValueError, match="spin_temperature_window"):
            ase_spin.SpinMDLogger(dyn, io.StringIO(), spin_temperature_window=bad)


def test_trajectory_restart_reproduces_uninterrupted_run(tmp_path):
    atoms = fcc_cobalt(2, temperature_K=300)
    straight = atoms.copy()
    straight.calc = SpinLatticeCalculator(ase_spin.scenes.fcc_cobalt_terms())
    run(straight, 1.0 * units.fs, 40)

    path = tmp_path / "md.traj"
    run(atoms, 1.0 * units.fs, 20, trajectory=str(path))
    frames = read(path, ":")
    assert len(frames) == 21
    last = frames[-1]
    assert last.get_initial_magnetic_moments().shape == (len(last), 3)
    last.calc = SpinLatticeCalculator(ase_spin.scenes.fcc_cobalt_terms())
    run(last, 1.0 * units.fs, 20)
    assert state_error(state(last), state(straight)) < 1e-12


def test_no_magnetic_atoms_is_velocity_verlet():
    def make():
        atoms = fcc_cobalt(2, temperature_K=300)
        atoms.set_initial_magnetic_moments(np.zeros((len(atoms), 3)))
        return atoms

    a, b = make(), make()
    dyn = run(a, 2 * units.fs, 25)
    assert dyn.iterations == 0
    VelocityVerlet(b, 2 * units.fs).run(25)
    assert state_error(state(a)[:2], state(b)[:2]) < 1e-12


def test_fixed_atoms_as_velocity_verlet_does():
    def make():
        atoms = fcc_cobalt(2, temperature_K=300)
        atoms.set_initial_magnetic_moments(np.zeros((len(atoms), 3)))
        atoms.set_constraint(FixAtoms(indices=[0, 5, 9]))
        return atoms

    a, b = make(), make()
    x0 = a.positions[[0, 5, 9]].copy()
    run(a, 2 * units.fs, 25)
    VelocityVerlet(b, 2 * units.fs).run(25)
    assert state_error(state(a)[:2], state(b)[:2]) < 1e-12
    assert np.array_equal(a.positions[[0, 5, 9]], x0)


def test_fixed_atoms_keep_precessing():
    atoms = fcc_cobalt(2, temperature_K=300)
    atoms.set_constraint(FixAtoms(indices=[0, 5]))
    s0 = ase_spin.get_spins(atoms)
    x0 = atoms.positions[[0, 5]].copy()
    run(atoms, 1 * units.fs, 20)
    assert np.array_equal(atoms.positions[[0, 5]], x0)
    assert np.array_equal(atoms.get_momenta()[[0, 5]], np.zeros((2, 3)))
    assert np.abs(ase_spin.get_spins(atoms)[[0, 5]] - s0[[0, 5]]).max() > 1e-3


def test_frozen_lattice_spins_only():
    """lattice="frozen" and FixAtoms on every atom: spins only, the same
    trajectory, converging at order 2 to the spin-only ODE solution."""
    t_end = 10 * units.fs
    ref = reference_solution(fcc_cobalt(2, temperature_K=300), t_end, hbar=ase_spin.HBAR,
                             frozen_lattice=True)
    errors = {}
    for how in ("switch", "FixAtoms"):
        for n in (40, 80):
            atoms = fcc_cobalt(2, temperature_K=300)
            x0, p0 = atoms.positions.copy(), atoms.get_momenta()
            if how == "FixAtoms":
                atoms.set_constraint(FixAtoms(indices=range(len(atoms))))
            dyn = run(atoms, t_end / n, n, **({"lattice": "frozen"} if how == "switch" else {}))
            assert dyn.frozen and dyn.geometry_evaluations == 0
            assert np.array_equal(atoms.positions, x0)
            if how == "switch":
                assert np.array_equal(atoms.get_momenta(), p0)
            errors[how, n] = np.abs(ase_spin.get_spins(atoms) - ref[2]).max()
    assert errors["switch", 40] / errors["switch", 80] == pytest.approx(4.0, rel=0.05)
    assert errors["switch", 80] == pytest.approx(errors["FixAtoms", 80], rel=1e-6)


def test_non_magnetic_atoms_do_no_spin_work():
    atoms = fcc_cobalt(2, temperature_K=300)
    moments = atoms.get_initial_magnetic_moments()
    moments[::3] = 0.0
    atoms.set_initial_magnetic_moments(moments)
    run(atoms, 1 * units.fs, 20)
    after = atoms.get_initial_magnetic_moments()
    assert np.array_equal(after[::3], np.zeros_like(after[::3]))
    assert np.isfinite(after).all() and np.isfinite(atoms.positions).all()


def test_several_spin_terms_add_up():
    def make(terms):
        atoms = paper_chain()
        atoms.calc = SpinLatticeCalculator(terms)
        return atoms

    lj = LennardJones(epsilon=1.0, sigma=2.0 ** (-1.0 / 6.0), rc=1.9)
    a = make([lj, Exchange(Cubic(-10.0, 1.5))])
    b = make([lj, Exchange(Cubic(-4.0, 1.5)), Exchange(Cubic(-6.0, 1.5))])
    run(a, 2.0**-6, 64, **CHAIN)
    run(b, 2.0**-6, 64, **CHAIN)
    assert state_error(state(a), state(b)) < 1e-12


def test_compositions_are_symmetric_and_consistent():
    for order, gammas in COMPOSITIONS.values():
        assert np.isclose(sum(gammas), 1.0, rtol=0, atol=1e-15)
        assert np.allclose(gammas, gammas[::-1], rtol=0, atol=0)


def test_atoms_changed_between_runs_are_picked_up():
    a = fcc_cobalt(2, temperature_K=300)
    dyn = CollectivePRK(a, 1 * units.fs)
    dyn.run(5)
    a.positions[3] += 0.05
    a.arrays["momenta"][2] *= 1.5  # in place, as the positions: the step's snapshot sees it
    ase_spin.set_spins(a, ase_spin.scenes.cone(len(a), np.random.default_rng(3)),
                       magnitudes=1.72)
    b = a.copy()
    b.calc = SpinLatticeCalculator(ase_spin.scenes.fcc_cobalt_terms())
    dyn.run(5)
    run(b, 1 * units.fs, 5)
    assert state_error(state(a), state(b)) < 1e-13
    # a moment flipped in place
    a.arrays["initial_magmoms"][1] *= -1.0
    b = a.copy()
    b.calc = SpinLatticeCalculator(ase_spin.scenes.fcc_cobalt_terms())
    dyn.run(5)
    run(b, 1 * units.fs, 5)
    assert state_error(state(a), state(b)) < 1e-13



@pytest.mark.parametrize("cls", ["CollectivePRK", "Langevin"])
def test_atoms_changed_by_an_observer_are_picked_up(cls):
    """Inside one run() the steps between observers skip comparing the Atoms
    with the state (nothing else runs there); a step after an observer that
    changed them must start from the change: the run equals runs of 3 steps
    with the same changes made between them. CollectivePRK takes the compiled
    blocks at this size, Langevin the step-by-step path."""

    def make():
        a = fcc_cobalt(2, temperature_K=300)
        if cls == "CollectivePRK":
            return a, CollectivePRK(a, 1 * units.fs)
        return a, ase_spin.Langevin(a, 1 * units.fs, 300.0, spin_damping=0.1,
                                    friction=0.01 / units.fs, rng=5)

    def change(a):
        a.positions[3] += 0.01
        a.arrays["momenta"][2] *= 1.5
        a.arrays["initial_magmoms"][1] *= -1.0

    a, dyn = make()
    dyn.attach(lambda: change(a) if 0 < dyn.nsteps < 9 else None, interval=3)
    dyn.run(9)
    b, ref = make()
    for k in range(3):
        ref.run(3)
        if k < 2:
            change(b)
    assert ref.nsteps == dyn.nsteps == 9
    for x, y in zip(state(a), state(b)):
        np.testing.assert_array_equal(x, y)

def test_not_converging_raises_and_keeps_last_good_state():
    atoms = fcc_cobalt(2, temperature_K=300)
    dyn = CollectivePRK(atoms, 1 * units.fs, solver="jacobi")  # the others converge at 8 fs
    dyn.run(2)
    good = state(atoms)
    magmoms = atoms.get_initial_magnetic_moments()
    dyn.dt = 8 * units.fs  # h|B|/ħ ≈ 4.6
    with pytest.raises(SpinConvergenceError, match="timestep"):
        dyn.run(1)
    assert state_error(state(atoms), good) == 0.0
    assert np.array_equal(atoms.get_initial_magnetic_moments(), magmoms)
    dyn.dt = 1 * units.fs  # and it carries on from there
    dyn.run(1)
    assert dyn.nsteps == 3


def test_lattice_blow_up_raises_and_keeps_last_good_state():
    """Atoms pushed much closer than the LJ wall allows: the next step would
    throw them across the box. A clear error, never NaN positions."""
    atoms = fcc_cobalt(2, temperature_K=300)
    atoms.positions[1] = atoms.positions[0] + [0.9, 0.0, 0.0]
    before = state(atoms)
    dyn = CollectivePRK(atoms, 1 * units.fs)
    with pytest.raises(ase_spin.UnstableStepError, match="reduce it"):
        dyn.run(1)
    assert state_error(state(atoms), before) == 0.0


def test_a_nan_displacement_is_named_non_finite_not_a_large_move():
    """A NaN in q̃ (which the displacement maxima now keep) is reported as a
    non-finite state naming the atom, not as an atom that moved too far."""
    dyn = CollectivePRK(fcc_cobalt(2), 0.1 * units.fs)
    dyn.run(1)
    with pytest.raises(IntegrationError, match=r"non-finite positions \(atom 3"):
        dyn._check_moved(float("nan"), 3, dyn.dt)
    with pytest.raises(IntegrationError, match="atom 3 moved 5 Å"):
        dyn._check_moved(5.0, 3, dyn.dt)


def test_overlapping_atoms_raise_named_error():
    atoms = fcc_cobalt(2, temperature_K=300)
    atoms.positions[1] = atoms.positions[0]
    with pytest.raises(ase_spin.AtomsTooCloseError, match="atoms"):
        CollectivePRK(atoms, 1 * units.fs).run(1)


def test_bad_arguments():
    atoms = fcc_cobalt(1)
    with pytest.raises(ValueError, match="precession"):
        CollectivePRK(atoms, 1.0, precession="clockwise")
    with pytest.raises(ValueError, match="order"):
        CollectivePRK(atoms, 1.0, order=3)
    with pytest.raises(ValueError, match="lattice"):
        CollectivePRK(atoms, 1.0, lattice="rigid")
    with pytest.raises(ValueError, match="hbar"):
        CollectivePRK(atoms, 1.0, hbar=-1)
    atoms.calc = None
    with pytest.raises(TypeError, match="SpinLatticeCalculator"):
        CollectivePRK(atoms, 1.0).run(1)


@pytest.mark.parametrize("case", ["hot", "paramagnet", "compressed", "head-on"])
def test_stress_cases_run_cleanly(case):
    """Short versions of benchmarks/stress.py: each ends finite, energy kept."""
    atoms = fcc_cobalt(2, temperature_K=2000 if case == "hot" else 100)
    if case == "paramagnet":
        ase_spin.set_spins(atoms, ase_spin.scenes.cone(len(atoms), np.random.default_rng(2),
                                                       180.0), magnitudes=1.72)
    if case == "compressed":
        atoms.set_cell(atoms.cell * 0.85, scale_atoms=True)
    if case == "head-on":
        momenta = np.zeros((len(atoms), 3))
        d = atoms.positions[1] - atoms.positions[0]
        d /= np.linalg.norm(d)
        p = np.sqrt(atoms.get_masses()[0] * 100.0)  # 100 eV of relative kinetic energy
        momenta[0], momenta[1] = p * d, -p * d
        atoms.set_momenta(momenta)
    dyn = CollectivePRK(atoms, 0.5 * units.fs)
    e0, ekin0 = dyn.get_total_energy(), dyn.get_kinetic_energy()
    dyn.run(200)
    assert np.isfinite(atoms.positions).all() and np.isfinite(atoms.get_momenta()).all()
    # the 100 eV collision is stiff for 0.5 fs: 0.18 eV error here, 0.2 % of its energy
    assert abs(dyn.get_total_energy() - e0) < max(1e-3 * len(atoms), 5e-3 * ekin0)
    assert np.abs(np.linalg.norm(dyn._state.s, axis=1) - 1).max() < 1e-14


def test_step_too_large_for_the_spin_iteration_is_named():
    """Past h|B|/ħ ≈ 1.5 (3 fs on fcc Co) the Jacobi midpoint iteration cannot
    converge: the error says so at the first step and the atoms are untouched.
    (The default solver converges there: tests/test_midpoint_solver.py.)"""
    atoms = fcc_cobalt(2)
    before = state(atoms)
    with pytest.raises(SpinConvergenceError, match="Reduce the timestep"):
        CollectivePRK(atoms, 3.0 * units.fs, solver="jacobi").run(5)
    assert state_error(state(atoms), before) == 0.0


@pytest.mark.parametrize("dt_fs", [0.1, 0.5])
def test_end_forces_begun_in_the_last_rounds_pass_change_no_bit(monkeypatch, dt_fs):
    """The outer round in which the last step settled computes the forces at
    q and, in the same pass over the pairs, the end forces at (q̃, W)
    (CollectivePRK._round_forces); used when the round settles this step too
    (at 0.1 fs mostly the second round, at 0.5 fs the third), dropped when a
    solve follows. The run equals the run with a pass for each, bit for bit."""
    from conftest import general_path_only

    def go(merge):
        used = [0]
        with monkeypatch.context() as m:
            general_path_only(m)
            if merge:
                finish = CollectivePRK._finish_round
                m.setattr(CollectivePRK, "_finish_round",
                          lambda self, p: (used.__setitem__(0, used[0] + 1), finish(self, p))[1])
            else:
                m.setattr(CollectivePRK, "_round_forces", lambda self, W, s_new: (
                    self._spin_forces(self._state.ops, W, self._state.FL), None))
            atoms = fcc_cobalt(3, temperature_K=300)
            CollectivePRK(atoms, dt_fs * units.fs).run(12)
        return state(atoms), used[0]

    (got, used), (want, _) = go(True), go(False)
    assert used >= 6  # (the first steps, the predictor still filling, settle later)
    for a, b in zip(got, want):
        np.testing.assert_array_equal(a, b)
