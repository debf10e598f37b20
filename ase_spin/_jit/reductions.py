"""Per-thread scatter and its reductions: how threaded kernels split rows of
pairs into chunks and sum per-thread buffers, in a fixed order (the same bits
whatever the number of threads)."""

from __future__ import annotations

import numba as nb
import numpy as np

from .cloning import prange_only, serial_twin

__all__ = ["balanced_chunks", "reduce_threads", "reduce_threads_serial", "sum_over_threads"]


@nb.njit(cache=True)
def balanced_chunks(row, nchunks):
    """Boundaries splitting the rows into ``nchunks`` runs of about equal pair count."""
    n = len(row) - 1
    bounds = np.empty(nchunks + 1, dtype=np.int64)
    bounds[0] = 0
    total = row[n]
    a = 0
    for c in range(1, nchunks):
        target = (total * c) // nchunks
        while a < n and row[a] < target:
            a += 1
        bounds[c] = a
    bounds[nchunks] = n
    return bounds


@nb.njit(cache=True, parallel=prange_only())
def reduce_threads(buf, out):
    """out[i] += Σ_t buf[t, i]: sum per-thread buffers (t, n, k) into (n, k),
    t in order. Three columns (forces, fields) spelled out: a loop over a
    run-time k of 3 is not unrolled, and this runs after every pair pass."""
    if buf.shape[2] == 3:
        for i in nb.prange(buf.shape[1]):
            x = out[i, 0]
            y = out[i, 1]
            z = out[i, 2]
            for t in range(buf.shape[0]):
                x += buf[t, i, 0]
                y += buf[t, i, 1]
                z += buf[t, i, 2]
            out[i, 0] = x
            out[i, 1] = y
            out[i, 2] = z
        return
    for i in nb.prange(buf.shape[1]):
        for t in range(buf.shape[0]):
            for c in range(buf.shape[2]):
                out[i, c] += buf[t, i, c]


reduce_threads_serial = serial_twin(reduce_threads)


@nb.njit(cache=True)
def sum_over_threads(acc):
    """out_c = Σ_t acc[t, c] for t = 0, 1, ... in order, from 0.0: the same
    sums, bit for bit, as ``acc.sum(axis=0)``, which numba compiles with its
    axis checks and their error messages (about a second per kernel using it)."""
    out = np.zeros(acc.shape[1])
    for t in range(acc.shape[0]):
        for c in range(acc.shape[1]):
            out[c] += acc[t, c]
    return out

