"""Compiled inner loops of the spin integrators."""

from __future__ import annotations

import numba as nb
import numpy as np

from .._jit import threads
from .._jit.cloning import serial_twin
from .._jit.reductions import balanced_chunks, reduce_threads, reduce_threads_serial
from .._jit.threads import threaded

# Exit status of :func:`midpoint_solve`.
CONVERGED, ROUNDOFF, NOT_CONVERGED = 0, 1, 2


#: Earlier midpoint differences the default solver's Anderson acceleration keeps
#: (0: none, the plain fixed-point iteration).
MEMORY = 3
#: Steps with c_i|B̄_i| above this (rad, for a unit spin) are refused by the locally
#: exact update: its Cayley rotation angle 2 atan(c|B̄|/|v|) saturates at π, so such a step
#: is no longer a step of the dynamics (fcc Co: c|B̄| ≈ 4.4 at 8 fs).
MAX_TURN = 8.0
#: Atoms per block of the Anderson inner products: a partition fixed whatever
#: the thread count, its partial sums added in block order, so that every bit of
#: the result is the same for any number of threads.
BLOCK = 256


@nb.njit(cache=True, inline="always")
def _add_compensated(i, sx, sy, sz, ax, ay, az, stilde, carry_out):
    """stilde_i = s_i + a (a: the increment with the carried rounding error
    added), its rounding error into ``carry_out`` (Kahan)."""
    tx = sx + ax
    ty = sy + ay
    tz = sz + az
    carry_out[i, 0] = ax - (tx - sx)
    carry_out[i, 1] = ay - (ty - sy)
    carry_out[i, 2] = az - (tz - sz)
    stilde[i, 0] = tx
    stilde[i, 1] = ty
    stilde[i, 2] = tz


@nb.njit(cache=True, inline="always")
def _reflect(i, s, wx, wy, wz, bx, by, bz, scale, stilde, carry, carry_out):
    """End point of spin i (into ``stilde``, its rounding error into
    ``carry_out``) for midpoint direction W_i = (wx, wy, wz) and midpoint field
    B̄_i = (bx, by, bz), as the reflection of s_i about v = 2 s_i + c_i W_i × B̄_i
    (see :func:`_midpoint_update`). Returns (v, |v|²)."""
    sx = s[i, 0]
    sy = s[i, 1]
    sz = s[i, 2]
    cx = carry[i, 0]
    cy = carry[i, 1]
    cz = carry[i, 2]
    c = scale[i]
    dx = c * (wy * bz - wz * by)
    dy = c * (wz * bx - wx * bz)
    dz = c * (wx * by - wy * bx)
    vx = 2.0 * (sx + cx) + dx
    vy = 2.0 * (sy + cy) + dy
    vz = 2.0 * (sz + cz) + dz
    vv = vx * vx + vy * vy + vz * vz
    # the spin is s + carry (the carried rounding error): keep its length
    kappa = (2.0 * ((sx * dx + sy * dy + sz * dz) + (cx * dx + cy * dy + cz * dz))
             + (dx * dx + dy * dy + dz * dz)) / vv
    _add_compensated(i, sx, sy, sz, cx + (dx - kappa * vx), cy + (dy - kappa * vy),
                     cz + (dz - kappa * vz), stilde, carry_out)
    return vx, vy, vz, vv


@nb.njit(cache=True, inline="always")
def _midpoint_update(i, s, cur, nxt, bx, by, bz, scale, stilde, carry, carry_out):
    """One spin's Jacobi update given its midpoint field B̄_i = (bx, by, bz).

    With d = c_i W_i × B̄_i (c_i = ``scale[i]``, hσ/ħ times the spin's
    precession rate factor) and v = 2 s_i + d (= s_i + s̃_i), the next iterate is
    W_i = v/|v| and the end point is

        s̃_i = s_i + d − κ v,   κ = (2 s_i·d + |d|²)/|v|²,

    the reflection of s_i about v: equal to s_i + d at the solution (κ = 0),
    and |s̃_i| = |s_i| to round-off whatever residual the iteration stops with
    (κ, the length error a residual would cause, is computed from the increment
    d, without cancellation). s_i is the stored spin plus the rounding error
    carried from the last step, and the sum is compensated (Kahan).
    Returns max |ΔW_i| over components.
    """
    wx = cur[i, 0]
    wy = cur[i, 1]
    wz = cur[i, 2]
    vx, vy, vz, vv = _reflect(i, s, wx, wy, wz, bx, by, bz, scale, stilde, carry, carry_out)
    inv = 1.0 / np.sqrt(vv)
    vx *= inv
    vy *= inv
    vz *= inv
    nxt[i, 0] = vx
    nxt[i, 1] = vy
    nxt[i, 2] = vz
    return max(abs(vx - wx), abs(vy - wy), abs(vz - wz))


@nb.njit(cache=True, inline="always")
def local_midpoint(px, py, pz, bx, by, bz, c):
    r"""The midpoint direction of one spin p in a fixed field b: the unit W with

    .. math:: \mathbf W = \frac{\mathbf v}{|\mathbf v|}, \qquad
              \mathbf v = 2\mathbf p + c\, \mathbf W \times \mathbf b

    (the spherical midpoint step of ṗ ∝ p × b: a Cayley rotation about b).
    With λ = |v| and a = c/λ the equation is linear in v, v − a v × b = 2p, so

    .. math:: \mathbf v \propto \mathbf p + a\, \mathbf p \times \mathbf b
              + a^2 (\mathbf p\cdot\mathbf b)\, \mathbf b, \qquad
              |\mathbf v|^2 = 4\frac{|p|^2 + a^2 (p\cdot b)^2}{1 + a^2 |b|^2},

    and y = λ² is the positive root of y² − (4|p|² − c²|b|²) y − 4c²(p·b)² = 0
    (taken in the form without cancellation). Returns (Wx, Wy, Wz, found):
    no root when p ⊥ b and |c b| ≥ 2|p| (a half-turn or more per step)."""
    pp = px * px + py * py + pz * pz
    pb = px * bx + py * by + pz * bz
    cc = c * c
    cb = cc * (bx * bx + by * by + bz * bz)
    q = 4.0 * pp - cb
    r = 4.0 * cc * pb * pb
    root = np.sqrt(q * q + 4.0 * r)
    if q >= 0.0:
        y = 0.5 * (q + root)
    else:
        y = 2.0 * r / (root - q)
    if not y > 0.0:
        return 0.0, 0.0, 0.0, False
    sy = np.sqrt(y)
    a = c / sy
    f = a * a * pb
    # W = v/λ = 2 sqrt(y) v'/(y + c²|b|²) with v' = p + a p × b + a²(p·b) b: unit,
    # as y(y + c²|b|²) = 4(|p|² y + c²(p·b)²) is the equation of y
    g = 2.0 * sy / (y + cb)
    return (g * (px + a * (py * bz - pz * by) + f * bx),
            g * (py + a * (pz * bx - px * bz) + f * by),
            g * (pz + a * (px * by - py * bx) + f * bz), True)


