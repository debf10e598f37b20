"""Compiled inner loops of the spin integrators."""

from __future__ import annotations

import numba as nb
import numpy as np

from ..neighbors import balanced_chunks
from .. import threads
from ..threads import threaded

# Exit status of :func:`midpoint_solve`.
CONVERGED, ROUNDOFF, NOT_CONVERGED = 0, 1, 2


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
    sx = s[i, 0]
    sy = s[i, 1]
    sz = s[i, 2]
    cx = carry[i, 0]
    cy = carry[i, 1]
    cz = carry[i, 2]
    wx = cur[i, 0]
    wy = cur[i, 1]
    wz = cur[i, 2]
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
    ax = cx + (dx - kappa * vx)
    ay = cy + (dy - kappa * vy)
    az = cz + (dz - kappa * vz)
    tx = sx + ax
    ty = sy + ay
    tz = sz + az
    carry_out[i, 0] = ax - (tx - sx)
    carry_out[i, 1] = ay - (ty - sy)
    carry_out[i, 2] = az - (tz - sz)
    stilde[i, 0] = tx
    stilde[i, 1] = ty
    stilde[i, 2] = tz
    inv = 1.0 / np.sqrt(vv)
    vx *= inv
    vy *= inv
    vz *= inv
    nxt[i, 0] = vx
    nxt[i, 1] = vy
    nxt[i, 2] = vz
    return max(abs(vx - wx), abs(vy - wy), abs(vz - wz))


@nb.njit(cache=True, inline="always")
def after_sweep(it, delta, previous, theta, measured, first, tol, floor):
    """Bookkeeping after sweep ``it`` with change ``delta`` (see :func:`midpoint_solve`):
    (status, or -1 to go on; contraction θ in use; θ measured; change of the first sweep)."""
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


@threaded()
def midpoint_solve(nthreads, row, nbr, Jbar, s, W, Wnext, stilde, scale, tol, floor, max_iter,
                   theta0, carry, carry_out):
    r"""Solve the spherical-midpoint equation for fixed pair couplings J̄_ij:

    .. math::

        \tilde{\mathbf s}_i = \mathbf s_i + c\, \mathbf W_i \times \bar{\mathbf B}_i,
        \qquad \bar{\mathbf B}_i = \sum_j \bar J_{ij} \mathbf W_j, \qquad
        \mathbf W_i = \frac{\mathbf s_i + \tilde{\mathbf s}_i}{|\mathbf s_i + \tilde{\mathbf s}_i|},

    with c = hσ/ħ (per spin: ``scale`` holds c_i, which carries each spin's
    precession rate factor), by the Jacobi fixed-point iteration
    W ← (2 s + c W × B̄(W)) / |2 s + c W × B̄(W)|, which contracts while c|B̄| ≲ 1.
    Rows with s_i = 0 (non-magnetic atoms) are skipped.

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
    1 = Wnext, contraction θ observed, or ``theta0`` if none was, max|ΔW| of the
    first sweep: how far the starting guess was from the result).
    """
    n = len(row) - 1
    bounds = balanced_chunks(row, nthreads)
    change = np.zeros(nthreads)
    cur = W
    nxt = Wnext
    which = 0
    previous = np.inf
    theta = theta0
    measured = theta0
    delta = 0.0
    first = 0.0
    for it in range(1, max_iter + 1):
        for t in nb.prange(nthreads):
            m = 0.0
            for i in range(bounds[t], bounds[t + 1]):
                if s[i, 0] == 0.0 and s[i, 1] == 0.0 and s[i, 2] == 0.0:
                    continue
                bx = 0.0
                by = 0.0
                bz = 0.0
                for k in range(row[i], row[i + 1]):
                    j = nbr[k]
                    Jk = Jbar[k]
                    bx += Jk * cur[j, 0]
                    by += Jk * cur[j, 1]
                    bz += Jk * cur[j, 2]
                m = max(m, _midpoint_update(i, s, cur, nxt, bx, by, bz, scale, stilde, carry,
                                            carry_out))
            change[t] = m
        delta = change.max()
        cur, nxt = nxt, cur
        which = 1 - which
        status, theta, measured, first = after_sweep(it, delta, previous, theta, measured,
                                                      first, tol, floor)
        if status >= 0:
            return it, delta, status, which, measured, first
        previous = delta
    return max_iter, delta, NOT_CONVERGED, which, measured, first


@threaded()
def midpoint_solve_half(nthreads, row, nbr, Jbar, s, W, Wnext, stilde, scale, tol, floor,
                        max_iter, theta0, carry, carry_out):
    """:func:`midpoint_solve` over a half pair list (each pair once, half the
    memory traffic): each sweep scatters J̄_ij W_j into row i and J̄_ij W_i into
    row j of per-thread buffers, then updates every spin from their sum."""
    n = len(row) - 1
    bounds = balanced_chunks(row, nthreads)
    atoms = np.empty(nthreads + 1, dtype=np.int64)
    for t in range(nthreads + 1):
        atoms[t] = (n * t) // nthreads
    buf = np.zeros((nthreads, n, 3))
    change = np.zeros(nthreads)
    cur = W
    nxt = Wnext
    which = 0
    previous = np.inf
    theta = theta0
    measured = theta0
    delta = 0.0
    first = 0.0
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
                m = max(m, _midpoint_update(i, s, cur, nxt, bx, by, bz, scale, stilde, carry,
                                            carry_out))
            change[t] = m
        delta = change.max()
        cur, nxt = nxt, cur
        which = 1 - which
        status, theta, measured, first = after_sweep(it, delta, previous, theta, measured,
                                                      first, tol, floor)
        if status >= 0:
            return it, delta, status, which, measured, first
        previous = delta
    return max_iter, delta, NOT_CONVERGED, which, measured, first


