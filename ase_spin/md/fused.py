"""One compiled CollectivePRK step for small systems, composed from the terms'
compiled pieces.

A step of the paper's 30-atom chain is a dozen kernel calls that each take a
microsecond or two of work and several of Python around them; at fcc Co with
500 atoms Python still took a fifth of the step. Below
:data:`~ase_spin._jit.threads.SERIAL_BELOW` atoms the whole second-order step
(kicks, drifts, geometry, midpoint solves, the checks between them) is one
numba function, compiled once per combination of pieces from what the terms
expose (:meth:`~ase_spin.terms.base.Term.compiled_lattice`,
:meth:`~ase_spin.terms.base.SpinOperator.compiled`) — the integrator never sees a
term's internals, and a term without the pieces simply keeps the general path.

The pieces are the twins of the same kernels the general path calls at that
size (all serial below :data:`~ase_spin._jit.threads.SERIAL_ALL_BELOW` atoms; above,
the pair-potential and geometry kernels threaded, called from compiled code),
with the same arguments and chunks in the same order, so the results are the
same bit for bit. Whatever the general path would stop at (an atom moving too
far, a pair list to rebuild, a midpoint solve that fails, non-finite forces)
makes the fused step give up before it has changed any state; the general path
then takes the step (and raises its error, if any).
"""

from __future__ import annotations

import os

import numba as nb
import numpy as np

from .._jit import threads
from .._jit.cloning import compile_with
from ..neighbors import all_finite, largest_displacements
from . import kernels, policy

__all__ = ["collective_block", "collective_step", "step_function"]

_DONE, _GIVE_UP = 0, 1


