"""The midpoint solvers: W of the spherical midpoint rule,
W = normalise(s + s̃), s̃ = s + c W × B̄(W), solved by Jacobi or locally exact
sweeps with optional Anderson acceleration, over one linear pair operator
(B̄_i = Σ_j c_ij W_j, in one compiled loop) or any spin operators.

All solve the same equation to the same tolerance; the locally exact sweeps
and Anderson's acceleration exist because they take fewer sweeps than Jacobi
from moderate steps on and still converge at steps where Jacobi stops
contracting (``benchmarks/solver.py`` for the largest step,
``benchmarks/solver_choice.py`` for the cost of each; docs/benchmarks.md, "The
midpoint solver against the step size"). The colour-ordered sweeps exist only
to save sweeps on a frozen lattice (``benchmarks/frozen_before_after.py``;
docs/benchmarks.md, "Why each fast path exists")."""

from __future__ import annotations

import numba as nb
import numpy as np

from ..._jit import threads
from ..._jit.cloning import kernel_twin
from ..._jit.reductions import balanced_chunks, reduce_threads, reduce_threads_serial
from ..._jit.threads import threaded
from .anderson import after_sweep, anderson_mix, anderson_mix_serial
from .midpoint import (MEMORY, NOT_CONVERGED, coloured_spins, coloured_sweep, end_points_of_rows,
                       local_midpoint_direction, pair_field_row, update_row)
from .predictor import max_abs_difference

#: ``field`` of the midpoint solvers when no midpoint fields are wanted: an
#: empty array rather than None, so that callers that want them (the fused
#: step, Langevin) and callers that do not share one compiled specialisation.
NO_FIELD = np.zeros((0, 3))
#: ``order`` and ``starts`` of :func:`_midpoint_solve` for sweeps in index
#: order (an empty array, not None: one compiled specialisation for every caller).
NO_ORDER = np.zeros(0, dtype=np.int64)


@nb.njit(cache=True, inline="always")
def _solver_buffers(n, memory, local):
    """(dF, dG, fprev, gprev, gram, jacobi_rows) of a midpoint solve over n
    spins: the Anderson history of ``memory`` sweeps (:func:`anderson_mix`)
    and the rows the locally exact update left to the Jacobi one. (Scalars
    in: an array passed into an inlined function with branches costs a
    reference-count increment and decrement.)"""
    dF = np.empty((memory, n, 3))
    dG = np.empty((memory, n, 3))
    fprev = np.empty((n if memory > 0 else 0, 3))
    gprev = np.empty((n if memory > 0 else 0, 3))
    gram = np.zeros((memory, memory))
    jacobi_rows = np.zeros(n if local else 0, dtype=np.bool_)
    return dF, dG, fprev, gprev, gram, jacobi_rows


#: Read by :func:`_midpoint_solve` as a compile-time constant: False in
#: :data:`midpoint_solve` (a full pair list), True in its twin
#: :data:`midpoint_solve_half` (a half list; :func:`~ase_spin._jit.cloning.kernel_twin`).
#: One solver, two compiled kernels: each holds only its own sweep.
_HALF = False


