"""Verlet pair lists built by vesin and kept across calls with a skin.

A :class:`NeighborCache` holds one *full* pair list (each pair stored as i→j and
j→i) at the largest cutoff any term needs plus a skin, in compressed-row form
sorted by i. Terms ask it for sub-lists at their own cutoffs (and, for spin
terms, restricted to magnetic atoms). Distances are never stored: kernels
recompute d_ij = r_j + S_ij − r_i from the current positions and the pair's
Cartesian image shift S_ij, so a list stays valid until some atom has moved more
than half the skin from where it was when the list was built.

Two shapes of list serve two kinds of kernel (measured on fcc Co, 2 cores):

- *half* lists (each pair once) for one-off evaluations of energy, forces and
  magnetic forces: threads take runs of rows of equal pair count and scatter
  into per-thread buffers summed at the end. Half the pair work of a full list,
  and half the exp() calls of a Bethe–Slater J(r): 0.32 against 0.52 µs/atom.
- *full* lists (i→j and j→i, rows sorted by j) for passes that only gather
  into row i, such as B_i = Σ_j J_ij s_j from cached pair geometry: no buffers,
  no reduction, threads over atoms.
"""

from __future__ import annotations

import numba as nb
import numpy as np
import vesin

from .threads import serial_twin

__all__ = ["PairList", "NeighborCache"]


class PairList:
    """Pairs in compressed-row form: for atom i, neighbours ``j[row[i]:row[i+1]]``
    with Cartesian image shifts ``images[image[k]]`` (Å).

    Image shifts are stored as a small index into the table ``images`` of the
    distinct lattice translations (27 of them in a large cell), not as three
    doubles per pair: the kernels are bound by memory traffic over the pair
    list, and this cuts it from 32 to 6 bytes per pair.
    """

    __slots__ = ("row", "j", "image", "images", "cutoff", "half")

    def __init__(self, row, j, image, images, cutoff, half=False):
        self.row = row
        self.j = j
        self.image = image
        self.images = images
        self.cutoff = cutoff
        self.half = half  # each unordered pair once (else both i → j and j → i)

    def __len__(self):
        return len(self.j)

    @property
    def shift(self):
        """Cartesian image shift of every pair (an (npairs, 3) array)."""
        return self.images[self.image]

    @property
    def i(self):
        """First index of every pair (expanded from the row pointer)."""
        return np.repeat(np.arange(len(self.row) - 1), np.diff(self.row))


@nb.njit(cache=True)
def max_displacement(positions, reference):
    """(largest |r_a − r_ref,a|, that atom's index); NaN if any distance is NaN."""
    worst = 0.0
    at = 0
    for a in range(positions.shape[0]):
        dx = positions[a, 0] - reference[a, 0]
        dy = positions[a, 1] - reference[a, 1]
        dz = positions[a, 2] - reference[a, 2]
        d2 = dx * dx + dy * dy + dz * dz
        if not d2 <= worst:
            worst = d2
            at = a
    return np.sqrt(worst), at


def _rows(i, n):
    row = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(i, minlength=n), out=row[1:])
    return row


@nb.njit(cache=True)
def _bucket_by_row(i, row):
    """Permutation that groups pairs by first index i (a counting sort)."""
    fill = row[:-1].copy()
    order = np.empty(len(i), dtype=np.int64)
    for k in range(len(i)):
        a = i[k]
        order[fill[a]] = k
        fill[a] += 1
    return order


@nb.njit(cache=True, parallel=True)
def _sort_rows(row, j, shift_int, order):
    """Sort each row's entries by neighbour index (then image shift), in place
    on ``order``: neighbours in memory order make the kernels' gathers of
    positions and spins cache-friendly."""
    n = len(row) - 1
    for a in nb.prange(n):
        lo = row[a]
        hi = row[a + 1]
        for x in range(lo + 1, hi):
            key = order[x]
            kj = j[key]
            k0 = shift_int[key, 0]
            k1 = shift_int[key, 1]
            k2 = shift_int[key, 2]
            y = x - 1
            while y >= lo:
                o = order[y]
                oj = j[o]
                if oj < kj or (oj == kj and (shift_int[o, 0], shift_int[o, 1],
                                             shift_int[o, 2]) <= (k0, k1, k2)):
                    break
                order[y + 1] = o
                y -= 1
            order[y + 1] = key


@nb.njit(cache=True, inline="always")
def separation(pos, images, i, j, m):
    """d_ij = r_j + S_m − r_i and |d_ij|² for pair (i, j) with image shift m."""
    dx = pos[j, 0] + images[m, 0] - pos[i, 0]
    dy = pos[j, 1] + images[m, 1] - pos[i, 1]
    dz = pos[j, 2] + images[m, 2] - pos[i, 2]
    return dx, dy, dz, dx * dx + dy * dy + dz * dz


@nb.njit(cache=True, parallel=True)
def _pair_distances(positions, row, j, image, images, out):
    n = len(row) - 1
    for a in nb.prange(n):
        for k in range(row[a], row[a + 1]):
            out[k] = np.sqrt(separation(positions, images, a, j[k], image[k])[3])