def _step(q, p, s, FL, m, h, carry_q, carry_p, carry_s, carry_mid, W, Wnext, scale, tol,
          first_tol, floor, max_iter, theta, lattice, op_q, op_t, reference, radius,
          fine_reference, fine_radius, settled_tol, qtol_floor, memory, local, switch,
          adaptive, one_sweep, predict, coef, hs, n_history, probe, kept, kept_n, field, merge,
          settled_round):
    """The skeleton of the fused step (compiled with ``lattice_forces``,
    ``spin_forces``, ``spin_geometry`` and ``spin_couplings`` bound to the
    terms' pieces): CollectivePRK._coupled_step for one spin operator on a
    half pair list, no constraints, no energy wanted. Returns (status, q̃, p̃,
    s̃, carry of q̃, carry of s̃, F_L(q̃), W, the other W buffer, θ, sweeps,
    geometries, the predictor's order (below), how far the second solve moved W
    or −1, the increment W − s for the predictor's history); status 1: give up,
    nothing but scratch buffers was written (also when an atom moves by more
    than ``radius`` or q̃ is farther than ``radius`` from ``reference`` or
    ``fine_radius`` from ``fine_reference``, where the pair list and the
    sub-lists hold: NeighborCache; separate arguments, not tuples of arrays,
    which cost the block of steps 5 %). The first solve stops at
    ``first_tol``, the others at ``tol`` (policy.first_tolerance).
    ``memory``, ``local``: the midpoint solver (kernels.midpoint_solve_half);
    a solve contracting by more than ``switch`` per sweep also gives up, so
    that CollectivePRK's ``solver="auto"`` makes its switch on the general path;
    with ``adaptive`` (auto's first mode) the step's first solve, if to
    ``tol``, chooses its sweeps from ``one_sweep`` (whether the stage's last
    such solve took one) and θ (policy.auto_takes_local), and the updated
    ``one_sweep`` is returned (last but one).
    With ``predict``, W is not read but predicted here as CollectivePRK._predict
    does (normalise(s + Σ c_m D_m), coefficients ``coef`` over the increments
    ``hs``, newest first, padded), and the returned order is the one that would
    have predicted the increment W − s best (CollectivePRK._remember_midpoint's,
    from ``n_history`` increments and the rows ``probe``, its difference table
    ``kept``, ``kept_n`` kept and updated: kernels.best_order_rows), else −1; ``settle``:
    how far the second solve moved W, or −1. ``field`` receives the last
    solve's midpoint fields (kernels.midpoint_solve_half's ``field``). With
    ``merge`` (the operator offers ``spin_forces_two``), the outer round
    ``settled_round`` (the one the last step settled in) also begins the end
    forces, as CollectivePRK._round_forces; returned last: the round this step
    settled in (−1: by a solve that moved W by round-off only)."""
    if predict:
        W = np.empty_like(s)
        extrapolate(coef, hs[0], hs[1], hs[2], hs[3], hs[4], hs[5], hs[6], hs[7],  # noqa: F821
                    hs[8], hs[9], hs[10], hs[11], hs[12], hs[13], hs[14], hs[15], s, W)
    qt_used = q
    first = True
    settled = False
    qtol = 0.0
    iterations = 0
    geometries = 0
    qt = q
    P = p
    carry_qt = carry_q
    stilde = s
    carry = carry_s
    solves = 0
    loose = False
    settle = -1.0
    solved = False
    pending = False  # the end forces begun in this round's pass
    keep = np.empty((0, 0, 6))
    settled_in = -1
    for rnd in range(policy.MAX_ROUNDS):
        F = FL.copy()
        if merge and solved and rnd == settled_round:
            keep = spin_forces_two(W, op_q, op_t, F)  # noqa: F821 - bound per combination
            pending = True
        else:
            spin_forces(W, op_q, F)  # noqa: F821 - bound per combination of terms
        P = np.empty_like(p)
        qt = np.empty_like(q)
        carry_qt = np.empty_like(q)
        moved, atom, apart, largest = kick_drift(  # noqa: F821
            1, p, 0.5 * h, F, carry_p, P, carry_mid, q, m, h, carry_q, qt, carry_qt, qt_used)
        new_q = True  # as CollectivePRK: a new q̃ gets its couplings
        if first:
            if not moved <= radius:
                return (_GIVE_UP, q, p, s, q, s, FL, W, Wnext, theta, 0, 0, -1, settle, s,
                        one_sweep, settled_round)
            qtol = policy.settled_qtol(largest, qtol_floor)
            first = False
        elif apart <= qtol:
            if not loose:
                settled = True
                settled_in = rnd
                break
            new_q = False  # settled after the loose first solve: finish it at its couplings
        pending = False  # W or q̃'s couplings change below: not the end's
        if new_q:
            # the pair list must stay valid at q̃ (else the general path rebuilds it)
            moved_list, moved_sublists = largest_displacements(qt, reference, fine_reference)
            if not (moved_list <= radius and moved_sublists <= fine_radius):
                return (_GIVE_UP, q, p, s, q, s, FL, W, Wnext, theta, 0, 0, -1, settle, s,
                        one_sweep, settled_round)
            spin_geometry(qt, op_t, op_q)  # noqa: F821
            geometries += 1
        row, nbr, c = spin_couplings(op_t)  # noqa: F821
        stilde = np.zeros_like(s)
        carry = np.zeros_like(s)
        use_tol = first_tol if solves == 0 else tol
        use_local = local
        # the step's first solve, to tol (not a loose one, not a later one)
        chooses = adaptive and solves == 0 and not use_tol > tol
        if chooses:
            use_local = policy.auto_takes_local(one_sweep, theta)
        its, delta, status, which, measured, moved_w = solve_half(  # noqa: F821
            1, row, nbr, c, s, W, Wnext, stilde, scale, use_tol, floor, max_iter,
            policy.start_contraction(theta), carry_s, carry, memory, use_local, field)
        if status == kernels.NOT_CONVERGED or policy.gives_up(its, measured, switch):
            return (_GIVE_UP, q, p, s, q, s, FL, W, Wnext, theta, 0, 0, -1, settle, s,
                    one_sweep, settled_round)
        if 0.0 <= measured < 1.0:  # observed (−1: none was)
            theta = measured
        if chooses:
            one_sweep = its == 1
        if which == 1:
            W, Wnext = Wnext, W
        solved = True
        iterations += its
        loose = use_tol > tol
        if new_q:
            qt_used = qt
            solves += 1
            if solves == 2:
                settle = moved_w
        if moved_w <= settled_tol:
            settled = True
            settled_in = -1
            break
    if not settled:
        return (_GIVE_UP, q, p, s, q, s, FL, W, Wnext, theta, 0, 0, -1, settle, s,
                one_sweep, settled_round)
    FLt = np.zeros_like(q)
    lattice_forces(qt, lattice, FLt)  # noqa: F821
    if not all_finite(FLt):
        return (_GIVE_UP, q, p, s, q, s, FL, W, Wnext, theta, 0, 0, -1, settle, s,
                one_sweep, settled_round)
    if pending:
        F = np.empty_like(FLt)
        add_kept(keep, FLt, F)  # noqa: F821
    else:
        F = FLt.copy()
        spin_forces(W, op_t, F)  # noqa: F821
    kick(P, 0.5 * h, F, carry_mid, P, carry_p)  # noqa: F821
    order = -1
    increment = s  # (not used without the predictor)
    if predict and n_history > 0:
        increment = W - s
        order = best_order(n_history, hs[0], hs[1], hs[2], hs[3], hs[4], hs[5],  # noqa: F821
                           hs[6], hs[7], hs[8], hs[9], hs[10], hs[11], hs[12], hs[13],
                           hs[14], hs[15], increment, probe, probe, kept, kept_n)
    return (_DONE, qt, P, stilde, carry_qt, carry, FLt, W, Wnext, theta, iterations,
            geometries, order, settle, increment, one_sweep, settled_in)


@nb.njit(cache=True, inline="always")
def _newest(ring, stage, head, count, k):
    """The k-th newest increment of a stage's ring buffer (the newest where
    fewer are kept: as kernels.newest_first pads)."""
    return ring[stage, (head - k) % ring.shape[1] if k < count else head]


