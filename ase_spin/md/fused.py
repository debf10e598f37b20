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

The fused step is taken whenever it applies, whatever the run's length: a
small system's fastest exact path is its default path. Its compilation (once
per combination of pieces and per install, then loaded from numba's disk
cache) is paid by ``ase-spin compile`` (:mod:`ase_spin.app.warmup`) for the
built-in scenes, or else by the first run that reaches it, not by running
slower.
"""

from __future__ import annotations

import numpy as np

from .._jit import threads
from .._jit.cloning import compile_with
from . import kernels, policy
from .fused_skeletons import (DONE, both_lattice, coupled_step, no_add_kept, no_forces_two,
                              no_lattice, run_frozen_steps, run_steps)

__all__ = ["collective_block", "collective_step", "step_function"]



_steps = {}


def step_function(lattice, spin, two=None):
    """The fused step for a lattice piece and a spin operator's pieces, with
    its ``(forces_two, add_kept)`` pieces if it offers them (compiled once per
    combination, cached on disk)."""
    two = two or (no_forces_two, no_add_kept)
    key = (lattice, *spin, *two)
    fn = _steps.get(key)
    if fn is None:
        forces, geometry, couplings = spin
        fn = _steps[key] = compile_with(
            coupled_step, {"lattice_forces": lattice, "spin_forces": forces,
                    "spin_geometry": geometry, "spin_couplings": couplings,
                    "spin_forces_two": two[0], "add_kept": two[1],
                    "kick_drift": kernels.kick_drift.serial, "kick": kernels.kick.serial,
                    "solve_half": kernels.midpoint_solve_half.serial,
                    "extrapolate": kernels.extrapolate_rows.serial,
                    "best_order": kernels.best_order_rows},
            f"{lattice.__name__}_{forces.__name__}", parallel=True)
    return fn


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
        return no_lattice, ()
    fn, data = pieces[0]
    for f2, d2 in pieces[1:]:
        key = (fn, f2)
        both = _pairs_of.get(key)
        if both is None:
            both = _pairs_of[key] = compile_with(
                both_lattice, {"first_lattice": fn, "second_lattice": f2},
                f"{fn.__name__}_{f2.__name__}")
        fn, data = both, (data, d2)
    return fn, data


_UNSEEN = object()


def _pieces(dyn):
    """(the fused step, lattice data, the two spin operators' data: at q and at
    q̃, whether the step may begin the end forces in an outer round's pass) when
    the system is small (light kernels serial: threads.small()) and
    every term offers its pieces, else None."""
    st = dyn._state
    ev = dyn.ev
    if (not threads.small() or len(st.ops) != 1
            or ev.neighbors is None or st.constraints or not dyn.half_lists):
        return None
    if not type(dyn).compiled_step:
        return None
    if st.ops_next is None:
        # a run's first step: the operator the step prepares at q̃ (its
        # geometry piece refills it there), made as the general path makes it,
        # here at q, where the pair lists hold (st.ops were made there)
        st.ops_next = ev.spin_operators(st.q, mean_with=st.ops, half=dyn.half_lists,
                                        refreshed=True)
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
    # F_L beside the midpoint solve, on another thread (coupled_step's
    # ``overlap``): where there are lattice forces and the system is not so
    # small that starting a parallel region costs more than they do
    overlap = lattice_fn is not no_lattice and not threads.tiny()
    return step, lattice_data, piece_q[3], piece_t[3], pieces["merge"], overlap


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
    step, lattice_data, data_q, data_t, merge, overlap = got
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
                                       field, merge, st.settled_round[stage], overlap)
    if status != DONE:
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
    """:func:`run_steps` for a fused step (compiled once per combination, cached on disk)."""
    fn = _runners.get(step)
    if fn is None:
        fn = _runners[step] = compile_with(run_steps, {"fused_step": step},
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
    (:func:`run_steps`, or :func:`run_frozen_steps` for a frozen lattice), for a small
    system whose every stage can take the fused step (frozen: whose one spin
    operator has ``linear_pairs`` and whose stages have a predictor history);
    the first step of a run included (W starts at s, as CollectivePRK._predict
    without a history); the state is
    left after the last whole step, the Atoms not written. Returns (steps
    done, sweeps in all, sweeps and geometries of the last step); 0 steps:
    nothing changed, take the general path."""
    st = dyn._state
    if not blocks_allowed(type(dyn)) or not dyn.magnetic or not threads.small():
        return 0, 0, 0, 0
    st.policy = dyn.step_policy()
    if dyn.frozen:
        if not all(st.history):
            return 0, 0, 0, 0
        return _frozen_block(dyn, steps)
    got = _pieces(dyn)
    if got is None:
        return 0, 0, 0, 0
    step, lattice_data, data_q, data_t, merge, overlap = got
    run = _runner(step)
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
                            kernels.COEFFICIENTS, merge, rounds, overlap)
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
#: Stands for the full pair list before it is made (see run_frozen_steps).
_NO_FULL_LIST = (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int32), np.zeros(0))


def _frozen_runner(half):
    """:func:`run_frozen_steps` over a half or a full pair list (compiled once each,
    cached on disk)."""
    fn = _frozen_runners.get(half)
    if fn is None:
        solve = kernels.midpoint_solve_half if half else kernels.midpoint_solve
        fn = _frozen_runners[half] = compile_with(
            run_frozen_steps, {"solve": solve.serial, "solve_full": kernels.midpoint_solve.serial,
                          "extrapolate": kernels.extrapolate_rows.serial,
                          "best_order": kernels.best_order_rows},
            "half" if half else "full")
    return fn


def _frozen_block(dyn, steps):
    """:func:`collective_block` for a frozen lattice."""
    st = dyn._state
    if st.constraints or len(st.ops) != 1 or not st.ops[0].linear:
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