#: The order of a frozen lattice's locally exact sweeps, per stage
#: (:func:`next_sweep_order`): the index order; the colour order; the index
#: order for good (the colour order tried and found not to pay).
INDEX_ORDER, COLOUR_ORDER, INDEX_ORDER_KEPT = 0, 1, 2
#: A stage whose locally exact solve in index order took at least this many
#: sweeps tries the colour order ...
COLOUR_FROM_SWEEPS = 5
#: ... and goes back to index order after a colour-ordered solve of at most
#: this many ...
INDEX_ORDER_UP_TO_SWEEPS = 3
#: ... or for good once a colour-ordered sweep contracts by less than the
#: index order's contraction to this power: what a colour-ordered sweep costs
#: in index-order sweeps, with a margin (a full list, and a pass per colour).
COLOUR_PAYS_POWER = 1.3


@nb.njit(cache=True, inline="always")
def next_sweep_order(order, local, sweeps, measured, theta_index):
    """After a solve at a frozen lattice's stage: (the order of its next
    locally exact sweeps, the contraction of its index-order sweeps), from the
    order the solve took (``order``: :data:`INDEX_ORDER`, :data:`COLOUR_ORDER`
    or :data:`INDEX_ORDER_KEPT`), whether its sweeps were locally exact
    (``local``; Jacobi sweeps say nothing), their number, the contraction
    they showed (``measured``, −1 if none) and the index order's last
    (``theta_index``, −1 if none yet). Colour order takes the earlier
    colours' new W (:func:`midpoint_solve`), about two index-order sweeps'
    contraction on a two-colourable lattice, far less on others; it is tried
    after a long index-order solve and kept while it contracts by more than
    the index order to the power :data:`COLOUR_PAYS_POWER`. One function for
    the Python and the compiled paths."""
    if not local:
        return order, theta_index
    if order == COLOUR_ORDER:
        if sweeps <= INDEX_ORDER_UP_TO_SWEEPS:
            return INDEX_ORDER, theta_index
        if (0.0 < measured < 1.0 and 0.0 < theta_index < 1.0
                and not measured < theta_index ** COLOUR_PAYS_POWER):
            return INDEX_ORDER_KEPT, theta_index
        return COLOUR_ORDER, theta_index
    if 0.0 <= measured < 1.0:
        theta_index = measured
    if order == INDEX_ORDER and sweeps >= COLOUR_FROM_SWEEPS:
        return COLOUR_ORDER, theta_index
    return order, theta_index


#: "auto" takes a Jacobi sweep rather than a locally exact one for a solve that
#: follows a one-sweep solve at its stage, while the stage's sweeps contract by
#: less than this a sweep (see :func:`auto_takes_local`).
JACOBI_AFTER_ONE_SWEEP_BELOW = 0.1


@nb.njit(cache=True, inline="always")
def auto_takes_local(one_sweep, theta):
    """Whether ``solver="auto"`` (in its first mode, before any switch to
    Anderson) makes a step's first solve (from the predictor, to the full
    tolerance) with locally exact sweeps, else with Jacobi's (every other
    solve takes locally exact ones): not when the stage's last such solve took
    a single sweep (``one_sweep``) and its sweeps
    contract by less than :data:`JACOBI_AFTER_ONE_SWEEP_BELOW` (``theta``):
    there the predictor leaves nothing to contract, and a one-sweep Jacobi
    solve costs less than a locally exact one (which needs its end points
    made in a pass of their own). One function for the Python and the
    compiled paths: the same choice to the bit."""
    return not (one_sweep and theta < JACOBI_AFTER_ONE_SWEEP_BELOW)


@nb.njit(cache=True, inline="always")
def _local_midpoint_direction(i, s, cur, nxt, bx, by, bz, scale, stilde, carry, carry_out,
                              jacobi_rows):
    """One spin's locally exact update: W_i solved exactly for the field B̄_i =
    (bx, by, bz) of the current iterate (:func:`local_midpoint`, for the spin
    p = s_i + carry), the next iterate. Its end point is left to
    :func:`_end_points` after the last sweep: it depends on that sweep's W_i
    only, so it is made once a solve, not once a sweep. Where the local equation has no root, the Jacobi update
    of :func:`_midpoint_update`, end point included, the row marked in
    ``jacobi_rows``. Returns max |ΔW_i| over components, or 4 (more than any
    change of unit vectors: "not converged") where c_i|B̄_i| >
    :data:`MAX_TURN` |s_i|."""
    px = s[i, 0] + carry[i, 0]
    py = s[i, 1] + carry[i, 1]
    pz = s[i, 2] + carry[i, 2]
    c = scale[i]
    jacobi_rows[i] = False
    if c * c * (bx * bx + by * by + bz * bz) > MAX_TURN * MAX_TURN * (px * px + py * py
                                                                      + pz * pz):
        return 4.0  # refused: reported as not converged (see MAX_TURN)
    wx, wy, wz, found = local_midpoint(px, py, pz, bx, by, bz, c)
    if not found:
        jacobi_rows[i] = True
        return _midpoint_update(i, s, cur, nxt, bx, by, bz, scale, stilde, carry, carry_out)
    ox = cur[i, 0]
    oy = cur[i, 1]
    oz = cur[i, 2]
    nxt[i, 0] = wx
    nxt[i, 1] = wy
    nxt[i, 2] = wz
    return max(abs(wx - ox), abs(wy - oy), abs(wz - oz))


@nb.njit(cache=True, inline="always")
def _end_points(lo, hi, s, W, stilde, carry, carry_out, jacobi_rows):
    r"""End points of rows lo … hi − 1 after locally exact sweeps
    (:func:`_local_midpoint_direction`): s̃_i the reflection of the spin
    p = s_i + carry_i about the last sweep's result W_i (which is v/|v| for
    v = 2p + c_i W_i × B̄_i: the reflection :func:`_reflect` makes), written as
    the increment

    .. math:: \tilde{\mathbf s}_i - \mathbf p = 2 (\mathbf p \times \mathbf W_i)
              \times \mathbf W_i = 2[(\mathbf p\cdot\mathbf W_i)\mathbf W_i
              - |\mathbf W_i|^2 \mathbf p],

    small and without cancellation for a small step (p × W is), and added to
    s_i compensated as in :func:`_reflect`. With |W_i|² = 1 + ε (round-off),
    |s̃_i|² = |p|² + 4ε|p × W_i|²: the length kept to far below round-off. No
    field, no division: a third of :func:`_reflect`'s cost. Rows without
    spin, and those the Jacobi update took (``jacobi_rows``: it wrote their
    end points), are skipped."""
    for i in range(lo, hi):
        sx = s[i, 0]
        sy = s[i, 1]
        sz = s[i, 2]
        if jacobi_rows[i] or (sx == 0.0 and sy == 0.0 and sz == 0.0):
            continue
        cx = carry[i, 0]
        cy = carry[i, 1]
        cz = carry[i, 2]
        wx = W[i, 0]
        wy = W[i, 1]
        wz = W[i, 2]
        # u = p × W, the carry's part kept apart from the spin's
        ux = (sy * wz - sz * wy) + (cy * wz - cz * wy)
        uy = (sz * wx - sx * wz) + (cz * wx - cx * wz)
        uz = (sx * wy - sy * wx) + (cx * wy - cy * wx)
        _add_compensated(i, sx, sy, sz, cx + 2.0 * (uy * wz - uz * wy),
                         cy + 2.0 * (uz * wx - ux * wz), cz + 2.0 * (ux * wy - uy * wx),
                         stilde, carry_out)


