"""The lattice half of a step, compiled: the Störmer–Verlet kick and drift,
compensated (Kahan), and both in one pass with the checks a step needs."""

from __future__ import annotations

import numba as nb
import numpy as np

from ..._jit.threads import threaded


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