@nb.njit(cache=True, inline="always")
def _history(ring, stage, head, count):
    """A stage's increments, newest first, as kernels.newest_first gives them."""
    return (_newest(ring, stage, head, count, 0), _newest(ring, stage, head, count, 1),
            _newest(ring, stage, head, count, 2), _newest(ring, stage, head, count, 3),
            _newest(ring, stage, head, count, 4), _newest(ring, stage, head, count, 5),
            _newest(ring, stage, head, count, 6), _newest(ring, stage, head, count, 7),
            _newest(ring, stage, head, count, 8), _newest(ring, stage, head, count, 9),
            _newest(ring, stage, head, count, 10), _newest(ring, stage, head, count, 11),
            _newest(ring, stage, head, count, 12), _newest(ring, stage, head, count, 13),
            _newest(ring, stage, head, count, 14), _newest(ring, stage, head, count, 15))


def _run(steps, q, p, s, FL, m, dt, gammas, scales, carry_q, carry_p, carry_s, carry_mid,
         Wnext, tol, fraction, loosest, floor, max_iter, theta, settle, memory, local, switch,
         adaptive, one_sweep, orders, ring, counts, heads, probe, kept, kept_n, lattice, op_q, op_t, reference,
         radius, fine_reference, fine_radius, settled_tol, qtol_floor, coefficients, merge,
         rounds):
    """Up to ``steps`` whole steps (every stage γ_k h of the composition) of the
    fused step (compiled with ``fused_step`` bound to :func:`_step` of the
    terms' pieces), as CollectivePRK takes them one by one with nothing
    between: the same calls with the same arguments, so the same bits. What
    the Python side keeps per stage comes in arrays, updated in place: the
    contraction ``theta``, how far the second solve moved W (``settle``), the
    whether its last solve took one sweep (``one_sweep``; ``adaptive``: see
    :func:`_step`), the predictor's ``orders`` and its increments in ``ring``
    (stage, slot, n, 3) with ``counts`` kept and the newest at ``heads``, the
    difference tables of
    its order choice (``kept``, ``kept_n``: per stage; those of a step not
    taken are dropped, kept_n = 0), the outer round each
    stage settled in (``rounds``; ``merge``: see :func:`_step`). A step is taken whole or
    not at all: where a stage gives up (see :func:`_step`) the state is that
    of the last whole step (``carry_p``, the one array the step changes in
    place, put back). Returns (steps done, the stage that gave up or −1, q, p,
    s, F_L, carry of q and of s, the spare W buffer, whether the two spin
    operators swapped roles, sweeps in all, sweeps and geometries of the last
    step)."""
    nstages = gammas.shape[0]
    depth = ring.shape[1]
    saved_p = np.empty_like(carry_p)
    increments = np.empty((nstages,) + s.shape)
    field = np.empty_like(s)  # the midpoint fields (not used here)
    new_theta = theta.copy()
    new_settle = settle.copy()
    new_orders = orders.copy()
    new_rounds = rounds.copy()
    new_one_sweep = one_sweep.copy()
    done = 0
    sweeps = 0
    last_sweeps = 0
    last_geometries = 0
    swapped = False
    failed = -1
    for _ in range(steps):
        q0, p0, s0, FL0, cq0, cs0, W0 = q, p, s, FL, carry_q, carry_s, Wnext
        saved_p[:] = carry_p
        oq, ot = op_q, op_t
        its_step = 0
        geometries = 0
        for stage in range(nstages):
            head, count = heads[stage], counts[stage]
            hs = _history(ring, stage, head, count)
            first_tol = policy.first_tolerance(tol, settle[stage], fraction, loosest)
            (status, qt, P, s_new, cq, cs, FLt, W, Wn, th, its, geos, order, moved,
             increment, single, rnd) = fused_step(  # noqa: F821 - bound per combination
                q, p, s, FL, m, gammas[stage] * dt, carry_q, carry_p, carry_s, carry_mid,
                hs[0], Wnext, scales[stage], tol, first_tol, floor, max_iter[stage],
                theta[stage], lattice, oq, ot, reference, radius, fine_reference, fine_radius,
                settled_tol, qtol_floor,
                memory[stage], local[stage], switch[stage], adaptive[stage], one_sweep[stage],
                count > 0, coefficients[min(orders[stage], count - 1)], hs, count, probe,
                kept[stage],
                kept_n[stage:stage + 1], field, merge, rounds[stage])
            if status != _DONE:
                failed = stage
                break
            q, p, s, FL, carry_q, carry_s, Wnext = qt, P, s_new, FLt, cq, cs, Wn
            oq, ot = ot, oq
            new_theta[stage] = th
            if moved >= 0.0:
                new_settle[stage] = moved
            new_orders[stage] = order
            new_rounds[stage] = rnd
            new_one_sweep[stage] = single
            increments[stage] = increment
            its_step += its
            geometries += geos
        if failed >= 0:
            q, p, s, FL, carry_q, carry_s, Wnext = q0, p0, s0, FL0, cq0, cs0, W0
            carry_p[:] = saved_p
            kept_n[:] = 0  # tables of a history the step did not extend
            break
        for stage in range(nstages):
            theta[stage] = new_theta[stage]
            settle[stage] = new_settle[stage]
            orders[stage] = new_orders[stage]
            rounds[stage] = new_rounds[stage]
            one_sweep[stage] = new_one_sweep[stage]
            heads[stage] = (heads[stage] + 1) % depth
            ring[stage, heads[stage]] = increments[stage]
            counts[stage] = min(counts[stage] + 1, depth)
        if nstages % 2 == 1:
            op_q, op_t = op_t, op_q
            swapped = not swapped
        done += 1
        sweeps += its_step
        last_sweeps = its_step
        last_geometries = geometries
    return (done, failed, q, p, s, FL, carry_q, carry_s, Wnext, swapped, sweeps, last_sweeps,
            last_geometries)