@nb.njit(cache=True, inline="always")
def _pair_field(i, row, nbr, Jbar, source):
    """B̄_i = Σ_k J̄_k source_j over row i's pairs k = (i → j) of a full list."""
    bx = 0.0
    by = 0.0
    bz = 0.0
    for k in range(row[i], row[i + 1]):
        j = nbr[k]
        Jk = Jbar[k]
        bx += Jk * source[j, 0]
        by += Jk * source[j, 1]
        bz += Jk * source[j, 2]
    return bx, by, bz


@nb.njit(cache=True)
def _coloured_spins(lo, hi, row, nbr, Jbar, s, cur, nxt, scale, stilde, carry, carry_out,
                    jacobi_rows, field, order):
    """The locally exact updates of the spins ``order[lo:hi]`` in turn, in
    place in ``nxt`` (:func:`midpoint_solve`): each in its field there, where
    the spins updated before it are already new and the rest still the
    iterate's. The rows are in ``order`` (row a is spin ``order[a]``'s:
    neighbors.rows_in_order). Returns max |ΔW| over their components."""
    m = 0.0
    for a in range(lo, hi):
        i = order[a]
        if s[i, 0] == 0.0 and s[i, 1] == 0.0 and s[i, 2] == 0.0:
            continue
        bx, by, bz = _pair_field(a, row, nbr, Jbar, nxt)
        if field is not None and field.shape[0] > 0:
            field[i, 0] = bx
            field[i, 1] = by
            field[i, 2] = bz
        d = _local_midpoint_direction(i, s, cur, nxt, bx, by, bz, scale, stilde, carry,
                                      carry_out, jacobi_rows)
        if not d <= m and m == m:  # a NaN stays (max(m, d) drops it)
            m = d
    return m


@nb.njit(cache=True)
def _coloured_sweep(row, nbr, Jbar, s, cur, nxt, scale, stilde, carry, carry_out, jacobi_rows,
                    field, order):
    """A locally exact sweep in colour order (:func:`midpoint_solve`), serial:
    g(W) made in place in ``nxt`` (W copied in first), each spin in ``order``
    (the atoms colour by colour) in its field there, where the colours before
    its own are already new and the rest still W's (:func:`_coloured_spins`).
    One colour's spins are not paired, so their order does not matter.
    Returns max |ΔW| over all components."""
    for i in range(s.shape[0]):
        nxt[i, 0] = cur[i, 0]
        nxt[i, 1] = cur[i, 1]
        nxt[i, 2] = cur[i, 2]
    return _coloured_spins(0, len(order), row, nbr, Jbar, s, cur, nxt, scale, stilde, carry,
                           carry_out, jacobi_rows, field, order)


@nb.njit(cache=True, inline="always")
def after_sweep(it, delta, previous, theta, measured, first, tol, floor):
    """Bookkeeping after sweep ``it`` with change ``delta`` (see :func:`midpoint_solve`):
    (status, or -1 to go on; contraction θ in use; θ measured, from the ratio of
    successive changes; change of the first sweep)."""
    if it > 1 and delta > 1e3 * tol and delta < previous:
        theta = delta / previous
        measured = theta
    if it == 1:
        first = delta
    if not delta <= 2.0:  # NaN: a non-finite field
        return NOT_CONVERGED, theta, measured, first
    if delta <= tol or (theta < 0.5 and delta * theta <= tol * (1.0 - theta)):
        return CONVERGED, theta, measured, first
    if delta <= floor and delta >= previous:
        return ROUNDOFF, theta, measured, first
    return -1, theta, measured, first


@nb.njit(cache=True)
def _solve_small(A, b, k):
    """x with A[:k, :k] x = b[:k] (Gaussian elimination, partial pivoting), after
    adding 1e-13 × the largest diagonal element to the diagonal: the
    regularised normal equations of the Anderson least-squares problem. A
    singular or non-finite system gives x = 0 (a plain fixed-point step)."""
    M = np.empty((k, k))
    x = np.empty(k)
    big = 0.0
    for a in range(k):
        big = max(big, A[a, a])
    for a in range(k):
        x[a] = b[a]
        for c in range(k):
            M[a, c] = A[a, c]
        M[a, a] += 1e-13 * big
    for col in range(k):
        piv = col
        for r in range(col + 1, k):
            if abs(M[r, col]) > abs(M[piv, col]):
                piv = r
        if not abs(M[piv, col]) > 0.0:
            return np.zeros(k)
        for c in range(k):
            M[col, c], M[piv, c] = M[piv, c], M[col, c]
        x[col], x[piv] = x[piv], x[col]
        for r in range(col + 1, k):
            f = M[r, col] / M[col, col]
            for c in range(col, k):
                M[r, c] -= f * M[col, c]
            x[r] -= f * x[col]
    for r in range(k - 1, -1, -1):
        acc = x[r]
        for c in range(r + 1, k):
            acc -= M[r, c] * x[c]
        x[r] = acc / M[r, r]
    for a in range(k):
        if not np.isfinite(x[a]):
            return np.zeros(k)
    return x


@nb.njit(cache=True, inline="always")
def _unit_or_zero(x, y, z):
    """(x, y, z)/|(x, y, z)|, or the zero vector as it is (a non-magnetic row)."""
    vv = x * x + y * y + z * z
    if vv > 0.0:
        inv = 1.0 / np.sqrt(vv)
        return x * inv, y * inv, z * inv
    return x, y, z


@nb.njit(cache=True, parallel=threads.prange_only())
def anderson_mix(it, x, g, fprev, gprev, dF, dG, gram):
    r"""Anderson acceleration of the fixed-point iteration x ← g(x) on unit
    vectors, after sweep ``it`` gave g = g(x) (both (n, 3); rows of zeros, the
    non-magnetic atoms, stay zero). With the residual f = g − x and the last k ≤
    m = ``len(dF)`` differences ΔF_a = f_a − f_{a−1}, ΔG_a = g_a − g_{a−1} (ring
    buffers ``dF``, ``dG``, their Gram matrix ``gram``; ``fprev``, ``gprev`` the
    last f and g):

    .. math:: \gamma = \arg\min_\gamma \bigl|f - \textstyle\sum_a \gamma_a
              \Delta F_a\bigr|_2, \qquad x \leftarrow \mathrm{normalise}\bigl(g -
              \textstyle\sum_a \gamma_a \Delta G_a\bigr),

    written into ``x`` row by row. The inner products are summed over blocks of
    :data:`BLOCK` atoms, then the blocks in order: the same bits for any thread count."""
    n = x.shape[0]
    m = dF.shape[0]
    k = min(it - 1, m)
    slot = (it - 2) % m
    nblocks = (n + BLOCK - 1) // BLOCK
    part = np.zeros((nblocks, 2 * m))
    for blk in nb.prange(nblocks):
        for i in range(blk * BLOCK, min(n, (blk + 1) * BLOCK)):
            fx = g[i, 0] - x[i, 0]
            fy = g[i, 1] - x[i, 1]
            fz = g[i, 2] - x[i, 2]
            if k > 0:
                ex = fx - fprev[i, 0]
                ey = fy - fprev[i, 1]
                ez = fz - fprev[i, 2]
                dF[slot, i, 0] = ex
                dF[slot, i, 1] = ey
                dF[slot, i, 2] = ez
                dG[slot, i, 0] = g[i, 0] - gprev[i, 0]
                dG[slot, i, 1] = g[i, 1] - gprev[i, 1]
                dG[slot, i, 2] = g[i, 2] - gprev[i, 2]
                for a in range(k):
                    part[blk, a] += dF[a, i, 0] * ex + dF[a, i, 1] * ey + dF[a, i, 2] * ez
                    part[blk, m + a] += dF[a, i, 0] * fx + dF[a, i, 1] * fy + dF[a, i, 2] * fz
            fprev[i, 0] = fx
            fprev[i, 1] = fy
            fprev[i, 2] = fz
            gprev[i, 0] = g[i, 0]
            gprev[i, 1] = g[i, 1]
            gprev[i, 2] = g[i, 2]
    if k == 0:
        for i in nb.prange(n):
            x[i, 0] = g[i, 0]
            x[i, 1] = g[i, 1]
            x[i, 2] = g[i, 2]
        return
    rhs = np.zeros(m)
    for a in range(k):
        d = 0.0
        r = 0.0
        for blk in range(nblocks):
            d += part[blk, a]
            r += part[blk, m + a]
        gram[slot, a] = d
        gram[a, slot] = d
        rhs[a] = r
    gamma = _solve_small(gram, rhs, k)
    for i in nb.prange(n):
        vx = g[i, 0]
        vy = g[i, 1]
        vz = g[i, 2]
        for a in range(k):
            vx -= gamma[a] * dG[a, i, 0]
            vy -= gamma[a] * dG[a, i, 1]
            vz -= gamma[a] * dG[a, i, 2]
        x[i, 0], x[i, 1], x[i, 2] = _unit_or_zero(vx, vy, vz)


