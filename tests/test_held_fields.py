"""The midpoint solve that holds expensive fields fixed (a long-range dipolar
field) while the rest converges (kernels.midpoint_solve_held, policy.held_operators):
the same midpoint as the plain solve to the tolerance, in far fewer
evaluations of the expensive field; the same trajectories; the order of
CollectivePRK against a high-accuracy ODE solution (slow); its energy over a
longer run (slow)."""

import numpy as np
import pytest
from ase import units

import ase_spin
from ase_spin import DIPOLAR_CODATA, CollectivePRK, Dipolar
from ase_spin.constants import G_ELECTRON, HBAR
from ase_spin.md import kernels, policy
from ase_spin.md.ode import reference_solution
from ase_spin.scenes import fcc_cobalt

#: 2000× the physical μ0μB²/4π: dipolar fields of ~0.1 eV on fcc Co, strong
#: enough that the outer iteration over them has work to do (it contracts by
#: ~0.02 a round at 0.5 fs, ~1e-5 with the physical prefactor) and that their
#: part of the error shows in the convergence tests.
STRONG = 2000 * DIPOLAR_CODATA


def _cobalt(method="ewald", temperature_K=300.0, prefactor=STRONG, accuracy=None):
    """fcc Co, 32 atoms, LJ + exchange (rc 4 Å, between the second and third
    shells) + Ewald or mesh dipolar with its real-space cutoff there too (no
    pair crosses a cutoff in these short runs: the dynamics is smooth; the
    default accuracies keep the jump of the truncated real-space sum below
    the errors the order tests fit)."""
    kw = {"accuracy": 1e-8} if method == "ewald" else {"accuracy": 1e-6, "order": 10}
    if accuracy is not None:
        kw["accuracy"] = accuracy
    return fcc_cobalt(2, temperature_K=temperature_K,
                      extra=[Dipolar(4.0, method, prefactor=prefactor, **kw)])


def _state(atoms):
    return atoms.positions.copy(), atoms.get_momenta(), ase_spin.get_spins(atoms)


def _state_error(a, b):
    return max(float(np.abs(x - y).max()) for x, y in zip(a, b))


class _Counting:
    """An operator that counts its field evaluations (and declares what the
    one it wraps declares)."""

    def __init__(self, op):
        self.op = op
        self.expensive_field = op.expensive_field
        self.linear = op.linear
        self.calls = 0

    def field(self, W, out, mean=False):
        self.calls += 1
        self.op.field(W, out, mean)


def _midpoint_problem(h_fs=1.0):
    """The spin operators of a coupled step (at q and at a q̃ moved by the
    momenta), the spins, a starting guess and the scale of a step h."""
    atoms = _cobalt(accuracy=1e-5)  # any accuracy: one sum either way
    ev, moments = atoms.calc.bound_evaluator(atoms)
    s, mu = ase_spin.spins.split_moments(moments)
    q = atoms.positions.copy()
    qt = q + (h_fs * units.fs) * atoms.get_momenta() / atoms.get_masses()[:, None]
    ev.refresh(qt, also=q)
    ops = ev.spin_operators(q, half=True, refreshed=True)
    ops_t = ev.spin_operators(qt, mean_with=ops, half=True, refreshed=True)
    # c_i = hσ r_i/ħ, physical conventions: σ = −1, r_i = g_e/μ_i
    scale = -(h_fs * units.fs) / HBAR * G_ELECTRON / mu
    return ops_t, s, scale


def _plain(ops, s, scale, tol):
    counted = [_Counting(op) for op in ops]
    W, Wn, st, carry = s.copy(), np.zeros_like(s), np.zeros_like(s), np.zeros_like(s)
    its, _, status, which, *_ = kernels.midpoint_solve_operators(
        counted, s, W, Wn, st, scale, tol, 64 * tol, 100, 1.0, np.zeros_like(s), carry, True,
        0, True)
    assert status != kernels.NOT_CONVERGED
    return (W if which == 0 else Wn), st, its, counted[1].calls