def _run_frozen(steps, s, dt, gammas, scales, carry_s, Wnext, tol, floor, max_iter, theta,
                memory, local, switch, adaptive, one_sweep, orders, ring, counts, heads, probe,
                kept, kept_n, row, nbr, c, coefficients, sweep_order, theta_index, full_row,
                full_nbr, full_c, order, starts):
    """:func:`_run` for a frozen lattice (CollectivePRK's spins-only step,
    ``_substep`` with ``lattice="frozen"``) with one spin operator of the form
    B_i = Σ_j c_k W_j (``linear_pairs``: row, nbr, c): per stage the
    predictor (``extrapolate``), the midpoint solve (``solve``: the serial
    twin of kernels.midpoint_solve_half or midpoint_solve, bound per pair-list
    kind) and the predictor's order (its difference tables ``kept``,
    ``kept_n`` as in :func:`_run`) and increment, the same calls as the
    Python path with the same arguments; a stage whose ``sweep_order`` is
    colour order solves with locally exact sweeps in that order
    (``solve_full``, kernels.midpoint_solve's serial twin, over the full list
    ``full_row``, ``full_nbr``, ``full_c``, its rows copied in its colour
    order ``order`` (neighbors.rows_in_order), the colours' boundaries
    ``starts``);
    ``sweep_order`` and ``theta_index`` kept by
    policy.next_sweep_order). Steps are taken whole or not at all;
    a solve that fails or contracts by more than ``switch`` per sweep, or a
    stage to be coloured without a full list given (empty ``order``), stops
    the block before its step. Returns (steps done, s, carry of s, the spare W
    buffer, sweeps in all, sweeps of the last step)."""
    no_field = np.zeros((0, 3))  # kernels.NO_FIELD: no midpoint fields wanted
    nstages = gammas.shape[0]
    depth = ring.shape[1]
    increments = np.empty((nstages,) + s.shape)
    new_theta = theta.copy()
    new_orders = orders.copy()
    new_one_sweep = one_sweep.copy()
    new_sweep_order = sweep_order.copy()
    new_theta_index = theta_index.copy()
    done = 0
    sweeps = 0
    last_sweeps = 0
    for _ in range(steps):
        s0, cs0, W0 = s, carry_s, Wnext
        its_step = 0
        failed = False
        for stage in range(nstages):
            head, count = heads[stage], counts[stage]
            hs = _history(ring, stage, head, count)
            W = np.empty_like(s)
            extrapolate(coefficients[min(orders[stage], count - 1)], hs[0], hs[1],  # noqa: F821
                        hs[2], hs[3], hs[4], hs[5], hs[6], hs[7], hs[8], hs[9], hs[10], hs[11],
                        hs[12], hs[13], hs[14], hs[15], s, W)
            stilde = np.zeros_like(s)
            carry = np.zeros_like(s)
            use_local = local[stage]
            if adaptive[stage]:
                use_local = policy.auto_takes_local(one_sweep[stage], theta[stage])
            if use_local and sweep_order[stage] == policy.COLOUR_ORDER:
                if len(order) == 0:  # no full list here: the general path makes it
                    failed = True
                    break
                its, delta, status, which, measured, moved = solve_full(  # noqa: F821
                    1, full_row, full_nbr, full_c, s, W, Wnext, stilde, scales[stage], tol,
                    floor, max_iter[stage], policy.start_contraction(theta[stage]), carry_s,
                    carry,
                    memory[stage], use_local, no_field, order, starts)
            else:
                its, delta, status, which, measured, moved = solve(  # noqa: F821
                    1, row, nbr, c, s, W, Wnext, stilde, scales[stage], tol, floor,
                    max_iter[stage], policy.start_contraction(theta[stage]), carry_s, carry,
                    memory[stage], use_local, no_field)
            if status == kernels.NOT_CONVERGED or policy.gives_up(its, measured, switch[stage]):
                failed = True
                break
            if 0.0 <= measured < 1.0:
                new_theta[stage] = measured
            if adaptive[stage]:
                new_one_sweep[stage] = its == 1
            new_sweep_order[stage], new_theta_index[stage] = policy.next_sweep_order(
                sweep_order[stage], use_local, its, measured, theta_index[stage])
            if which == 1:
                W, Wnext = Wnext, W
            increment = W - s
            new_orders[stage] = best_order(count, hs[0], hs[1], hs[2], hs[3],  # noqa: F821
                                           hs[4], hs[5], hs[6], hs[7], hs[8], hs[9], hs[10],
                                           hs[11], hs[12], hs[13], hs[14], hs[15], increment,
                                           probe, probe, kept[stage], kept_n[stage:stage + 1])
            increments[stage] = increment
            s, carry_s = stilde, carry
            its_step += its
        if failed:
            s, carry_s, Wnext = s0, cs0, W0
            kept_n[:] = 0  # tables of a history the step did not extend
            break
        for stage in range(nstages):
            theta[stage] = new_theta[stage]
            orders[stage] = new_orders[stage]
            one_sweep[stage] = new_one_sweep[stage]
            sweep_order[stage] = new_sweep_order[stage]
            theta_index[stage] = new_theta_index[stage]
            heads[stage] = (heads[stage] + 1) % depth
            ring[stage, heads[stage]] = increments[stage]
            counts[stage] = min(counts[stage] + 1, depth)
        done += 1
        sweeps += its_step
        last_sweeps = its_step
    return done, s, carry_s, Wnext, sweeps, last_sweeps


