"""The skeletons of the compiled small-system step (:mod:`ase_spin.md.fused`):
CollectivePRK's coupled second-order step (:func:`coupled_step`), whole runs
of steps of every stage of a composition (:func:`run_steps`, and
:func:`run_frozen_steps` for a frozen lattice), written over named pieces
(``lattice_forces``, ``spin_forces``, ``spin_geometry``, ``spin_couplings``,
``fused_step``, ...) that :func:`ase_spin._jit.cloning.compile_with` binds to
the terms' compiled pieces. Every decision a step takes comes from
:mod:`ase_spin.md.policy`, as in the Python executor.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from ..neighbors import all_finite, largest_displacements
from . import kernels, policy

__all__ = ["coupled_step", "run_steps", "run_frozen_steps", "both_lattice", "no_lattice",
           "no_forces_two", "no_add_kept", "DONE", "GIVE_UP"]

DONE, GIVE_UP = 0, 1

# Constants passed to another kernel are written np.int64(1), np.bool_(False):
# numba types a bare 1 or False as a literal and compiles that kernel again for
# it, beside the specialisation the general path already compiled.


def coupled_step(q, p, s, FL, m, h, carry_q, carry_p, carry_s, carry_mid, W, Wnext, scale, tol,
          first_tol, floor, max_iter, theta, lattice, op_q, op_t, reference, radius,
          fine_reference, fine_radius, settled_tol, qtol_floor, memory, local, switch,
          adaptive, one_sweep, predict, coef, hs, n_history, probe, kept, kept_n, field, merge,
          settled_round, overlap):
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
    which cost the block of steps time: ``benchmarks/small_systems.py``). The first solve stops at
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
    settled in (−1: by a solve that moved W by round-off only).

    F_L is taken at the q̃ of the step's couplings (the last geometry's, within
    round-off of the last drift's), as CollectivePRK._coupled_step takes it. With
    ``overlap`` it is made on one thread while another makes the couplings at
    each new q̃ and solves there (two branches of a ``prange``; with one thread
    in turn, the same bits); the one made at the last geometry is kept."""
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
    no_order = np.zeros(0, dtype=np.int64)  # kernels.NO_ORDER: sweeps in index order
    no_external = np.zeros((0, 3))  # kernels.NO_FIELD: no field held fixed
    settled_in = -1
    FLt = np.zeros_like(q)
    made_at = -1  # the geometry FLt was made at (beside its solve), −1: none
    ints = np.zeros(3, dtype=np.int64)  # a solve's results from beside F_L: its, status, which
    reals = np.zeros(3)  # ... delta, the contraction measured, how far W moved
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
            np.int64(1), p, 0.5 * h, F, carry_p, P, carry_mid, q, m, h, carry_q, qt, carry_qt,
            qt_used)
        new_q = True  # as CollectivePRK: a new q̃ gets its couplings
        if first:
            if not moved <= radius:
                return (GIVE_UP, q, p, s, q, s, FL, W, Wnext, theta, 0, 0, -1, settle, s,
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
                return (GIVE_UP, q, p, s, q, s, FL, W, Wnext, theta, 0, 0, -1, settle, s,
                        one_sweep, settled_round)
            geometries += 1
        stilde = np.zeros_like(s)
        carry = np.zeros_like(s)
        use_tol = first_tol if solves == 0 else tol
        use_local = local
        # the step's first solve, to tol (not a loose one, not a later one)
        chooses = adaptive and solves == 0 and not use_tol > tol
        if chooses:
            use_local = policy.auto_takes_local(one_sweep, theta)
        if overlap and new_q:
            # F_L at this q̃ on one thread, its couplings and the solve on the other
            FLt[:] = 0.0
            for branch in nb.prange(2):
                if branch == 0:
                    lattice_forces(qt, lattice, FLt, True)  # noqa: F821
                else:
                    spin_geometry(qt, op_t, op_q, True)  # noqa: F821
                    row, nbr, c = spin_couplings(op_t)  # noqa: F821
                    got = solve_half(  # noqa: F821
                        np.int64(1), row, nbr, c, s, W, Wnext, stilde, scale, use_tol, floor,
                        max_iter, policy.start_contraction(theta), carry_s, carry, memory,
                        use_local, field, no_order, no_order, no_external)
                    ints[0], reals[0], ints[1], ints[2], reals[1], reals[2] = got
            its, delta, status, which, measured, moved_w = (
                ints[0], reals[0], ints[1], ints[2], reals[1], reals[2])
            made_at = geometries
        else:
            if new_q:
                spin_geometry(qt, op_t, op_q, False)  # noqa: F821
            row, nbr, c = spin_couplings(op_t)  # noqa: F821
            its, delta, status, which, measured, moved_w = solve_half(  # noqa: F821
                np.int64(1), row, nbr, c, s, W, Wnext, stilde, scale, use_tol, floor, max_iter,
                policy.start_contraction(theta), carry_s, carry, memory, use_local, field,
                no_order, no_order, no_external)
        if status == kernels.NOT_CONVERGED or policy.gives_up(its, measured, switch):
            return (GIVE_UP, q, p, s, q, s, FL, W, Wnext, theta, 0, 0, -1, settle, s,
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
        return (GIVE_UP, q, p, s, q, s, FL, W, Wnext, theta, 0, 0, -1, settle, s,
                one_sweep, settled_round)
    if made_at != geometries:
        FLt[:] = 0.0
        lattice_forces(qt_used, lattice, FLt, False)  # noqa: F821
    if not all_finite(FLt):
        return (GIVE_UP, q, p, s, q, s, FL, W, Wnext, theta, 0, 0, -1, settle, s,
                one_sweep, settled_round)
    if pending:
        F = np.empty_like(FLt)
        add_kept(keep, FLt, F)  # noqa: F821
    else:
        F = FLt.copy()
        spin_forces(W, op_t, F)  # noqa: F821
    kick(P, 0.5 * h, F, carry_mid, P, carry_p)  # noqa: F821
    order = -1
    increment = difference(W, s)
    if predict and n_history > 0:
        order = best_order(n_history, hs[0], hs[1], hs[2], hs[3], hs[4], hs[5],  # noqa: F821
                           hs[6], hs[7], hs[8], hs[9], hs[10], hs[11], hs[12], hs[13],
                           hs[14], hs[15], increment, probe, probe, kept, kept_n)
    return (DONE, qt, P, stilde, carry_qt, carry, FLt, W, Wnext, theta, iterations,
            geometries, order, settle, increment, one_sweep, settled_in)


@nb.njit(cache=True)
def difference(a, b):
    """a − b as a loop: an array expression in the fused step, compiled with
    ``parallel`` for its branches, would be compiled as a function of its own
    that numba then warns it cannot parallelise."""
    out = np.empty_like(a)
    for i in range(a.shape[0]):
        for k in range(a.shape[1]):
            out[i, k] = a[i, k] - b[i, k]
    return out


@nb.njit(cache=True, inline="always")
def push_increments(ring, heads, counts, increments):
    """Each stage's increment of a whole step into its ring buffer (stage,
    slot, n, 3): the newest at the slot after ``heads``, ``counts`` up to the
    buffer's depth."""
    depth = ring.shape[1]
    for stage in range(ring.shape[0]):
        heads[stage] = (heads[stage] + 1) % depth
        ring[stage, heads[stage]] = increments[stage]
        counts[stage] = min(counts[stage] + 1, depth)


@nb.njit(cache=True, inline="always")
def tentative(theta, real, orders, whole, one_sweep):
    """Copies of the per-stage values a step updates stage by stage: θ, the
    predictor's order, the one-sweep choice, and a real and a whole number of
    the runner's own (:func:`run_steps`: how far the second solve moved W and
    the round the stage settled in; :func:`run_frozen_steps`: the index
    order's contraction and the sweep order, policy.next_sweep_order's),
    kept by :func:`keep_stages` once the whole step is taken."""
    return theta.copy(), real.copy(), orders.copy(), whole.copy(), one_sweep.copy()


@nb.njit(cache=True, inline="always")
def keep_stages(new, theta, real, orders, whole, one_sweep, ring, heads, counts, increments):
    """A whole step taken: each stage's values (those of :func:`tentative`)
    become the step's ``new`` ones (a step not taken whole leaves them as
    they were), and its increment W − s joins its history
    (:func:`push_increments`)."""
    new_theta, new_real, new_orders, new_whole, new_one_sweep = new
    theta[:] = new_theta
    real[:] = new_real
    orders[:] = new_orders
    whole[:] = new_whole
    one_sweep[:] = new_one_sweep
    push_increments(ring, heads, counts, increments)


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


def run_steps(steps, q, p, s, FL, m, dt, gammas, scales, carry_q, carry_p, carry_s, carry_mid,
         Wnext, tol, fraction, loosest, floor, max_iter, theta, settle, memory, local, switch,
         adaptive, one_sweep, orders, ring, counts, heads, probe, kept, kept_n, lattice, op_q, op_t, reference,
         radius, fine_reference, fine_radius, settled_tol, qtol_floor, coefficients, merge,
         rounds, overlap):
    """Up to ``steps`` whole steps (every stage γ_k h of the composition) of the
    fused step (compiled with ``fused_step`` bound to :func:`coupled_step` of the
    terms' pieces), as CollectivePRK takes them one by one with nothing
    between: the same calls with the same arguments, so the same bits. What
    the Python side keeps per stage comes in arrays, updated in place: the
    contraction ``theta``, how far the second solve moved W (``settle``), the
    whether its last solve took one sweep (``one_sweep``; ``adaptive``: see
    :func:`coupled_step`), the predictor's ``orders`` and its increments in ``ring``
    (stage, slot, n, 3) with ``counts`` kept and the newest at ``heads``, the
    difference tables of
    its order choice (``kept``, ``kept_n``: per stage; those of a step not
    taken are dropped, kept_n = 0), the outer round each
    stage settled in (``rounds``; ``merge``, ``overlap``: see :func:`coupled_step`). A step is taken whole or
    not at all: where a stage gives up (see :func:`coupled_step`) the state is that
    of the last whole step (``carry_p``, the one array the step changes in
    place, put back). Returns (steps done, the stage that gave up or −1, q, p,
    s, F_L, carry of q and of s, the spare W buffer, whether the two spin
    operators swapped roles, sweeps in all, sweeps and geometries of the last
    step)."""
    nstages = gammas.shape[0]
    saved_p = np.empty_like(carry_p)
    increments = np.empty((nstages,) + s.shape)
    field = np.empty_like(s)  # the midpoint fields (not used here)
    new = tentative(theta, settle, orders, rounds, one_sweep)
    new_theta, new_settle, new_orders, new_rounds, new_one_sweep = new
    done = sweeps = last_sweeps = 0
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
            # no history yet (a run's first step): W starts at s, as CollectivePRK._predict
            W_start = hs[0] if count > 0 else s.copy()
            (status, qt, P, s_new, cq, cs, FLt, W, Wn, th, its, geos, order, moved,
             increment, single, rnd) = fused_step(  # noqa: F821 - bound per combination
                q, p, s, FL, m, gammas[stage] * dt, carry_q, carry_p, carry_s, carry_mid,
                W_start, Wnext, scales[stage], tol, first_tol, floor, max_iter[stage],
                theta[stage], lattice, oq, ot, reference, radius, fine_reference, fine_radius,
                settled_tol, qtol_floor,
                memory[stage], local[stage], switch[stage], adaptive[stage], one_sweep[stage],
                count > 0, coefficients[min(orders[stage], count - 1)], hs, count, probe,
                kept[stage],
                kept_n[stage:stage + 1], field, merge, rounds[stage], overlap)
            if status != DONE:
                failed = stage
                break
            q, p, s, FL, carry_q, carry_s, Wnext = qt, P, s_new, FLt, cq, cs, Wn
            oq, ot = ot, oq
            new_theta[stage] = th
            if moved >= 0.0:
                new_settle[stage] = moved
            if order >= 0:  # (−1: no history to choose it from; kept, as in Python)
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
        keep_stages(new, theta, settle, orders, rounds, one_sweep, ring, heads, counts,
                    increments)
        if nstages % 2 == 1:
            op_q, op_t = op_t, op_q
            swapped = not swapped
        done += 1
        sweeps += its_step
        last_sweeps = its_step
        last_geometries = geometries
    return (done, failed, q, p, s, FL, carry_q, carry_s, Wnext, swapped, sweeps, last_sweeps,
            last_geometries)


def run_frozen_steps(steps, s, dt, gammas, scales, carry_s, Wnext, tol, floor, max_iter, theta,
                memory, local, switch, adaptive, one_sweep, orders, ring, counts, heads, probe,
                kept, kept_n, row, nbr, c, coefficients, sweep_order, theta_index, full_row,
                full_nbr, full_c, order, starts):
    """:func:`run_steps` for a frozen lattice (CollectivePRK's spins-only step,
    ``_substep`` with ``lattice="frozen"``) with one spin operator of the form
    B_i = Σ_j c_k W_j (``linear_pairs``: row, nbr, c): per stage the
    predictor (``extrapolate``), the midpoint solve (``solve``: the serial
    twin of kernels.midpoint_solve_half or midpoint_solve, bound per pair-list
    kind) and the predictor's order (its difference tables ``kept``,
    ``kept_n`` as in :func:`run_steps`) and increment, the same calls as the
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
    no_order = np.zeros(0, dtype=np.int64)  # kernels.NO_ORDER: sweeps in index order
    nstages = gammas.shape[0]
    increments = np.empty((nstages,) + s.shape)
    new = tentative(theta, theta_index, orders, sweep_order, one_sweep)
    new_theta, new_theta_index, new_orders, new_sweep_order, new_one_sweep = new
    done = sweeps = last_sweeps = 0
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
                    np.int64(1), full_row, full_nbr, full_c, s, W, Wnext, stilde,
                    scales[stage], tol, floor, max_iter[stage],
                    policy.start_contraction(theta[stage]), carry_s, carry, memory[stage],
                    use_local, no_field, order, starts, no_field)
            else:
                its, delta, status, which, measured, moved = solve(  # noqa: F821
                    np.int64(1), row, nbr, c, s, W, Wnext, stilde, scales[stage], tol, floor,
                    max_iter[stage], policy.start_contraction(theta[stage]), carry_s, carry,
                    memory[stage], use_local, no_field, no_order, no_order, no_field)
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
        keep_stages(new, theta, theta_index, orders, sweep_order, one_sweep, ring, heads, counts,
                    increments)
        done += 1
        sweeps += its_step
        last_sweeps = its_step
    return done, s, carry_s, Wnext, sweeps, last_sweeps


def both_lattice(positions, data, forces, serial):
    """Two lattice pieces in turn (the terms' order, as Evaluator.lattice)."""
    first_lattice(positions, data[0], forces, serial)  # noqa: F821
    second_lattice(positions, data[1], forces, serial)  # noqa: F821


@nb.njit(cache=True)
def no_lattice(positions, data, forces, serial):
    pass




@nb.njit(cache=True)
def no_forces_two(W, data, there, F):
    """Stands for a ``forces_two`` piece the operator does not offer (never
    called: the step's ``merge`` is then False)."""
    return np.empty((0, 0, 6))


@nb.njit(cache=True)
def no_add_kept(keep, base, out):
    """Stands for an ``add_kept`` piece the operator does not offer."""
