"""The midpoint predictor: polynomial extrapolation of the midpoint
increments D = W − s of earlier steps (exact orders and a least-squares row),
and the choice of the order that would have predicted best."""

from __future__ import annotations

import numba as nb
import numpy as np

from ..._jit.threads import threaded

#: Midpoints the predictor keeps per stage at most: extrapolation orders 0 to
#: 11 from the newest 1 … 12, and in the last row a least-squares polynomial of
#: degree :data:`LEAST_SQUARES_DEGREE` through all 16. At small steps each order
#: is about an order of magnitude more accurate than the one below until the
#: last digits of the increments (the midpoints are solved to ``tol``) take
#: over, amplified by Σ|c_m| = 2^(k+1) − 1; the least-squares row, of degree 12
#: but Σ|c_m| = 1125 instead of 8191, predicts better there, and the midpoint
#: solve takes one sweep less per factor 1/θ (θ the contraction per sweep). The
#: deep history and the least-squares row exist only to save sweeps:
#: ``benchmarks/predictor.py`` shows each row's miss and the step's cost
#: (docs/benchmarks.md, "Why each fast path exists"). Rows 12–14 are
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
    into ``out`` if given (the predictor reuses its oldest increment: each
    (N, 3) array of float64 is 24 bytes an atom, a new one per step would be
    one more such allocation)."""
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


@threaded()
def extrapolate_rows(c, h0, h1, h2, h3, h4, h5, h6, h7, h8, h9, h10, h11, h12, h13, h14, h15,
                 base, out):
    """out = normalise(base + Σ_m c_m h_m) row by row (C-contiguous (n, 3)
    arrays), each value as :func:`_extrapolated_deep` computes it."""
    n = h0.shape[0]
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
    makes, so the same bits, in O(n) instead of O(n²) (the whole table, every
    step, was most of the predictor's bookkeeping in a small system's step;
    ``benchmarks/small_systems.py`` times that step). Else the whole table.
    Either way ``kept`` then holds this call's column."""
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