def _held(ops, s, scale, tol, switch=policy.HELD_SWITCH):
    held, rest = policy.held_operators(ops)
    assert len(held) == 1 and len(rest) == 1 and rest[0].linear
    counted = _Counting(held[0])
    pairs, c = rest[0].linear_pairs(True)
    st, carry = np.zeros_like(s), np.zeros_like(s)

    def inner(cur, nxt, external):
        return kernels.midpoint_solve_half.serial(
            1, pairs.row, pairs.j, c, s, cur, nxt, st, scale, tol, 64 * tol, 100, 1.0,
            np.zeros_like(s), carry, 0, True, kernels.NO_FIELD, kernels.NO_ORDER,
            kernels.NO_ORDER, external)

    W, Wn = s.copy(), np.zeros_like(s)
    its, _, status, which, _, _, outer, gave_up = kernels.midpoint_solve_held(
        inner, [counted], W, Wn, tol, 64 * tol, 100, 1.0, True, switch)
    return (W if which == 0 else Wn), st, its, counted.calls, status, outer, gave_up


def test_only_expensive_fields_are_held():
    """Exchange is solved in the sweeps, the Ewald dipolar field held; a
    Hamiltonian without an expensive field, or with nothing but, is solved
    plainly (None)."""
    ops, _, _ = _midpoint_problem()
    assert [op.expensive_field for op in ops] == [False, True]
    held, rest = policy.held_operators(ops)
    assert held == [ops[1]] and rest == [ops[0]]
    assert policy.held_operators(ops[:1]) is None
    assert policy.held_operators(ops[1:]) is None
    cut = fcc_cobalt(2, extra=[Dipolar(4.0)])  # "cut": a pair pass like exchange's
    ev, _ = cut.calc.bound_evaluator(cut)
    ev.refresh(cut.positions)
    assert policy.held_operators(ev.spin_operators(cut.positions, refreshed=True)) is None


@pytest.mark.parametrize("tol", [1e-15, 1e-10])
def test_held_solve_reaches_the_plain_midpoint(tol):
    """One midpoint solve at 1 fs from W = s (some 20-30 sweeps): holding the dipolar field
    while exchange converges gives the plain solve's W and s̃ to the tolerance
    (each solve's own error is at most tol; round-off near 1e-16), in a
    handful of dipolar evaluations where the plain solve takes one a sweep."""
    ops, s, scale = _midpoint_problem()
    W0, st0, its0, calls0 = _plain(ops, s, scale, tol)
    W1, st1, its1, calls1, status, outer, gave_up = _held(ops, s, scale, tol)
    assert status != kernels.NOT_CONVERGED and not gave_up
    assert 0.0 < outer < 0.25  # the outer map contracts (by ~0.1 a round here)
    bound = 4 * tol + 1e-15
    assert np.abs(W1 - W0).max() <= bound and np.abs(st1 - st0).max() <= 2 * bound
    assert calls0 == its0 >= 6  # the plain solve evaluates the dipolar field every sweep
    assert calls1 <= calls0 // 2, (calls0, calls1)
    # and it is not the same iteration: the held solve's sweeps run with it fixed
    assert its1 > calls1


def test_held_solve_gives_up_when_the_outer_map_contracts_slowly():
    """With ``switch`` 0 (no outer contraction is small enough) the held
    solve stops after its second round and says so."""
    ops, s, scale = _midpoint_problem()
    *_, calls, status, outer, gave_up = _held(ops, s, scale, 1e-15, switch=0.0)
    assert gave_up and status == kernels.NOT_CONVERGED and calls == 2 and outer > 0.0


def _run(atoms, h, steps, held=True, monkeypatch=None, **kw):
    if not held:
        monkeypatch.setattr(policy, "held_operators", lambda operators: None)
    dyn = CollectivePRK(atoms, h, **kw)
    dyn.run(steps)
    if not held:
        monkeypatch.undo()
    return dyn