def _both(positions, data, forces):
    """Two lattice pieces in turn (the terms' order, as Evaluator.lattice)."""
    first_lattice(positions, data[0], forces)  # noqa: F821
    second_lattice(positions, data[1], forces)  # noqa: F821


@nb.njit(cache=True)
def _no_lattice(positions, data, forces):
    pass


_steps = {}


def step_function(lattice, spin, two=None):
    """The fused step for a lattice piece and a spin operator's pieces, with
    its ``(forces_two, add_kept)`` pieces if it offers them (compiled once per
    combination, cached on disk)."""
    two = two or (_no_forces_two, _no_add_kept)
    key = (lattice, *spin, *two)
    fn = _steps.get(key)
    if fn is None:
        forces, geometry, couplings = spin
        fn = _steps[key] = compile_with(
            _step, {"lattice_forces": lattice, "spin_forces": forces,
                    "spin_geometry": geometry, "spin_couplings": couplings,
                    "spin_forces_two": two[0], "add_kept": two[1],
                    "kick_drift": kernels.kick_drift.serial, "kick": kernels.kick.serial,
                    "solve_half": kernels.midpoint_solve_half.serial,
                    "extrapolate": kernels.extrapolate_rows.serial,
                    "best_order": kernels.best_order_rows},
            f"{lattice.__name__}_{forces.__name__}")
    return fn


@nb.njit(cache=True)
def _no_forces_two(W, data, there, F):
    """Stands for a ``forces_two`` piece the operator does not offer (never
    called: the step's ``merge`` is then False)."""
    return np.empty((0, 0, 6))


@nb.njit(cache=True)
def _no_add_kept(keep, base, out):
    """Stands for an ``add_kept`` piece the operator does not offer."""


_pairs_of = {}


def _lattice_pieces(ev):
    """(function, data) of all lattice terms together, or None if one has no
    compiled piece."""
    pieces = []
    for t, table in zip(ev.hamiltonian.terms, ev._tables):
        if t.spin_dependent:
            continue
        piece = t.compiled_lattice(ev._pairs(t, half=True), ev.types, table)
        if piece is None:
            return None
        pieces.append(piece)
    if not pieces:
        return _no_lattice, ()
    fn, data = pieces[0]
    for f2, d2 in pieces[1:]:
        key = (fn, f2)
        both = _pairs_of.get(key)
        if both is None:
            both = _pairs_of[key] = compile_with(
                _both, {"first_lattice": fn, "second_lattice": f2},
                f"{fn.__name__}_{f2.__name__}")
        fn, data = both, (data, d2)
    return fn, data


_UNSEEN = object()


#: Steps a run must still have ahead for a system of 64–1 500 atoms to compile its
#: fused step when numba has not cached it yet: the compilation takes ~15 s once
#: per install (benchmarks/first_use.py), which a short first run should not pay;
#: a long run does, and every later run loads the step from the cache and saves
#: ~80 µs per step at N = 500 (benchmarks/small_systems.py). Below 64 atoms it is
#: always used.
FUSE_AFTER_STEPS = 20_000


def _compiled(step):
    """Whether the fused step is compiled in this process or in numba's disk cache."""
    if step.overloads:
        return True
    try:
        return os.path.exists(step._cache._cache_file._index_path)
    except AttributeError:  # another numba's internals: assume not
        return False