def _midpoint_solve(nthreads, row, nbr, Jbar, s, W, Wnext, stilde, scale, tol, floor, max_iter,
                    theta0, carry, carry_out, memory, local, field, order, starts, external):
    r"""Solve the spherical-midpoint equation for fixed pair couplings J̄_ij:

    .. math::

        \tilde{\mathbf s}_i = \mathbf s_i + c\, \mathbf W_i \times \bar{\mathbf B}_i,
        \qquad \bar{\mathbf B}_i = \sum_j \bar J_{ij} \mathbf W_j + \mathbf E_i, \qquad
        \mathbf W_i = \frac{\mathbf s_i + \tilde{\mathbf s}_i}{|\mathbf s_i + \tilde{\mathbf s}_i|},

    with c = hσ/ħ (per spin: ``scale`` holds c_i, which carries each spin's
    precession rate factor). Each sweep maps the iterate W to g(W): with
    ``local`` (the default), every spin's own equation solved exactly in the
    field of the others, B̄_i(W) held fixed (:func:`local_midpoint`, a Cayley
    rotation about B̄_i; contracts for every step size where the plain
    iteration may not; the end points made once, after the last sweep:
    :func:`end_points_of_rows`). With a colour order (``order``: the atoms colour by
    colour, no two of one colour paired; neighbors.greedy_colouring) the
    locally exact sweep takes the colours in turn (Gauss–Seidel order), spin i
    of colour c in the field

    .. math:: \bar{\mathbf B}_i = \sum_{j:\, c_j < c} \bar J_{ij} g(W)_j
              + \sum_{j:\, c_j > c} \bar J_{ij} \mathbf W_j,

    which contracts about as fast as two sweeps in index order (the error is
    squared on a two-colourable lattice); the spins of one colour are
    independent, so they are solved side by side. With ``order`` the rows of
    ``row``, ``nbr`` and ``Jbar`` are taken in that order (row a belongs to
    spin ``order[a]``: neighbors.rows_in_order), so that each colour's rows
    are read as one stretch of memory. With ``starts`` (colour c
    is ``order[starts[c]:starts[c + 1]]``) and more than one chunk, each colour
    in a parallel region of its own, its spins split evenly among the chunks;
    else in one serial pass (:func:`coloured_sweep`). Either way each spin
    sees the same values, so the bits do not depend on the chunks. Else the
    Jacobi map g(W) = (2 s + c W × B̄(W)) /
    |2 s + c W × B̄(W)|, which contracts only while c|B̄| ≲ 1. With ``memory``
    m > 0, the next iterate is the Anderson combination of the last m + 1
    sweeps (:func:`anderson_mix`); else g(W). Rows with s_i = 0 (non-magnetic atoms) are skipped.

    Over a half pair list (:data:`midpoint_solve_half`; each pair once, half
    the memory traffic; ``order`` and ``starts`` not read) each sweep
    scatters J̄_ij W_j into row i and J̄_ij W_i into row j of per-thread
    buffers, then updates every spin from their sum, B̄_i = Σ_t buf_t,i in
    thread order (so in index order only: no row has its whole field before
    the pass ends).

    ``W`` holds the starting guess; ``Wnext`` is a buffer of the same shape (zero
    on non-magnetic rows). ``stilde`` receives the end point of the last sweep,
    s + c W × B̄ written as the reflection of s about the midpoint direction (see
    :func:`update_row`): |s̃| = |s| to round-off, never renormalised. The
    sum is compensated (Kahan): ``carry`` holds the rounding error of the
    previous step's update, added back here, and ``carry_out`` receives this
    one's.

    Stops when the distance to the solution, bounded by θ/(1−θ)·max|ΔW| with θ
    the observed contraction per sweep (``theta0``, from earlier solves, until
    two sweeps have been made), is at most ``tol``; or when the change has
    stopped falling below ``floor`` (round-off reached). Returns (iterations,
    last max|ΔW|, status, index of the buffer holding the result: 0 = W,
    1 = Wnext, contraction θ observed, or −1 if none was, max|ΔW| of the
    first sweep: how far the starting guess was from the result). ``field``,
    if not empty (:data:`NO_FIELD`), receives the midpoint fields B̄_i
    of the last sweep's input iterate (magnetic rows; the others are not
    written). ``external``, if not empty (:data:`NO_FIELD`), is a field E
    fixed during the solve (the fields a solve holds while the rest converges:
    :func:`midpoint_solve_held`), added to every spin's; with it the sweeps
    take index order (``order`` not read).
    """
    n = len(row) - 1
    held = external.shape[0] > 0
    bounds = balanced_chunks(row, nthreads)
    if _HALF:  # the update pass reads no pairs: the atoms in even chunks
        atoms = np.empty(nthreads + 1, dtype=np.int64)
        for t in range(nthreads + 1):
            atoms[t] = (n * t) // nthreads
    else:
        atoms = bounds
    buf = np.zeros((nthreads, n if _HALF else 0, 3))
    change = np.zeros(nthreads)
    dF, dG, fprev, gprev, gram, jacobi_rows = _solver_buffers(n, memory, local)
    cur = W
    nxt = Wnext
    which = 1  # the buffer nxt is: 0 = W, 1 = Wnext
    previous = np.inf
    theta = theta0
    measured = -1.0
    delta = 0.0
    first = 0.0
    status = -1
    it = 0
    by_colour = order
    coloured = local and len(by_colour) > 0 and not held
    colour_starts = starts
    threaded_colours = coloured and nthreads > 1 and len(colour_starts) > 1
    for it in range(1, max_iter + 1):
        if _HALF:
            for t in nb.prange(nthreads):
                _midpoint_solve_chunk0(np.int64(t), bounds, cur, buf, row, nbr, Jbar)
        elif threaded_colours:
            for t in nb.prange(nthreads):
                for i in range((n * t) // nthreads, (n * (t + 1)) // nthreads):
                    nxt[i, 0] = cur[i, 0]
                    nxt[i, 1] = cur[i, 1]
                    nxt[i, 2] = cur[i, 2]
                change[t] = 0.0
            for col in range(len(colour_starts) - 1):
                lo = colour_starts[col]
                size = colour_starts[col + 1] - lo
                for t in nb.prange(nthreads):
                    d = coloured_spins(lo + (size * t) // nthreads,
                                        lo + (size * (t + 1)) // nthreads, row, nbr, Jbar, s,
                                        cur, nxt, scale, stilde, carry, carry_out, jacobi_rows,
                                        field, by_colour)
                    if not d <= change[t] and change[t] == change[t]:  # (NaN stays)
                        change[t] = d
        elif coloured:
            change[:] = 0.0
            change[0] = coloured_sweep(row, nbr, Jbar, s, cur, nxt, scale, stilde, carry,
                                        carry_out, jacobi_rows, field, by_colour)
        if _HALF or not coloured:  # index order: each spin from its whole field
            for t in nb.prange(nthreads):
                _midpoint_solve_chunk1(np.int64(t), _HALF, held, local, atoms, nthreads, row, nbr,
                                       Jbar, cur, external, field, s, nxt, scale, stilde, carry,
                                       carry_out, jacobi_rows, buf, change)
        delta = change.max()
        status, theta, measured, first = after_sweep(it, delta, previous, theta, measured,
                                                      first, tol, floor)
        if status >= 0:
            break
        previous = delta
        if memory > 0:
            anderson_mix(it, cur, nxt, fprev, gprev, dF, dG, gram)
        else:
            cur, nxt = nxt, cur
            which = 1 - which
    if local:
        for t in nb.prange(nthreads):
            end_points_of_rows(atoms[t], atoms[t + 1], s, nxt, stilde, carry, carry_out,
                        jacobi_rows)
    if status < 0:
        return max_iter, delta, NOT_CONVERGED, which, measured, first
    return it, delta, status, which, measured, first


@nb.njit(cache=True, error_model="numpy")
def _midpoint_solve_chunk0(t, bounds, cur, buf, row, nbr, Jbar):
    """One chunk ``t`` of :func:`_midpoint_solve`'s threaded loop: its work,
    compiled once for the threaded kernel and its serial twin."""
    for i in range(bounds[t], bounds[t + 1]):
        wx = cur[i, 0]
        wy = cur[i, 1]
        wz = cur[i, 2]
        bx = 0.0
        by = 0.0
        bz = 0.0
        for k in range(row[i], row[i + 1]):
            j = nbr[k]
            Jk = Jbar[k]
            bx += Jk * cur[j, 0]
            by += Jk * cur[j, 1]
            bz += Jk * cur[j, 2]
            buf[t, j, 0] += Jk * wx
            buf[t, j, 1] += Jk * wy
            buf[t, j, 2] += Jk * wz
        buf[t, i, 0] += bx
        buf[t, i, 1] += by
        buf[t, i, 2] += bz


@nb.njit(cache=True, error_model="numpy")
def _midpoint_solve_chunk1(t, half, held, local, atoms, nthreads, row, nbr, Jbar, cur, external,
                           field, s, nxt, scale, stilde, carry, carry_out, jacobi_rows, buf,
                           change):
    """One chunk ``t`` of :func:`_midpoint_solve`'s update pass in index order:
    its work, compiled once for the threaded kernel, its serial twin and the
    half-list twin (``half``: the twin's ``_HALF``, the fields summed from the
    per-thread buffers rather than from the rows)."""
    m = 0.0
    for i in range(atoms[t], atoms[t + 1]):
        if half:
            bx = 0.0
            by = 0.0
            bz = 0.0
            for u in range(nthreads):
                bx += buf[u, i, 0]
                by += buf[u, i, 1]
                bz += buf[u, i, 2]
                buf[u, i, 0] = 0.0
                buf[u, i, 1] = 0.0
                buf[u, i, 2] = 0.0
        if s[i, 0] == 0.0 and s[i, 1] == 0.0 and s[i, 2] == 0.0:
            continue
        if not half:
            bx, by, bz = pair_field_row(i, row, nbr, Jbar, cur)
        if held:
            bx += external[i, 0]
            by += external[i, 1]
            bz += external[i, 2]
        if field is not None and field.shape[0] > 0:
            field[i, 0] = bx
            field[i, 1] = by
            field[i, 2] = bz
        if local:
            d = local_midpoint_direction(i, s, cur, nxt, bx, by, bz, scale,
                                          stilde, carry, carry_out, jacobi_rows)
        else:
            d = update_row(i, s, cur, nxt, bx, by, bz, scale, stilde, carry,
                                 carry_out)
        if not d <= m and m == m:  # a NaN stays (max(m, d) drops it)
            m = d
    change[t] = m


midpoint_solve = threaded(anderson_mix=lambda: anderson_mix_serial)(_midpoint_solve)
midpoint_solve_half = threaded(anderson_mix=lambda: anderson_mix_serial)(
    kernel_twin(_midpoint_solve, "_half", _HALF=True))


@threaded()
def midpoint_update(nthreads, s, W, Wnext, B, scale, stilde, carry, carry_out, local,
                    jacobi_rows):
    """One sweep of the midpoint iteration for given midpoint fields B̄ = ``B``
    (the sum of every spin operator's field at W): the locally exact update of
    :func:`local_midpoint_direction` (``local``; the end points are left to
    :func:`end_points` after the last sweep, the rows it leaves to the Jacobi
    update marked in ``jacobi_rows``) or the Jacobi update of
    :func:`update_row` for every magnetic spin (rows with s_i = 0 are
    skipped), W → ``Wnext``. Returns max |ΔW| over all components."""
    n = s.shape[0]
    change = np.zeros(nthreads)
    for t in nb.prange(nthreads):
        _midpoint_update_chunk(np.int64(t), local, nthreads, n, s, W, Wnext, scale, stilde, carry,
                               carry_out, jacobi_rows, B, change)
    return change.max()


@nb.njit(cache=True, error_model="numpy")
def _midpoint_update_chunk(t, local, nthreads, n, s, W, Wnext, scale, stilde, carry, carry_out,
                           jacobi_rows, B, change):
    """One chunk ``t`` of :func:`midpoint_update`'s threaded loop: its work,
    compiled once for the threaded kernel and its serial twin."""
    m = 0.0
    for i in range((n * t) // nthreads, (n * (t + 1)) // nthreads):
        if s[i, 0] == 0.0 and s[i, 1] == 0.0 and s[i, 2] == 0.0:
            continue
        if local:
            d = local_midpoint_direction(i, s, W, Wnext, B[i, 0], B[i, 1], B[i, 2], scale,
                                          stilde, carry, carry_out, jacobi_rows)
        else:
            d = update_row(i, s, W, Wnext, B[i, 0], B[i, 1], B[i, 2], scale, stilde,
                                 carry, carry_out)
        if not d <= m and m == m:  # a NaN stays (max(m, d) drops it)
            m = d
    change[t] = m


@threaded()
def end_points(nthreads, s, W, stilde, carry, carry_out, jacobi_rows):
    """The end points after the last of :func:`midpoint_update`'s locally exact
    sweeps (:func:`end_points_of_rows`: W their result)."""
    n = s.shape[0]
    for t in nb.prange(nthreads):
        end_points_of_rows((n * t) // nthreads, (n * (t + 1)) // nthreads, s, W, stilde, carry,
                    carry_out, jacobi_rows)


@threaded(reduce_threads=lambda: reduce_threads_serial)
def linear_field_and_form(nthreads, row, nbr, c, half, u, y, x, out):
    """One pass over the pairs of a term in the ``linear_pairs`` form (B = C x,
    B_i = Σ_j c_k x_j over k = (i → j), C symmetric): out += C u, and returns
    the forms (d·C d, x·C d) = Σ_i Σ_j c_k (d_i·d_j, x_i·d_j) of the move
    d = y − x (formed per row: one (n, 3) array fewer to write and read). A
    half list holds each pair once: scattered into row j too, each pair's
    terms taken both ways; per-thread buffers and sums added in thread order."""
    n = len(row) - 1
    bounds = balanced_chunks(row, nthreads)
    buf = np.zeros((nthreads, n if half else 0, 3))
    form = np.zeros((nthreads, 2))
    twice = 2.0 if half else 1.0
    for t in nb.prange(nthreads):
        _linear_field_and_form_chunk(np.int64(t), half, bounds, u, twice, row, nbr, c, x, y, buf,
                                     out, form)
    if half:
        reduce_threads(buf, out)
    total = 0.0
    mixed = 0.0
    for t in range(nthreads):
        total += form[t, 0]
        mixed += form[t, 1]
    return total, mixed


@nb.njit(cache=True, error_model="numpy")
def _linear_field_and_form_chunk(t, half, bounds, u, twice, row, nbr, c, x, y, buf, out, form):
    """One chunk ``t`` of :func:`linear_field_and_form`'s threaded loop: its work,
    compiled once for the threaded kernel and its serial twin."""
    acc = 0.0
    cross = 0.0
    for i in range(bounds[t], bounds[t + 1]):
        ux = u[i, 0]
        uy = u[i, 1]
        uz = u[i, 2]
        # row sums Σ_j c_k (u_j, d_j, x_j): the forms from them, per row
        fx = fy = fz = 0.0
        ax = ay = az = 0.0
        bx = by = bz = 0.0
        for k in range(row[i], row[i + 1]):
            j = nbr[k]
            ck = c[k]
            fx += ck * u[j, 0]
            fy += ck * u[j, 1]
            fz += ck * u[j, 2]
            xj0 = x[j, 0]
            xj1 = x[j, 1]
            xj2 = x[j, 2]
            ax += ck * (y[j, 0] - xj0)
            ay += ck * (y[j, 1] - xj1)
            az += ck * (y[j, 2] - xj2)
            if half:
                bx += ck * xj0
                by += ck * xj1
                bz += ck * xj2
                buf[t, j, 0] += ck * ux
                buf[t, j, 1] += ck * uy
                buf[t, j, 2] += ck * uz
        dx = y[i, 0] - x[i, 0]
        dy = y[i, 1] - x[i, 1]
        dz = y[i, 2] - x[i, 2]
        acc += twice * (dx * ax + dy * ay + dz * az)
        cross += x[i, 0] * ax + x[i, 1] * ay + x[i, 2] * az
        if half:
            cross += dx * bx + dy * by + dz * bz
            buf[t, i, 0] += fx
            buf[t, i, 1] += fy
            buf[t, i, 2] += fz
        else:
            out[i, 0] += fx
            out[i, 1] += fy
            out[i, 2] += fz
    form[t, 0] = acc
    form[t, 1] = cross


def midpoint_solve_operators(operators, s, W, Wnext, stilde, scale, tol, floor, max_iter,
                             theta0, carry, carry_out, mean, memory=MEMORY, local=True,
                             external=NO_FIELD):
    r""":func:`midpoint_solve` for any spin terms: B̄_i = Σ_terms B̄_i(W) (+ the
    fixed field ``external``, if not empty), each operator adding its own
    midpoint field (``field(W, out, mean)``) every
    sweep. The same updates (a single-site term's field is held at the
    current W_i in the locally exact update: still the same fixed point),
    Anderson acceleration, reflection form, compensated sum,
    stopping rule and return values as :func:`midpoint_solve`; ``operators``
    whose field is of the form Σ_j c_ij W_j are better solved there (one
    compiled loop)."""
    B = np.empty_like(s)
    nthreads = threads.count()
    mix = anderson_mix if nthreads > 1 else anderson_mix_serial
    dF, dG, fprev, gprev, gram, jacobi_rows = _solver_buffers(s.shape[0], memory, local)
    cur, nxt = W, Wnext
    which = 1  # as in midpoint_solve
    previous = np.inf
    theta = theta0
    measured = -1.0
    delta = first = 0.0
    for it in range(1, max_iter + 1):
        if external.shape[0] > 0:
            B[:] = external
        else:
            B[:] = 0.0
        for op in operators:
            op.field(cur, B, mean)
        delta = midpoint_update(nthreads, s, cur, nxt, B, scale, stilde, carry, carry_out,
                                local, jacobi_rows)
        status, theta, measured, first = after_sweep(it, delta, previous, theta, measured,
                                                     first, tol, floor)
        if status >= 0:
            if local:
                end_points(nthreads, s, nxt, stilde, carry, carry_out, jacobi_rows)
            return it, delta, status, which, measured, first
        previous = delta
        if memory > 0:
            mix(it, cur, nxt, fprev, gprev, dF, dG, gram)
        else:
            cur, nxt = nxt, cur
            which = 1 - which
    if local:
        end_points(nthreads, s, nxt, stilde, carry, carry_out, jacobi_rows)
    return max_iter, delta, NOT_CONVERGED, which, measured, first


def midpoint_solve_held(inner, held, W, Wnext, tol, floor, max_outer, theta0, mean, switch,
                        memory=MEMORY):
    r"""The midpoint solve with the fields of the operators ``held`` held fixed
    while the others converge (long-range fields, each evaluation as dear as
    hundreds of sweeps of the rest): the outer iteration

    .. math:: \mathbf E^{(k)} = \bar{\mathbf B}_{\rm held}(\mathbf W^{(k)}), \qquad
              g(\mathbf W^{(k)}) = \text{the midpoint of }
              \bar{\mathbf B} = \bar{\mathbf B}_{\rm rest}(\mathbf W) + \mathbf E^{(k)},

    ``inner(cur, nxt, E)`` solving the inner equation to ``tol`` from ``cur``
    (buffers ``cur``, ``nxt``; the return values of :func:`midpoint_solve`,
    its end points and carry written by its last call), and W⁽ᵏ⁺¹⁾ = g(W⁽ᵏ⁾),
    or with ``memory`` m > 0 the Anderson combination of the last m + 1
    rounds (:func:`anderson_mix`). A fixed point of the outer map solves the
    full equation, so the solve reaches the plain solve's midpoint to the
    tolerance: the method, its order and its symplecticity are unchanged. The
    plain outer map contracts by about c|∂B̄_held/∂W| (weak for dipolar
    fields). It stops by the rule of the sweeps (:func:`after_sweep`, on the
    changes max|g(W⁽ᵏ⁾) − W⁽ᵏ⁾|, the contraction ``theta0`` until two are
    measured), after ``max_outer`` rounds, or when it contracts by more than
    ``switch`` (gave up: the plain solve is then the one to take). The
    result is the last g(W⁽ᵏ⁾), whose end points the last inner solve wrote.

    Returns (inner sweeps in all, the last outer change, status, index of the
    buffer holding the result: 0 = ``W``, 1 = ``Wnext``, the inner sweeps'
    last measured contraction or −1, the first outer change (how far the
    starting guess was from the result), the outer contraction measured or
    −1, whether it gave up)."""
    external = np.empty_like(W)
    x = W.copy()  # the outer iterate W⁽ᵏ⁾
    dF, dG, fprev, gprev, gram, _ = _solver_buffers(W.shape[0], memory, False)
    mix = anderson_mix if threads.count() > 1 else anderson_mix_serial
    cur, nxt = W, Wnext
    which = 0  # the buffer cur is: 0 = W, 1 = Wnext
    sweeps = 0
    inner_theta = -1.0
    previous = np.inf
    theta = theta0
    measured = -1.0
    change = first = 0.0
    for k in range(1, max_outer + 1):
        external[:] = 0.0
        for op in held:
            op.field(x, external, mean)
        if k > 1:
            cur[:] = x
        its, delta, status, result, inner_measured, _ = inner(cur, nxt, external)
        sweeps += its
        if 0.0 <= inner_measured < 1.0:
            inner_theta = inner_measured
        if result == 1:
            cur, nxt = nxt, cur
            which = 1 - which
        if status == NOT_CONVERGED:
            return sweeps, delta, status, which, inner_theta, first, measured, False
        change = max_abs_difference(cur, x)
        status, theta, measured, first = after_sweep(k, change, previous, theta, measured,
                                                     first, tol, floor)
        if status >= 0:
            return sweeps, change, status, which, inner_theta, first, measured, False
        if k > 1 and measured > switch:
            return sweeps, change, NOT_CONVERGED, which, inner_theta, first, measured, True
        previous = change
        if memory > 0:
            mix(k, x, cur, fprev, gprev, dF, dG, gram)
        else:
            x[:] = cur
    return sweeps, change, NOT_CONVERGED, which, inner_theta, first, measured, False
