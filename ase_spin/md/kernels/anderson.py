"""The midpoint solvers' convergence test and Anderson acceleration: the
bookkeeping after a sweep (contraction, stopping at the tolerance or at
round-off) and the mixing of the last iterates. The acceleration exists to
save sweeps at large steps, where plain sweeps contract slowly
(``benchmarks/solver_choice.py``, ``benchmarks/solver.py``; docs/benchmarks.md,
"The midpoint solver against the step size")."""

from __future__ import annotations

import numba as nb
import numpy as np

from ..._jit import threads
from ..._jit.cloning import serial_twin
from .midpoint import BLOCK, CONVERGED, NOT_CONVERGED, ROUNDOFF


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