def _pays(dyn, step):
    """Use the fused step of a system of 64–1 500 atoms: if it costs no
    compilation (:func:`_compiled`) or the run is long enough to repay it."""
    if _compiled(step):
        return True
    return getattr(dyn, "max_steps", 0) - dyn.nsteps >= FUSE_AFTER_STEPS


def _pieces(dyn):
    """(the fused step, lattice data, the two spin operators' data: at q and at
    q̃, whether the step may begin the end forces in an outer round's pass) when
    the system is small (light kernels serial: threads.small()) and
    every term offers its pieces, else None."""
    st = dyn._state
    ev = dyn.ev
    if (not threads.small() or st.ops_next is None or len(st.ops) != 1
            or ev.neighbors is None or dyn.atoms.constraints or not dyn.half_lists):
        return None
    if not type(dyn).compiled_step:
        return None
    op_q, op_t = st.ops[0], st.ops_next[0]
    token = ev.state_token
    # per state and pair list: the lattice pieces, each operator's pieces (its
    # arrays are refilled in place while the token holds) and the step
    cached = getattr(st, "fused", None)
    if cached is None or cached[0] != token:
        cached = st.fused = (token, _lattice_pieces(ev), {})
    plan = cached[1]
    if plan is None:
        return None
    pieces = cached[2]
    piece_q = pieces.get(op_q, _UNSEEN)
    if piece_q is _UNSEEN:
        piece_q = pieces[op_q] = op_q.compiled()
    piece_t = pieces.get(op_t, _UNSEEN)
    if piece_t is _UNSEEN:
        piece_t = pieces[op_t] = op_t.compiled()
    if (piece_q is None or piece_t is None or piece_q[:3] != piece_t[:3]
            or getattr(op_q, "pairs", None) is not getattr(op_t, "pairs", None)):
        return None
    lattice_fn, lattice_data = plan
    step = pieces.get("step")
    if step is None:
        two = piece_t[4] if len(piece_t) > 4 else None
        step = pieces["step"] = step_function(lattice_fn, piece_t[:3], two)
        pieces["merge"] = two is not None and len(piece_q) > 4
    reference = ev.neighbors.reference
    if reference is None or reference.shape != st.q.shape:
        return None
    return step, lattice_data, piece_q[3], piece_t[3], pieces["merge"]


def _validity(ev):
    """Where the pair list and its sub-lists hold: (the positions the list
    was built at, how far from them, the positions the sub-lists were
    filtered at, how far from those)."""
    nbl = ev.neighbors
    return nbl.reference, 0.5 * nbl.skin, nbl.fine_reference, nbl.fine_radius


def _solver_settings(dyn, stage, h):
    """(Anderson memory, locally exact sweep, sweeps allowed, contraction per
    sweep above which to give up, whether each solve chooses its sweeps by
    policy.auto_takes_local) of a stage's midpoint solves: policy.solver_settings,
    as CollectivePRK._solve takes them (with "auto", its first mode until it
    contracts slowly: then the general path makes the switch)."""
    st = dyn._state
    return policy.solver_settings(st.policy.solver, (stage, h) in st.modes,
                                  st.policy.max_iter)


def collective_step(dyn, h, stage):
    """CollectivePRK's second-order step of size h as one compiled call, when
    the system is small (light kernels serial: threads.small()) and every term
    offers its pieces; returns (sweeps, geometries), or None to take the general
    path (nothing changed)."""
    got = _pieces(dyn)
    if got is None:
        return None
    step, lattice_data, data_q, data_t, merge = got
    if not threads.tiny() and not _pays(dyn, step):
        return None
    st = dyn._state
    ev = dyn.ev
    scale = dyn._scale(h)
    rules = st.policy
    memory, local, max_iter, switch, adaptive = _solver_settings(dyn, stage, h)
    # the midpoint fields, where asked for (else into the same buffer, unread:
    # one compiled specialisation of the step)
    field = st.field_out if st.field_out is not None else dyn._midpoint_field_buffer()
    history = st.history[stage]
    predict = bool(history) and type(dyn).compiled_predictor
    if predict:  # CollectivePRK._predict, inside the step
        hs = kernels.newest_first(history)
        n_history = len(history)
        coef = kernels.COEFFICIENTS[min(st.predictor_order[stage], n_history - 1)]
        W = hs[0]  # not read
    else:
        W = dyn._predict(stage)
        hs = (W,) * kernels.PREDICTOR_DEPTH
        n_history = 0
        coef = kernels.COEFFICIENTS[0]
    (status, qt, P, s_new, carry_q, carry_s, FL, W, Wnext, theta, iterations,
     geometries, order, settle, increment, one_sweep, settled_in) = step(st.q, st.p, st.s, st.FL, dyn.masses[:, 0], h,
                                       st.carry_q, st.carry_p, st.carry_s, st.carry_mid, W,
                                       st.Wnext, scale, rules.tol,
                                       policy.first_tolerance(rules.tol, st.settle[stage],
                                                              rules.first_fraction,
                                                              rules.first_loosest),
                                       rules.floor, max_iter, st.theta[stage], lattice_data,
                                       data_q, data_t, *_validity(ev),
                                       rules.settled_tol, rules.qtol_floor, memory,
                                       local, switch, adaptive, bool(st.one_sweep[stage]),
                                       predict, coef, hs, n_history,
                                       st.probe, st.kept[stage], st.kept_n[stage:stage + 1],
                                       field, merge, st.settled_round[stage])
    if status != _DONE:
        return None
    st.settled_round[stage] = settled_in
    st.one_sweep[stage] = one_sweep
    st.field_filled = st.field_out is not None
    st.theta[stage] = theta
    st.Wnext = Wnext
    st.FL, st.EL, st.EL_terms, st.VL = FL, None, None, None
    st.carry_q, st.carry_s = carry_q, carry_s
    if settle >= 0.0:
        st.settle[stage] = settle
    if predict:  # CollectivePRK._remember_midpoint, order and increment W − s from the step
        st.predictor_order[stage] = order
        if len(history) == history.maxlen:
            history.popleft()
        history.append(increment)
    else:
        dyn._remember_midpoint(stage, W)
    st.q, st.p, st.s = qt, P, s_new
    st.ops, st.ops_next = st.ops_next, st.ops
    return iterations, geometries


