"""Compiled helpers for the state a step keeps: equality tests, the commit of
q, p, s to the Atoms' arrays, the first non-finite row."""

from __future__ import annotations

import numba as nb
import numpy as np


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