def _image_table(s, cell):
    """Distinct integer image shifts as a Cartesian table plus each pair's index
    into it (a counting pass: np.unique over rows would sort every pair)."""
    if len(s) == 0:
        return np.zeros((1, 3)), np.zeros(0, dtype=np.int16)
    lo = s.min(axis=0)
    span = s.max(axis=0) - lo + 1
    key = ((s[:, 0] - lo[0]) * span[1] + (s[:, 1] - lo[1])) * span[2] + (s[:, 2] - lo[2])
    present = np.flatnonzero(np.bincount(key, minlength=int(np.prod(span))))
    lookup = np.zeros(int(np.prod(span)), dtype=np.int64)
    lookup[present] = np.arange(len(present))
    distinct = np.column_stack(np.unravel_index(present, tuple(span))) + lo
    index_type = np.int16 if len(present) < 32768 else np.int32
    return np.ascontiguousarray(distinct @ cell), lookup[key].astype(index_type)


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


@nb.njit(cache=True, parallel=True)
def reduce_threads(buf, out):
    """out[i] += Σ_t buf[t, i]: sum per-thread buffers (t, n, k) into (n, k)."""
    for i in nb.prange(buf.shape[1]):
        for t in range(buf.shape[0]):
            for c in range(buf.shape[2]):
                out[i, c] += buf[t, i, c]


reduce_threads_serial = serial_twin(reduce_threads)


class NeighborCache:
    """A full Verlet list at ``max(cutoffs) + skin``, rebuilt only when needed.

    Rebuilt when an atom has moved more than ``skin / 2`` since the last build,
    or when the cell, the periodicity or the number of atoms changed.
    ``builds`` counts the builds.
    """

    def __init__(self, cutoff, skin=0.3):
        if not cutoff > 0.0:
            raise ValueError(f"neighbour-list cutoff must be positive, got {cutoff}")
        if not skin >= 0.0:
            raise ValueError(f"skin must be >= 0, got {skin}")
        self.cutoff = float(cutoff)
        self.skin = float(skin)
        # vesin's own sort orders by i only; rows are sorted here (by j too)
        # One vesin thread: its OpenMP workers would otherwise spin after each
        # build and steal the cores from the numba kernels that follow.
        self._vesin = vesin.NeighborList(
            cutoff=self.cutoff + self.skin, full_list=True, sorted=False, n_threads=1
        )
        self._reference = None
        self._cell = None
        self._pbc = None
        self._sublists = {}
        self.builds = 0
        self.pairs = None

    def invalidate(self):
        self._reference = None

    def needs_rebuild(self, positions, cell, pbc):
        if self._reference is None or positions.shape != self._reference.shape:
            return True
        if not np.array_equal(cell, self._cell) or not np.array_equal(pbc, self._pbc):
            return True
        return max_displacement(positions, self._reference)[0] > 0.5 * self.skin

    def update(self, positions, cell, pbc):
        """Make the list valid for ``positions``; return True if it was rebuilt."""
        positions = np.ascontiguousarray(positions, dtype=float)
        cell = np.asarray(cell, dtype=float)
        pbc = np.asarray(pbc, dtype=bool)
        if not self.needs_rebuild(positions, cell, pbc):
            return False
        n = len(positions)
        if n:
            i, j, s = self._vesin.compute(positions, cell, pbc, "ijS", copy=False)
            i = i.astype(np.int64)
            j = j.astype(np.int64)
            s = np.asarray(s, dtype=np.int64)
        else:
            i = j = np.zeros(0, dtype=np.int64)
            s = np.zeros((0, 3), dtype=np.int64)
        row = _rows(i, n)
        order = _bucket_by_row(i, row)
        _sort_rows(row, j, s, order)
        j = j[order].astype(np.int32)
        images, image = _image_table(s[order], cell)
        self.pairs = PairList(row, j, image, images, self.cutoff)
        self._pair_i = i[order]
        # each unordered pair once: i < j, or an atom and its own image with the
        # shift that is lexicographically positive
        so = s[order]
        self._first = (j > self._pair_i) | (
            (j == self._pair_i)
            & ((so[:, 0] > 0) | ((so[:, 0] == 0) & ((so[:, 1] > 0)
                                                    | ((so[:, 1] == 0) & (so[:, 2] > 0))))))
        self._dist = np.empty(len(j))
        _pair_distances(positions, row, j, image, images, self._dist)
        self._reference = positions.copy()
        self._cell = cell.copy()
        self._pbc = pbc.copy()
        self._sublists = {}
        self.builds += 1
        return True

    def sublist(self, cutoff, mask=None, half=False):
        """Pairs within ``cutoff + skin`` at the last build, between atoms where
        ``mask`` is True (all atoms if None); with ``half``, each unordered pair
        once (row of the smaller index). Cached until the next rebuild."""
        key = (float(cutoff), None if mask is None else mask.tobytes(), half)
        cached = self._sublists.get(key)
        if cached is not None:
            return cached
        if cutoff >= self.cutoff and mask is None and not half:
            sub = self.pairs
        else:
            keep = self._dist < cutoff + self.skin
            if half:
                keep &= self._first
            if mask is not None:
                keep &= mask[self._pair_i] & mask[self.pairs.j]
            n = len(self.pairs.row) - 1
            sub = PairList(
                _rows(self._pair_i[keep], n),
                np.ascontiguousarray(self.pairs.j[keep]),
                np.ascontiguousarray(self.pairs.image[keep]),
                self.pairs.images,
                float(cutoff),
                half,
            )
        self._sublists[key] = sub
        return sub