_runners = {}


def _runner(step):
    """:func:`_run` for a fused step (compiled once per combination, cached on disk)."""
    fn = _runners.get(step)
    if fn is None:
        fn = _runners[step] = compile_with(_run, {"fused_step": step},
                                           step.py_func.__name__)
    return fn


def blocks_allowed(cls):
    """Whether steps of integrator class ``cls`` may be taken in blocks: it
    declares its coupled step, its predictor and runs of its steps compiled
    (CollectivePRK.compiled_step, compiled_predictor, compiled_blocks)."""
    return cls.compiled_step and cls.compiled_predictor and cls.compiled_blocks


def _stage_arrays(dyn):
    """Per stage, as arrays for the block runners: γ, c_i (scales), and the
    solver settings (:func:`_solver_settings`)."""
    st = dyn._state
    gammas = np.ascontiguousarray(dyn.gammas, dtype=float)
    nstages = len(gammas)
    scales = np.empty((nstages, len(st.s)))
    memory = np.empty(nstages, dtype=np.int64)
    local = np.empty(nstages, dtype=np.bool_)
    max_iter = np.empty(nstages, dtype=np.int64)
    switch = np.empty(nstages)
    adaptive = np.empty(nstages, dtype=np.bool_)
    for stage, gamma in enumerate(dyn.gammas):
        h = gamma * dyn.dt
        scales[stage] = dyn._scale(h)
        (memory[stage], local[stage], max_iter[stage], switch[stage],
         adaptive[stage]) = _solver_settings(dyn, stage, h)
    return gammas, scales, memory, local, max_iter, switch, adaptive


def _history_ring(st):
    """The predictor's increments of every stage in one ring buffer (stage,
    slot, n, 3), oldest first, with the counts and the newest's slots."""
    nstages = len(st.history)
    depth = st.history[0].maxlen
    ring = np.empty((nstages, depth) + st.s.shape)
    counts = np.empty(nstages, dtype=np.int64)
    heads = np.empty(nstages, dtype=np.int64)
    for stage, history in enumerate(st.history):
        for k, increment in enumerate(history):
            ring[stage, k] = increment
        counts[stage] = len(history)
        heads[stage] = len(history) - 1
    return ring, counts, heads


def _keep_history(st, ring, counts, heads):
    """The ring buffer back into the histories (views of it, oldest first)."""
    depth = ring.shape[1]
    for stage, history in enumerate(st.history):
        history.clear()
        for k in range(counts[stage] - 1, -1, -1):
            history.append(ring[stage, (heads[stage] - k) % depth])