anderson_mix_serial = serial_twin(anderson_mix)


#: ``field`` of the midpoint solvers when no midpoint fields are wanted: an
#: empty array rather than None, so that callers that want them (the fused
#: step, Langevin) and callers that do not share one compiled specialisation.
NO_FIELD = np.zeros((0, 3))


@threaded(anderson_mix=lambda: anderson_mix_serial)
def midpoint_solve(nthreads, row, nbr, Jbar, s, W, Wnext, stilde, scale, tol, floor, max_iter,
                   theta0, carry, carry_out, memory=MEMORY, local=True, field=None,
                   order=None, starts=None):
    r"""Solve the spherical-midpoint equation for fixed pair couplings J̄_ij:

    .. math::

        \tilde{\mathbf s}_i = \mathbf s_i + c\, \mathbf W_i \times \bar{\mathbf B}_i,
        \qquad \bar{\mathbf B}_i = \sum_j \bar J_{ij} \mathbf W_j, \qquad
        \mathbf W_i = \frac{\mathbf s_i + \tilde{\mathbf s}_i}{|\mathbf s_i + \tilde{\mathbf s}_i|},

    with c = hσ/ħ (per spin: ``scale`` holds c_i, which carries each spin's
    precession rate factor). Each sweep maps the iterate W to g(W): with
    ``local`` (the default), every spin's own equation solved exactly in the
    field of the others, B̄_i(W) held fixed (:func:`local_midpoint`, a Cayley
    rotation about B̄_i; contracts for every step size where the plain
    iteration may not; the end points made once, after the last sweep:
    :func:`_end_points`). With a colour order (``order``: the atoms colour by
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
    else in one serial pass (:func:`_coloured_sweep`). Either way each spin
    sees the same values, so the bits do not depend on the chunks. Else the
    Jacobi map g(W) = (2 s + c W × B̄(W)) /
    |2 s + c W × B̄(W)|, which contracts only while c|B̄| ≲ 1. With ``memory``
    m > 0, the next iterate is the Anderson combination of the last m + 1
    sweeps (:func:`anderson_mix`); else g(W). Rows with s_i = 0 (non-magnetic atoms) are skipped.

    ``W`` holds the starting guess; ``Wnext`` is a buffer of the same shape (zero
    on non-magnetic rows). ``stilde`` receives the end point of the last sweep,
    s + c W × B̄ written as the reflection of s about the midpoint direction (see
    :func:`_midpoint_update`): |s̃| = |s| to round-off, never renormalised. The
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
    if given and not empty (:data:`NO_FIELD`), receives the midpoint fields B̄_i
    of the last sweep's input iterate (magnetic rows; the others are not
    written).
    """
    n = len(row) - 1
    bounds = balanced_chunks(row, nthreads)
    change = np.zeros(nthreads)
    dF = np.empty((memory, n, 3))
    dG = np.empty((memory, n, 3))
    fprev = np.empty((n if memory > 0 else 0, 3))
    gprev = np.empty((n if memory > 0 else 0, 3))
    gram = np.zeros((memory, memory))
    jacobi_rows = np.zeros(n if local else 0, dtype=np.bool_)
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
    if order is None:
        by_colour = np.empty(0, dtype=np.int64)
    else:
        by_colour = order
    coloured = local and len(by_colour) > 0
    if starts is None:
        colour_starts = np.zeros(0, dtype=np.int64)
    else:
        colour_starts = starts
    threaded_colours = coloured and nthreads > 1 and len(colour_starts) > 1
    for it in range(1, max_iter + 1):
        if threaded_colours:
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
                    d = _coloured_spins(lo + (size * t) // nthreads,
                                        lo + (size * (t + 1)) // nthreads, row, nbr, Jbar, s,
                                        cur, nxt, scale, stilde, carry, carry_out, jacobi_rows,
                                        field, by_colour)
                    if not d <= change[t] and change[t] == change[t]:  # (NaN stays)
                        change[t] = d
        elif coloured:
            change[:] = 0.0
            change[0] = _coloured_sweep(row, nbr, Jbar, s, cur, nxt, scale, stilde, carry,
                                        carry_out, jacobi_rows, field, by_colour)
        else:
            for t in nb.prange(nthreads):
                m = 0.0
                for i in range(bounds[t], bounds[t + 1]):
                    if s[i, 0] == 0.0 and s[i, 1] == 0.0 and s[i, 2] == 0.0:
                        continue
                    bx, by, bz = _pair_field(i, row, nbr, Jbar, cur)
                    if field is not None and field.shape[0] > 0:
                        field[i, 0] = bx
                        field[i, 1] = by
                        field[i, 2] = bz
                    if local:
                        d = _local_midpoint_direction(i, s, cur, nxt, bx, by, bz, scale,
                                                      stilde, carry, carry_out, jacobi_rows)
                    else:
                        d = _midpoint_update(i, s, cur, nxt, bx, by, bz, scale, stilde, carry,
                                             carry_out)
                    if not d <= m and m == m:  # a NaN stays (max(m, d) drops it)
                        m = d
                change[t] = m
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
            _end_points(bounds[t], bounds[t + 1], s, nxt, stilde, carry, carry_out,
                        jacobi_rows)
    if status < 0:
        return max_iter, delta, NOT_CONVERGED, which, measured, first
    return it, delta, status, which, measured, first