@threaded()
def midpoint_update(nthreads, s, W, Wnext, B, scale, stilde, carry, carry_out):
    """One Jacobi sweep of the midpoint iteration for given midpoint fields
    B̄ = ``B`` (the sum of every spin operator's field at W): the update of
    :func:`_midpoint_update` for every magnetic spin (rows with s_i = 0 are
    skipped), W → ``Wnext``. Returns max |ΔW| over all components."""
    n = s.shape[0]
    change = np.zeros(nthreads)
    for t in nb.prange(nthreads):
        m = 0.0
        for i in range((n * t) // nthreads, (n * (t + 1)) // nthreads):
            if s[i, 0] == 0.0 and s[i, 1] == 0.0 and s[i, 2] == 0.0:
                continue
            m = max(m, _midpoint_update(i, s, W, Wnext, B[i, 0], B[i, 1], B[i, 2], scale,
                                        stilde, carry, carry_out))
        change[t] = m
    return change.max()


def midpoint_solve_operators(operators, s, W, Wnext, stilde, scale, tol, floor, max_iter,
                             theta0, carry, carry_out, mean):
    r""":func:`midpoint_solve` for any spin terms: B̄_i = Σ_terms B̄_i(W), each
    operator adding its own midpoint field (``field(W, out, mean)``) every
    sweep. The same update, reflection form, compensated sum, stopping rule and
    return values as :func:`midpoint_solve`; ``operators`` whose field is of the
    form Σ_j c_ij W_j are better solved there (one compiled loop)."""
    B = np.empty_like(s)
    nthreads = threads.count()
    cur = W
    nxt = Wnext
    which = 0
    previous = np.inf
    theta = measured = theta0
    delta = first = 0.0
    for it in range(1, max_iter + 1):
        B[:] = 0.0
        for op in operators:
            op.field(cur, B, mean)
        delta = midpoint_update(nthreads, s, cur, nxt, B, scale, stilde, carry, carry_out)
        cur, nxt = nxt, cur
        which = 1 - which
        status, theta, measured, first = after_sweep(it, delta, previous, theta, measured,
                                                     first, tol, floor)
        if status >= 0:
            return it, delta, status, which, measured, first
        previous = delta
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


# Polynomial extrapolation from the last k+1 values, newest first: row k is order k.
_EXTRAPOLATION = np.array([[1.0, 0.0, 0.0, 0.0],
                           [2.0, -1.0, 0.0, 0.0],
                           [3.0, -3.0, 1.0, 0.0],
                           [4.0, -6.0, 4.0, -1.0]])


def _last_four(history):
    """The last four midpoints, newest first (the newest repeated where history
    is shorter: those entries get coefficient 0)."""
    h0 = history[-1]
    return tuple(history[-1 - k] if len(history) > k else h0 for k in range(4))


def extrapolate(history, order):
    """Predict the next midpoint spins from earlier ones (``history``, oldest
    first) by polynomial extrapolation of the given order, renormalised."""
    out = np.empty_like(history[-1])
    _extrapolate(_EXTRAPOLATION[order], *_last_four(history), out)
    return out


@nb.njit(cache=True, inline="always")
def _extrapolated(c, h0, h1, h2, h3, i, k):
    return c[0] * h0[i, k] + c[1] * h1[i, k] + c[2] * h2[i, k] + c[3] * h3[i, k]


@threaded()
def _extrapolate(c, h0, h1, h2, h3, out):
    for i in nb.prange(h0.shape[0]):
        x = _extrapolated(c, h0, h1, h2, h3, i, 0)
        y = _extrapolated(c, h0, h1, h2, h3, i, 1)
        z = _extrapolated(c, h0, h1, h2, h3, i, 2)
        norm = np.sqrt(x * x + y * y + z * z)
        if norm > 0.0:
            x /= norm
            y /= norm
            z /= norm
        out[i, 0] = x
        out[i, 1] = y
        out[i, 2] = z


@nb.njit(cache=True)
def max_abs_difference(a, b):
    """max |a − b| over all elements."""
    worst = 0.0
    for i in range(a.shape[0]):
        for c in range(a.shape[1]):
            d = abs(a[i, c] - b[i, c])
            if not d <= worst:
                worst = d
    return worst


def best_extrapolation_order(history, W, rows):
    """The extrapolation order that would have predicted ``W`` best from
    ``history`` (judged on a sample of ``rows``)."""
    n = min(len(history), len(_EXTRAPOLATION))
    return _best_order(_EXTRAPOLATION[:n], *_last_four(history), W, rows)


@nb.njit(cache=True)
def _best_order(C, h0, h1, h2, h3, W, rows):
    best = np.inf
    order = 0
    for k in range(C.shape[0]):
        err = 0.0
        for r in rows:
            for c in range(3):
                err = max(err, abs(_extrapolated(C[k], h0, h1, h2, h3, r, c) - W[r, c]))
        if err < best:
            best = err
            order = k
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
def first_nonfinite_row(a):
    """Index of the first row of a 2-D array holding a NaN or inf, else −1."""
    for i in range(a.shape[0]):
        for c in range(a.shape[1]):
            if not np.isfinite(a[i, c]):
                return i
    return -1
