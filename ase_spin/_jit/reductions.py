"""Per-thread scatter and its reductions: how threaded kernels split rows of
pairs into chunks and sum per-thread buffers, in a fixed order (the same bits
whatever the number of threads).

The pair kernels over half lists (Lennard-Jones, EAM, exchange) share one
skeleton: rows in ``nthreads`` chunks of about equal pair count
(:func:`balanced_chunks`), each chunk scattering into buffers of its own
(:func:`scatter_buffers`, :func:`thread_buffer`; a pair's share and each
row's own sums added with :func:`add_row`, :func:`sub_row`, or
:func:`add_to` where a row is its chunk's alone), each chunk's energy and
virial kept apart (:func:`store_sums`), then the buffers summed in thread
order (:func:`reduce_scatter`). The pieces are inlined (``inline="always"``):
a kernel runs the same operations in the same order as if written out.

Those called per row or pair take arrays and hold no branch, and the
request's flags stay in the kernels (``if want_forces: add_row(...)``): an
array passed into an inlined function with branches costs a reference-count
increment and decrement per call, which numba's pruning does not remove
(measured on the exchange passes' serial twins: ``git show
80c7697:docs/benchmarks.md``, "Tried and not kept"). A kernel with a serial twin passes its
own ``reduce_threads`` to :func:`reduce_scatter` (the twin's is
:func:`reduce_threads_serial`; a name looked up here would stay the threaded
one).

A scatter onto a mesh (the particle-mesh Ewald sum's spread) takes no
per-thread buffers, which would cost a whole mesh per thread: its rows,
sorted by mesh plane, are cut into groups of planes (:func:`stencil_groups`)
such that groups of one parity write disjoint planes; the even groups run
in parallel, then the odd ones."""

from __future__ import annotations

import numba as nb
import numpy as np

from .cloning import prange_only, serial_twin

__all__ = ["stencil_groups", "balanced_chunks", "reduce_threads", "reduce_threads_serial",
           "sum_over_threads", "thread_buffer", "scatter_buffers", "add_to", "add_row", "sub_row",
           "store_sums", "reduce_scatter"]


def stencil_groups(keys, nkeys, reach):
    """Boundaries (ngroups + 1) cutting rows sorted by a periodic key
    k ∈ [0, nkeys) into groups of whole runs of keys, where a row of key k
    writes to keys k − reach … k (mod nkeys): an even number of groups, each
    at least ``reach`` keys wide (or one group where nkeys < 2 reach), so that
    no two groups of one parity write a common key and each parity's groups
    can run in parallel without buffers, the even ones first. The cut depends
    on nkeys and reach alone: every key receives its rows' sums in the same
    order whatever the number of threads."""
    reach = max(1, int(reach))
    ngroups = 2 * (nkeys // (2 * reach))
    if ngroups < 2:
        ngroups = 1
    cuts = (np.arange(ngroups + 1, dtype=np.int64) * nkeys) // ngroups
    return np.searchsorted(np.asarray(keys), cuts, side="left").astype(np.int64)


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


@nb.njit(cache=True, inline="always")
def thread_buffer(nthreads, n, want, columns):
    """Zeros (nthreads, n, columns): a per-thread scatter buffer for n atoms,
    with no rows unless ``want``."""
    return np.zeros((nthreads, n if want else 0, columns))


@nb.njit(cache=True, inline="always")
def scatter_buffers(row, nthreads, want_forces, want_energies):
    """(bounds, fbuf, ebuf, acc) of a pair kernel over a half list: the chunks'
    rows (:func:`balanced_chunks`), per-thread forces (t, n, 3) and energies
    (t, n, 1) (no rows unless wanted) and per-thread sums (t, 7): energy and
    virial in Voigt order (:func:`store_sums`)."""
    n = len(row) - 1
    bounds = balanced_chunks(row, nthreads)
    fbuf = thread_buffer(nthreads, n, want_forces, 3)
    ebuf = thread_buffer(nthreads, n, want_energies, 1)
    acc = np.zeros((nthreads, 7))
    return bounds, fbuf, ebuf, acc


@nb.njit(cache=True, inline="always")
def add_to(out, i, x, y, z):
    """out[i, 0:3] += (x, y, z): a row's sums where it alone writes (a full list)."""
    out[i, 0] += x
    out[i, 1] += y
    out[i, 2] += z


@nb.njit(cache=True, inline="always")
def add_row(buf, t, i, col, x, y, z):
    """buf[t, i, col:col + 3] += (x, y, z)."""
    buf[t, i, col] += x
    buf[t, i, col + 1] += y
    buf[t, i, col + 2] += z


@nb.njit(cache=True, inline="always")
def sub_row(buf, t, i, col, x, y, z):
    """buf[t, i, col:col + 3] −= (x, y, z)."""
    buf[t, i, col] -= x
    buf[t, i, col + 1] -= y
    buf[t, i, col + 2] -= z


@nb.njit(cache=True, inline="always")
def store_sums(acc, t, e, vxx, vyy, vzz, vyz, vxz, vxy):
    """acc[t] = (E, W in Voigt order xx yy zz yz xz xy): chunk t's sums."""
    acc[t, 0] = e
    acc[t, 1] = vxx
    acc[t, 2] = vyy
    acc[t, 3] = vzz
    acc[t, 4] = vyz
    acc[t, 5] = vxz
    acc[t, 6] = vxy


@nb.njit(cache=True, inline="always")
def reduce_scatter(reduce, fbuf, forces, ebuf, energies, acc):
    """forces += Σ_t fbuf[t], energies += Σ_t ebuf[t] (by ``reduce``: the
    calling kernel's reduce_threads, threaded or serial), and returns
    Σ_t acc[t] (:func:`sum_over_threads`)."""
    reduce(fbuf, forces)
    reduce(ebuf, energies.reshape((energies.shape[0], 1)))
    return sum_over_threads(acc)