@threaded(anderson_mix=lambda: anderson_mix_serial)
def midpoint_solve_half(nthreads, row, nbr, Jbar, s, W, Wnext, stilde, scale, tol, floor,
                        max_iter, theta0, carry, carry_out, memory=MEMORY, local=True,
                        field=None):
    """:func:`midpoint_solve` over a half pair list (each pair once, half the
    memory traffic): each sweep scatters J̄_ij W_j into row i and J̄_ij W_i into
    row j of per-thread buffers, then updates every spin from their sum (so
    in index order only: no row has its whole field before the pass ends)."""
    n = len(row) - 1
    bounds = balanced_chunks(row, nthreads)
    atoms = np.empty(nthreads + 1, dtype=np.int64)
    for t in range(nthreads + 1):
        atoms[t] = (n * t) // nthreads
    buf = np.zeros((nthreads, n, 3))
    change = np.zeros(nthreads)
    dF = np.empty((memory, n, 3))
    dG = np.empty((memory, n, 3))
    fprev = np.empty((n if memory > 0 else 0, 3))
    gprev = np.empty((n if memory > 0 else 0, 3))
    gram = np.zeros((memory, memory))
    jacobi_rows = np.zeros(n if local else 0, dtype=np.bool_)
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
    for it in range(1, max_iter + 1):
        for t in nb.prange(nthreads):
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
        for t in nb.prange(nthreads):
            m = 0.0
            for i in range(atoms[t], atoms[t + 1]):
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
                if field is not None and field.shape[0] > 0:
                    field[i, 0] = bx
                    field[i, 1] = by
                    field[i, 2] = bz
                if local:
                    d = _local_midpoint_direction(i, s, cur, nxt, bx, by, bz, scale, stilde,
                                                  carry, carry_out, jacobi_rows)
                else:
                    d = _midpoint_update(i, s, cur, nxt, bx, by, bz, scale, stilde, carry,
                                         carry_out)
                if not d <= m and m == m:  # a NaN stays (max(m, d) drops it)
                    m = d
            change[t] = m
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
            _end_points(atoms[t], atoms[t + 1], s, nxt, stilde, carry, carry_out,
                        jacobi_rows)
    if status < 0:
        return max_iter, delta, NOT_CONVERGED, which, measured, first
    return it, delta, status, which, measured, first