def test_trajectories_agree_with_the_plain_solve(monkeypatch):
    """Six steps of 0.3 fs (moving lattice, LJ + exchange + strong Ewald
    dipolar): the held and the plain solves give the same state to ~10²
    tolerances (each of the ~18 solves is exact to tol = 1e-15, differences
    carried along by the dynamics), far below the step's error."""
    a, b = _cobalt(), _cobalt()
    dyn = _run(a, 0.3 * units.fs, 6)
    _run(b, 0.3 * units.fs, 6, held=False, monkeypatch=monkeypatch)
    assert not any(dyn._state.unheld) and 0.0 < dyn._state.held_theta[0] < 0.1
    assert _state_error(_state(a), _state(b)) < 1e-13


def test_a_stage_whose_outer_map_gives_up_solves_plainly(monkeypatch):
    """policy.HELD_SWITCH 0: the first held solve gives up, the solve is
    redone plainly from the same guess and the stage stays plain: the same
    steps as the plain solve's to the last bit."""
    a, b = _cobalt(), _cobalt()
    monkeypatch.setattr(policy, "HELD_SWITCH", 0.0)
    dyn = _run(a, 0.3 * units.fs, 3)
    assert dyn._state.unheld == [True]
    _run(b, 0.3 * units.fs, 3, held=False, monkeypatch=monkeypatch)
    assert _state_error(_state(a), _state(b)) == 0.0


def _fitted_order(hs, errors):
    return np.polyfit(np.log(hs), np.log(errors), 1)[0]


@pytest.mark.slow
@pytest.mark.parametrize("method, order, steps", [
    ("ewald", 2, (10, 20, 40)), ("pme", 2, (10, 20, 40)),
    ("ewald", 4, (10, 20, 40)), ("ewald", 6, (10, 20, 40))])
def test_order_with_held_dipolar_fields(method, order, steps):
    """CollectivePRK with the dipolar field held in its solves (checked: the
    outer iteration ran) converges to the DOP853 solution of the equations of
    motion at its order over 10 fs: LJ + exchange + strong Ewald or mesh
    dipolar, thermal velocities (300 K) and a spin cone."""
    t_end = 10 * units.fs
    ref = reference_solution(_cobalt(method), t_end)
    hs, errors = [], []
    for n in steps:
        atoms = _cobalt(method)
        dyn = _run(atoms, t_end / n, n, order=order)
        assert not any(dyn._state.unheld) and 0.0 < max(dyn._state.held_theta) < 0.5
        hs.append(t_end / n)
        errors.append(_state_error(_state(atoms), ref))
    slope = _fitted_order(hs, errors)
    print(f"{method} order {order}: errors {errors}, slope {slope:.3f}")
    assert errors[-1] > 1e-11  # above the reference's own accuracy
    assert abs(slope - order) < 0.2, errors


@pytest.mark.slow
def test_energy_with_held_dipolar_fields(monkeypatch):
    """1000 steps of 0.25 fs with the strong Ewald dipolar field held: the
    total energy stays as close to its start as with the plain solve (a
    symplectic method's bounded error, the same for both: they take the same
    midpoints to the tolerance)."""
    spreads = []
    for held in (True, False):
        atoms = _cobalt(temperature_K=100.0)
        e0 = atoms.get_potential_energy() + atoms.get_kinetic_energy()
        if not held:
            monkeypatch.setattr(policy, "held_operators", lambda operators: None)
        dyn = CollectivePRK(atoms, 0.25 * units.fs)
        worst = 0.0
        for _ in range(20):
            dyn.run(50)
            e = atoms.get_potential_energy() + atoms.get_kinetic_energy()
            worst = max(worst, abs(e - e0))
        monkeypatch.undo()
        spreads.append(worst)
    print(f"max |E - E0| over 250 fs: held {spreads[0]:.3e} eV, plain {spreads[1]:.3e} eV")
    assert spreads[0] < 1e-4 * len(atoms)
    assert spreads[0] < 1.5 * spreads[1] + 1e-9