def collective_block(dyn, steps):
    """Up to ``steps`` whole CollectivePRK steps as one compiled call
    (:func:`_run`, or :func:`_run_frozen` for a frozen lattice), for a small
    system whose every stage can take the fused step (frozen: whose one spin
    operator has ``linear_pairs``) and has a predictor history; the state is
    left after the last whole step, the Atoms not written. Returns (steps
    done, sweeps in all, sweeps and geometries of the last step); 0 steps:
    nothing changed, take the general path."""
    st = dyn._state
    if not blocks_allowed(type(dyn)) or not dyn.magnetic or not threads.small():
        return 0, 0, 0, 0
    if not all(st.history):
        return 0, 0, 0, 0
    st.policy = dyn.step_policy()
    if dyn.frozen:
        return _frozen_block(dyn, steps)
    got = _pieces(dyn)
    if got is None:
        return 0, 0, 0, 0
    step, lattice_data, data_q, data_t, merge = got
    run = _runner(step)
    # its compilation (~5 s: the step's code is compiled again inside it) is
    # paid as the fused step's is, whatever the size
    if not (_pays(dyn, step) and _pays(dyn, run)):
        return 0, 0, 0, 0
    ev = dyn.ev
    rules = st.policy
    gammas, scales, memory, local, max_iter, switch, adaptive = _stage_arrays(dyn)
    ring, counts, heads = _history_ring(st)
    theta = np.array(st.theta, dtype=float)
    settle = np.array(st.settle, dtype=float)
    orders = np.array(st.predictor_order, dtype=np.int64)
    rounds = np.array(st.settled_round, dtype=np.int64)
    (done, failed, q, p, s, FL, carry_q, carry_s, Wnext, swapped, sweeps, last_sweeps,
     last_geometries) = run(steps, st.q, st.p, st.s, st.FL, dyn.masses[:, 0], dyn.dt, gammas,
                            scales, st.carry_q, st.carry_p, st.carry_s, st.carry_mid,
                            st.Wnext, rules.tol, rules.first_fraction, rules.first_loosest,
                            rules.floor, max_iter, theta, settle, memory, local, switch,
                            adaptive, st.one_sweep, orders, ring, counts, heads, st.probe, st.kept, st.kept_n,
                            lattice_data,
                            data_q,
                            data_t, *_validity(ev),
                            rules.settled_tol, rules.qtol_floor,
                            kernels.COEFFICIENTS, merge, rounds)
    if done:
        st.q, st.p, st.s, st.FL = q, p, s, FL
        st.EL, st.EL_terms, st.VL = None, None, None
        st.carry_q, st.carry_s, st.Wnext = carry_q, carry_s, Wnext
        if swapped:
            st.ops, st.ops_next = st.ops_next, st.ops
        st.theta = theta.tolist()
        st.settle = settle.tolist()
        st.predictor_order = orders.tolist()
        st.settled_round = rounds.tolist()
        _keep_history(st, ring, counts, heads)
    if failed > 0:
        # a later stage gave up: the operator at q was refilled at that stage's
        # q̃; prepare it at q again for the general path
        st.ops = ev.spin_operators(st.q, out=st.ops, half=dyn.half_lists)
    return done, sweeps, last_sweeps, last_geometries


_frozen_runners = {}
#: Stands for the full pair list before it is made (see _run_frozen).
_NO_FULL_LIST = (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int32), np.zeros(0))


def _frozen_runner(half):
    """:func:`_run_frozen` over a half or a full pair list (compiled once each,
    cached on disk)."""
    fn = _frozen_runners.get(half)
    if fn is None:
        solve = kernels.midpoint_solve_half if half else kernels.midpoint_solve
        fn = _frozen_runners[half] = compile_with(
            _run_frozen, {"solve": solve.serial, "solve_full": kernels.midpoint_solve.serial,
                          "extrapolate": kernels.extrapolate_rows.serial,
                          "best_order": kernels.best_order_rows},
            "half" if half else "full")
    return fn


def _frozen_block(dyn, steps):
    """:func:`collective_block` for a frozen lattice."""
    st = dyn._state
    if dyn.atoms.constraints or len(st.ops) != 1 or not st.ops[0].linear:
        return 0, 0, 0, 0
    pairs, c = st.ops[0].linear_pairs(False)
    run = _frozen_runner(bool(pairs.half))
    if st.full_ops is not None or not pairs.half:
        # the full list's rows in colour order (a system of this size always
        # takes colour order where its stages want it)
        full_row, full_nbr, full_c, order, starts = dyn._colour_pairs(st.ops, False)
    else:  # made by the general path when a stage first needs it
        full_row, full_nbr, full_c = _NO_FULL_LIST
        order = starts = _NO_FULL_LIST[0]
    if not _pays(dyn, run):
        return 0, 0, 0, 0
    gammas, scales, memory, local, max_iter, switch, adaptive = _stage_arrays(dyn)
    ring, counts, heads = _history_ring(st)
    theta = np.array(st.theta, dtype=float)
    orders = np.array(st.predictor_order, dtype=np.int64)
    done, s, carry_s, Wnext, sweeps, last_sweeps = run(
        steps, st.s, dyn.dt, gammas, scales, st.carry_s, st.Wnext, st.policy.tol, st.policy.floor,
        max_iter, theta, memory, local, switch, adaptive, st.one_sweep, orders, ring, counts,
        heads, st.probe, st.kept, st.kept_n, pairs.row, pairs.j, c, kernels.COEFFICIENTS,
        st.sweep_order, st.theta_index, full_row, full_nbr, full_c, order, starts)
    if done:
        st.s, st.carry_s, st.Wnext = s, carry_s, Wnext
        st.theta = theta.tolist()
        st.predictor_order = orders.tolist()
        _keep_history(st, ring, counts, heads)
    return done, sweeps, last_sweeps, 0