@threaded()
def midpoint_update(nthreads, s, W, Wnext, B, scale, stilde, carry, carry_out, local,
                    jacobi_rows):
    """One sweep of the midpoint iteration for given midpoint fields B̄ = ``B``
    (the sum of every spin operator's field at W): the locally exact update of
    :func:`_local_midpoint_direction` (``local``; the end points are left to
    :func:`end_points` after the last sweep, the rows it leaves to the Jacobi
    update marked in ``jacobi_rows``) or the Jacobi update of
    :func:`_midpoint_update` for every magnetic spin (rows with s_i = 0 are
    skipped), W → ``Wnext``. Returns max |ΔW| over all components."""
    n = s.shape[0]
    change = np.zeros(nthreads)
    for t in nb.prange(nthreads):
        m = 0.0
        for i in range((n * t) // nthreads, (n * (t + 1)) // nthreads):
            if s[i, 0] == 0.0 and s[i, 1] == 0.0 and s[i, 2] == 0.0:
                continue
            if local:
                d = _local_midpoint_direction(i, s, W, Wnext, B[i, 0], B[i, 1], B[i, 2], scale,
                                              stilde, carry, carry_out, jacobi_rows)
            else:
                d = _midpoint_update(i, s, W, Wnext, B[i, 0], B[i, 1], B[i, 2], scale, stilde,
                                     carry, carry_out)
            if not d <= m and m == m:  # a NaN stays (max(m, d) drops it)
                m = d
        change[t] = m
    return change.max()


@threaded()
def end_points(nthreads, s, W, stilde, carry, carry_out, jacobi_rows):
    """The end points after the last of :func:`midpoint_update`'s locally exact
    sweeps (:func:`_end_points`: W their result)."""
    n = s.shape[0]
    for t in nb.prange(nthreads):
        _end_points((n * t) // nthreads, (n * (t + 1)) // nthreads, s, W, stilde, carry,
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
    if half:
        reduce_threads(buf, out)
    total = 0.0
    mixed = 0.0
    for t in range(nthreads):
        total += form[t, 0]
        mixed += form[t, 1]
    return total, mixed


def midpoint_solve_operators(operators, s, W, Wnext, stilde, scale, tol, floor, max_iter,
                             theta0, carry, carry_out, mean, memory=MEMORY, local=True):
    r""":func:`midpoint_solve` for any spin terms: B̄_i = Σ_terms B̄_i(W), each
    operator adding its own midpoint field (``field(W, out, mean)``) every
    sweep. The same updates (a single-site term's field is held at the
    current W_i in the locally exact update: still the same fixed point),
    Anderson acceleration, reflection form, compensated sum,
    stopping rule and return values as :func:`midpoint_solve`; ``operators``
    whose field is of the form Σ_j c_ij W_j are better solved there (one
    compiled loop)."""
    B = np.empty_like(s)
    nthreads = threads.count()
    mix = anderson_mix if nthreads > 1 else anderson_mix_serial
    n = s.shape[0]
    dF = np.empty((memory, n, 3))
    dG = np.empty((memory, n, 3))
    fprev = np.empty((n if memory > 0 else 0, 3))
    gprev = np.empty_like(fprev)
    gram = np.zeros((memory, memory))
    jacobi_rows = np.zeros(n if local else 0, dtype=np.bool_)
    cur, nxt = W, Wnext
    which = 1  # as in midpoint_solve
    previous = np.inf
    theta = theta0
    measured = -1.0
    delta = first = 0.0
    for it in range(1, max_iter + 1):
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


@threaded()
def drift(q, p, m, h, carry, out, carry_out):
    """out = q + h p / m (Störmer–Verlet's position update), compensated: the
    rounding error of each sum is carried into the next (Kahan; Hairer, Lubich
    & Wanner VIII.5), so round-off does not pile up over millions of tiny steps."""
    for i in nb.prange(q.shape[0]):
        f = h / m[i]
        for c in range(3):
            a = f * p[i, c] + carry[i, c]
            t = q[i, c] + a
            carry_out[i, c] = a - (t - q[i, c])
            out[i, c] = t


@threaded()
def kick(p, a, f, carry, out, carry_out):
    """out = p + a f (a half kick: a = h/2), compensated as :func:`drift`."""
    for i in nb.prange(p.shape[0]):
        for c in range(3):
            y = a * f[i, c] + carry[i, c]
            t = p[i, c] + y
            carry_out[i, c] = y - (t - p[i, c])
            out[i, c] = t



@threaded()
def kick_drift(nthreads, p, a, f, carry_p, P, carry_mid, q, m, h, carry_q, qt, carry_qt,
               reference):
    """:func:`kick` then :func:`drift` in one pass, the same arithmetic in the
    same order (so bitwise the same results):

        P = p + a f,   q̃ = q + h P / m      (both compensated, as there),

    and what the integrators check of q̃ in the same pass. Returns (max_i |q̃_i −
    q_i|, that atom, max |q̃ − ``reference``| over all elements, max |q| over
    all elements); the first two as :func:`~ase_spin.neighbors.max_displacement`
    gives them, the third as :func:`max_abs_difference`. Fixed chunks over
    atoms (``nthreads``), whose maxima combine in chunk order."""
    n = q.shape[0]
    worst = np.zeros(nthreads)
    where = np.zeros(nthreads, dtype=np.int64)
    apart = np.zeros(nthreads)
    largest = np.zeros(nthreads)
    for t in nb.prange(nthreads):
        w2 = 0.0
        at = (n * t) // nthreads
        d = 0.0
        big = 0.0
        for i in range((n * t) // nthreads, (n * (t + 1)) // nthreads):
            f_m = h / m[i]
            for c in range(3):
                y = a * f[i, c] + carry_p[i, c]
                u = p[i, c] + y
                carry_mid[i, c] = y - (u - p[i, c])
                P[i, c] = u
                b = f_m * u + carry_q[i, c]
                x = q[i, c] + b
                carry_qt[i, c] = b - (x - q[i, c])
                qt[i, c] = x
                e = abs(x - reference[i, c])
                if not e <= d and d == d:  # a NaN stays
                    d = e
                e = abs(q[i, c])
                if not e <= big and big == big:
                    big = e
            dx = qt[i, 0] - q[i, 0]
            dy = qt[i, 1] - q[i, 1]
            dz = qt[i, 2] - q[i, 2]
            d2 = dx * dx + dy * dy + dz * dz
            if not d2 <= w2 and w2 == w2:
                w2 = d2
                at = i
        worst[t] = w2
        where[t] = at
        apart[t] = d
        largest[t] = big
    w2 = 0.0
    at = 0
    d = 0.0
    big = 0.0
    for t in range(nthreads):
        if not worst[t] <= w2 and w2 == w2:
            w2 = worst[t]
            at = where[t]
        if not apart[t] <= d and d == d:
            d = apart[t]
        if not largest[t] <= big and big == big:
            big = largest[t]
    return np.sqrt(w2), at, d, big

#: Midpoints the predictor keeps per stage at most: extrapolation orders 0 to
#: 11 from the newest 1 … 12, and in the last row a least-squares polynomial of
#: degree :data:`LEAST_SQUARES_DEGREE` through all 16. At small steps each order
#: is about an order of magnitude more accurate than the one below until the
#: last digits of the increments (the midpoints are solved to ``tol``) take
#: over, amplified by Σ|c_m| = 2^(k+1) − 1; the least-squares row, of degree 12
#: but Σ|c_m| = 1125 instead of 8191, predicts better there, and the midpoint
#: solve takes one sweep less per factor 1/θ (θ the contraction per sweep); see
#: docs/benchmarks.md, "The predictor's least-squares row". Rows 12–14 are
#: order 11 again: what the last row falls back to while fewer than 16
#: increments are kept (exact orders 12–14 would only amplify the noise more).
PREDICTOR_DEPTH = 16
#: Degree of the polynomial fitted to all :data:`PREDICTOR_DEPTH` increments in
#: the predictor's last row (:func:`_coefficients`).
LEAST_SQUARES_DEGREE = 12
#: The exact extrapolation orders the predictor chooses from (0 … 11).
EXACT_ORDERS = 12


def _least_squares_row(degree, depth):
    """Coefficients c_m (m = 0 newest … depth − 1) of the value at the next step
    of the least-squares polynomial of ``degree`` through the last ``depth``
    values, at times 0, −1, …: c = V (VᵀV)⁻¹ e with V_mk = (−m)^k, e = (1, …, 1)
    (the value at t = 1), solved in exact rational arithmetic. A polynomial of
    degree ≤ ``degree`` is extrapolated exactly; the noise gain Σ|c_m| is far
    smaller than exact extrapolation's of that degree."""
    from fractions import Fraction

    n = degree + 1
    V = [[Fraction((-m) ** k) for k in range(n)] for m in range(depth)]
    A = [[sum(V[m][a] * V[m][b] for m in range(depth)) for b in range(n)] + [Fraction(1)]
         for a in range(n)]
    for col in range(n):  # Gauss–Jordan on (VᵀV | e), exact: no pivoting needed
        piv = A[col][col]
        A[col] = [x / piv for x in A[col]]
        for r in range(n):
            if r != col and A[r][col] != 0:
                f = A[r][col]
                A[r] = [x - f * y for x, y in zip(A[r], A[col])]
    y = [A[k][n] for k in range(n)]
    return [float(sum(V[m][k] * y[k] for k in range(n))) for m in range(depth)]


def _coefficients(depth):
    """Row k ≤ 11: polynomial extrapolation of order k from the last k+1
    values, newest first, c_m = (−1)^m C(k+1, m+1) (zero beyond m = k); rows
    12 … depth − 2: order 11 again; the last row (the one that reads all
    ``depth`` values, as an order would): the least-squares polynomial of
    degree :data:`LEAST_SQUARES_DEGREE` through them (:func:`_least_squares_row`)."""
    from math import comb

    rows = [[(-1.0) ** m * comb(min(k, EXACT_ORDERS - 1) + 1, m + 1)
             if m <= min(k, EXACT_ORDERS - 1) else 0.0 for m in range(depth)]
            for k in range(depth - 1)]
    rows.append(_least_squares_row(LEAST_SQUARES_DEGREE, depth))
    return np.array(rows)


COEFFICIENTS = _coefficients(PREDICTOR_DEPTH)
#: The least-squares row: its prediction, judged beside the exact orders by
#: best_order_rows (a compile-time constant there).
_LEAST_SQUARES = np.ascontiguousarray(COEFFICIENTS[PREDICTOR_DEPTH - 1])
# The first four orders (Langevin's predictor of remainders): row k is order k.
LOW_ORDER_COEFFICIENTS = np.ascontiguousarray(COEFFICIENTS[:4, :4])


def newest_first(history, order=PREDICTOR_DEPTH):
    """The last :data:`PREDICTOR_DEPTH` entries, newest first, padded with
    the newest (coefficient 0 there): one tuple type, one compiled kernel.
    Beyond ``order`` + 1 the newest again (a zero coefficient times it adds
    the same +0.0, and a large system then reads only the arrays it uses)."""
    newest = list(reversed(history))[:order + 1]  # C loops: this runs every step
    return tuple(newest + newest[:1] * (PREDICTOR_DEPTH - len(newest)))


def extrapolate(history, order, base):
    """Predict the next midpoint spins from the increments D = W − s of earlier
    steps (``history``, oldest first, at most :data:`PREDICTOR_DEPTH`) by
    polynomial extrapolation of the given order, renormalised:

        W = normalise(base + Σ_m c_m D_m),   c_m = (−1)^m C(order+1, m+1),

    D_0 the newest, ``base`` the spins at the start of the step."""
    out = np.empty_like(history[-1])
    extrapolate_rows(COEFFICIENTS[order], *newest_first(history, order), base, out)
    return out


def increment(W, s, out=None):
    """W − s (a midpoint's increment over the spins at the start of its step),
    into ``out`` if given (the predictor reuses its oldest increment: at 10⁶
    atoms each (N, 3) array is 24 MB)."""
    if out is None:
        out = np.empty_like(W)
    _increment(W, s, out)
    return out


@threaded()
def _increment(W, s, out):
    for i in nb.prange(W.shape[0]):
        for k in range(3):
            out[i, k] = W[i, k] - s[i, k]


@nb.njit(cache=True, inline="always")
def _extrapolated_deep(c, h0, h1, h2, h3, h4, h5, h6, h7, h8, h9, h10, h11, h12, h13, h14,
                       h15, i, k):
    """Σ_m c_m h_m[i, k], m = 0 … 15 in order (the zero coefficients of a lower
    order add +0.0: the same value; one straight sum, which numba compiles far
    better than a loop over a tuple or a chain of tests)."""
    return (c[0] * h0[i, k] + c[1] * h1[i, k] + c[2] * h2[i, k] + c[3] * h3[i, k]
            + c[4] * h4[i, k] + c[5] * h5[i, k] + c[6] * h6[i, k] + c[7] * h7[i, k]
            + c[8] * h8[i, k] + c[9] * h9[i, k] + c[10] * h10[i, k] + c[11] * h11[i, k]
            + c[12] * h12[i, k] + c[13] * h13[i, k] + c[14] * h14[i, k]
            + c[15] * h15[i, k])


#: From :data:`~ase_spin._jit.threads.SERIAL_ALL_BELOW` to :data:`~ase_spin._jit.threads.SERIAL_BELOW`
#: atoms :func:`extrapolate_rows` takes its blocks of flat loops (the arrays in
#: cache: the arithmetic is the cost, and it vectorises); outside, one loop over
#: rows (fewer atoms: the blocks' scratch arrays cost more than they save; more:
#: the arrays are streamed from memory, and the row loop measured faster there;
#: docs/benchmarks.md, "The predictor's least-squares row").
_EXTRAPOLATE_FLAT = (threads.SERIAL_ALL_BELOW, threads.SERIAL_BELOW)
#: Atoms per block of the flat loops.
_EXTRAPOLATE_BLOCK = 256


@threaded()
def extrapolate_rows(c, h0, h1, h2, h3, h4, h5, h6, h7, h8, h9, h10, h11, h12, h13, h14, h15,
                 base, out):
    """out = normalise(base + Σ_m c_m h_m) row by row (C-contiguous (n, 3)
    arrays). A small system (:data:`_EXTRAPOLATE_FLAT`) a block of atoms at a
    time: base + Σ over the block's flat values in one straight loop over the
    16 streams, then the norms, then the rows divided by them — loops that
    vectorise, where one loop per row does not; others in one loop over rows.
    Each value is computed as :func:`_extrapolated_deep` computes it either
    way: the same bits."""
    n = h0.shape[0]
    if not _EXTRAPOLATE_FLAT[0] <= n < _EXTRAPOLATE_FLAT[1]:
        for i in nb.prange(n):
            x = base[i, 0] + _extrapolated_deep(c, h0, h1, h2, h3, h4, h5, h6, h7, h8, h9, h10,
                                                h11, h12, h13, h14, h15, i, 0)
            y = base[i, 1] + _extrapolated_deep(c, h0, h1, h2, h3, h4, h5, h6, h7, h8, h9, h10,
                                                h11, h12, h13, h14, h15, i, 1)
            z = base[i, 2] + _extrapolated_deep(c, h0, h1, h2, h3, h4, h5, h6, h7, h8, h9, h10,
                                                h11, h12, h13, h14, h15, i, 2)
            norm = np.sqrt(x * x + y * y + z * z)
            if norm > 0.0:
                x /= norm
                y /= norm
                z /= norm
            out[i, 0] = x
            out[i, 1] = y
            out[i, 2] = z
        return
    f0, f1, f2, f3 = h0.reshape(-1), h1.reshape(-1), h2.reshape(-1), h3.reshape(-1)
    f4, f5, f6, f7 = h4.reshape(-1), h5.reshape(-1), h6.reshape(-1), h7.reshape(-1)
    f8, f9, f10, f11 = h8.reshape(-1), h9.reshape(-1), h10.reshape(-1), h11.reshape(-1)
    f12, f13, f14, f15 = h12.reshape(-1), h13.reshape(-1), h14.reshape(-1), h15.reshape(-1)
    fb = base.reshape(-1)
    c0, c1, c2, c3, c4, c5, c6, c7 = c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]
    c8, c9, c10, c11, c12, c13, c14, c15 = (c[8], c[9], c[10], c[11], c[12], c[13], c[14],
                                            c[15])
    for b in nb.prange((n + _EXTRAPOLATE_BLOCK - 1) // _EXTRAPOLATE_BLOCK):
        lo = b * _EXTRAPOLATE_BLOCK
        hi = min(n, lo + _EXTRAPOLATE_BLOCK)
        acc = np.empty(3 * (hi - lo))
        norms = np.empty(hi - lo)
        for a in range(3 * (hi - lo)):
            x = 3 * lo + a
            acc[a] = fb[x] + (c0 * f0[x] + c1 * f1[x] + c2 * f2[x] + c3 * f3[x]
                              + c4 * f4[x] + c5 * f5[x] + c6 * f6[x] + c7 * f7[x]
                              + c8 * f8[x] + c9 * f9[x] + c10 * f10[x] + c11 * f11[x]
                              + c12 * f12[x] + c13 * f13[x] + c14 * f14[x] + c15 * f15[x])
        for a in range(hi - lo):
            x = acc[3 * a]
            y = acc[3 * a + 1]
            z = acc[3 * a + 2]
            norms[a] = np.sqrt(x * x + y * y + z * z)
        for a in range(hi - lo):
            norm = norms[a]
            i = lo + a
            if norm > 0.0:
                out[i, 0] = acc[3 * a] / norm
                out[i, 1] = acc[3 * a + 1] / norm
                out[i, 2] = acc[3 * a + 2] / norm
            else:
                out[i, 0] = acc[3 * a]
                out[i, 1] = acc[3 * a + 1]
                out[i, 2] = acc[3 * a + 2]


@nb.njit(cache=True, inline="always")
def _extrapolated(c, h0, h1, h2, h3, i, k):
    return c[0] * h0[i, k] + c[1] * h1[i, k] + c[2] * h2[i, k] + c[3] * h3[i, k]


@nb.njit(cache=True)
def max_abs_difference(a, b):
    """max |a − b| over all elements (NaN if any difference is NaN)."""
    worst = 0.0
    for i in range(a.shape[0]):
        for c in range(a.shape[1]):
            d = abs(a[i, c] - b[i, c])
            if not d <= worst and worst == worst:  # a NaN stays
                worst = d
    return worst


def best_extrapolation_order(history, W, rows, base=None, kept=None):
    """The extrapolation order that would have predicted ``W`` (``W − base``
    with a base) best from ``history``, judged on a sample of ``rows`` (only
    those rows are read: no array of the system's size is made). ``kept``:
    (table, count) of :func:`difference_table`, kept per history between
    calls (see :func:`best_order_rows`), or None."""
    D = W[rows] if base is None else W[rows] - base[rows]
    n = min(len(history), PREDICTOR_DEPTH)
    if kept is None:
        kept = difference_table(len(rows))
    # the increments read at the sampled rows inside the kernel (no copies);
    # newest_first's padding repeats the newest
    return best_order_rows(n, *newest_first(history), D, rows, np.arange(len(rows)), *kept)


def difference_table(nrows):
    """A kept backward-difference table for :func:`best_order_rows` over ``nrows``
    sampled rows, empty: (table, count)."""
    return np.zeros((PREDICTOR_DEPTH, 3 * nrows)), np.zeros(1, dtype=np.int64)


@nb.njit(cache=True)
def best_order_rows(n, h0, h1, h2, h3, h4, h5, h6, h7, h8, h9, h10, h11, h12, h13, h14, h15, W,
                rows, w_rows, kept, kept_n):
    """The row of :data:`COEFFICIENTS` (order) with the smallest max error
    over ``rows`` of the increments h (W at its rows ``w_rows``: the same
    sample): the exact orders 0 … min(n, 12) − 1 from one backward-difference
    table (Newton's form: order k predicts Σ_{j≤k} ∇^j h_0, the polynomial of
    :func:`extrapolate`'s coefficients), and with a full history (n = 16) the
    least-squares row (15), Σ_m c_m h_m evaluated at the sample; the sampled
    values side by side (loops that vectorise). On a tie the lower row.

    ``kept`` holds ∇^k h_0, k < ``kept_n[0]``, of the last call for this
    history. When the history has gained one increment since (h_1 now is
    that call's h_0, bit for bit, and n is one more or, full, the same), the
    new column follows from it, ∇^k h_0 = ∇^{k−1} h_0 − ∇^{k−1} h_1, with
    ∇^{k−1} h_1 the kept ∇^{k−1} h_0: the same subtractions the whole table
    makes, so the same bits, in O(n) instead of O(n²) (at 500 atoms the whole
    table took ~5 µs a step, most of the predictor's bookkeeping). Else the
    whole table. Either way ``kept`` then holds this call's column."""
    m = 3 * len(rows)
    w = np.empty(m)
    col = np.empty(m)  # ∇^0 h_0 at the sampled rows
    for a in range(len(rows)):
        r = rows[a]
        rw = w_rows[a]
        for c in range(3):
            col[3 * a + c] = h0[r, c]
            w[3 * a + c] = W[rw, c]
    last = kept_n[0]
    follows = n >= 2 and last > 0 and (n == last + 1 or n == last)
    if follows:
        for a in range(len(rows)):
            r = rows[a]
            for c in range(3):
                if h1[r, c] != kept[0, 3 * a + c]:
                    follows = False
    if follows:
        # kept[k] ← kept[k − 1] (already the new ∇^{k−1} h_0) − the old kept[k − 1]
        prev = kept[0].copy()
        older = np.empty(m)
        kept[0] = col
        for k in range(1, n):
            if k < last:
                older[:] = kept[k]
            for x in range(m):
                kept[k, x] = kept[k - 1, x] - prev[x]
            prev, older = older, prev
    else:
        D = np.empty((PREDICTOR_DEPTH, m))
        for a in range(len(rows)):
            r = rows[a]
            for c in range(3):
                D[0, 3 * a + c] = h0[r, c]
                D[1, 3 * a + c] = h1[r, c]
                D[2, 3 * a + c] = h2[r, c]
                D[3, 3 * a + c] = h3[r, c]
                D[4, 3 * a + c] = h4[r, c]
                D[5, 3 * a + c] = h5[r, c]
                D[6, 3 * a + c] = h6[r, c]
                D[7, 3 * a + c] = h7[r, c]
                D[8, 3 * a + c] = h8[r, c]
                D[9, 3 * a + c] = h9[r, c]
                D[10, 3 * a + c] = h10[r, c]
                D[11, 3 * a + c] = h11[r, c]
                D[12, 3 * a + c] = h12[r, c]
                D[13, 3 * a + c] = h13[r, c]
                D[14, 3 * a + c] = h14[r, c]
                D[15, 3 * a + c] = h15[r, c]
        kept[0] = D[0]
        for k in range(1, n):
            for j in range(n - k):  # now D[0] = ∇^k h_0
                for x in range(m):
                    D[j, x] = D[j, x] - D[j + 1, x]
            kept[k] = D[0]
    kept_n[0] = n
    prediction = kept[0].copy()
    best = np.inf
    order = 0
    for k in range(min(n, EXACT_ORDERS)):
        if k > 0:
            for x in range(m):
                prediction[x] += kept[k, x]
        err = 0.0
        for x in range(m):
            err = max(err, abs(prediction[x] - w[x]))
        if err < best:
            best = err
            order = k
    if n == PREDICTOR_DEPTH:
        c = _LEAST_SQUARES
        err = 0.0
        for a in range(len(rows)):
            r = rows[a]
            for j in range(3):
                p = _extrapolated_deep(c, h0, h1, h2, h3, h4, h5, h6, h7, h8, h9, h10, h11,
                                       h12, h13, h14, h15, r, j)
                err = max(err, abs(p - w[3 * a + j]))
        if err < best:
            order = PREDICTOR_DEPTH - 1
    return order


@nb.njit(cache=True)
def same(a, b):
    """a and b hold the same values (arrays of equal shape, any dimension)."""
    x = a.ravel()
    y = b.ravel()
    if x.shape[0] != y.shape[0]:
        return False
    for i in range(x.shape[0]):
        if x[i] != y[i]:
            return False
    return True


@nb.njit(cache=True)
def same_rows(a0, b0, a1, b1, a2, b2):
    """(a0, a1, a2) hold the same values as (b0, b1, b2) (pairs of C-contiguous
    (n, 3) arrays of equal shapes): the integrators' check that the Atoms'
    positions, momenta and moments are as the last step wrote them, in one
    call. Flat views and no branch per element: SIMD lanes."""
    x0, y0, x1, y1 = a0.reshape(-1), b0.reshape(-1), a1.reshape(-1), b1.reshape(-1)
    x2, y2 = a2.reshape(-1), b2.reshape(-1)
    differ = False
    for k in range(x0.shape[0]):
        differ |= (x0[k] != y0[k]) | (x1[k] != y1[k]) | (x2[k] != y2[k])
    return not differ


@nb.njit(cache=True)
def commit_state(q, p, s, mu, magnetic, positions, momenta, moments, copy_q, copy_p, copy_m):
    """Write a finished step into the Atoms' arrays and into the snapshot
    buffers ``copy_*`` in one pass: positions = q, momenta = p and, if
    ``magnetic``, moments = μ_i s_i — but only if q, p and s are all finite.
    Returns (which, row): (−1, −1) when written, else nothing was written and
    ``which`` (0 positions, 1 momenta, 2 spins) and ``row`` locate the first
    NaN or inf. All arrays C-contiguous (n, 3), ``mu`` (n,): flat views
    indexed from 0 and no branch per element, so that the loops run on SIMD
    lanes."""
    qf, pf, sf = q.reshape(-1), p.reshape(-1), s.reshape(-1)
    nonfinite = False
    for k in range(qf.shape[0]):
        # x − x is 0 for finite x, NaN for ±inf and NaN
        nonfinite |= (((qf[k] - qf[k]) != 0.0) | ((pf[k] - pf[k]) != 0.0)
                      | ((sf[k] - sf[k]) != 0.0))
    if nonfinite:
        row = first_nonfinite_row(q)
        if row >= 0:
            return 0, row
        row = first_nonfinite_row(p)
        if row >= 0:
            return 1, row
        return 2, first_nonfinite_row(s)
    xf, vf, mf = positions.reshape(-1), momenta.reshape(-1), moments.reshape(-1)
    cq, cp, cm = copy_q.reshape(-1), copy_p.reshape(-1), copy_m.reshape(-1)
    for k in range(qf.shape[0]):
        xf[k] = cq[k] = qf[k]
        vf[k] = cp[k] = pf[k]
    if magnetic:
        for i in range(s.shape[0]):
            for c in range(3):
                mf[3 * i + c] = cm[3 * i + c] = mu[i] * sf[3 * i + c]
    return -1, -1


@nb.njit(cache=True)
def first_nonfinite_row(a):
    """Index of the first row of a 2-D array holding a NaN or inf, else −1."""
    for i in range(a.shape[0]):
        for c in range(a.shape[1]):
            if not np.isfinite(a[i, c]):
                return i
    return -1
