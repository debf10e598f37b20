"""Verlet pair lists built by vesin and kept across calls with a skin.

A :class:`NeighborCache` holds one *full* pair list (each pair stored as i→j and
j→i) at the largest cutoff any term needs plus a skin, in compressed-row form
sorted by i. Terms ask it for sub-lists at their own cutoffs (and, for spin
terms, restricted to magnetic atoms). Distances are never stored: kernels
recompute d_ij = r_j + S_ij − r_i from the current positions and the pair's
Cartesian image shift S_ij, so a list stays valid until some atom has moved more
than half the skin from where it was when the list was built.

A full list costs twice the pair work of a half list but lets every kernel
gather into row i only, so kernels run threaded over atoms without races or
per-thread buffers.
"""

from __future__ import annotations

import numba as nb
import numpy as np
import vesin

__all__ = ["PairList", "NeighborCache"]


class PairList:
    """Pairs in compressed-row form: for atom i, neighbours ``j[row[i]:row[i+1]]``
    with Cartesian image shifts ``shift[row[i]:row[i+1]]`` (Å)."""

    __slots__ = ("row", "j", "shift", "cutoff")

    def __init__(self, row, j, shift, cutoff):
        self.row = row
        self.j = j
        self.shift = shift
        self.cutoff = cutoff

    def __len__(self):
        return len(self.j)

    @property
    def i(self):
        """First index of every pair (expanded from the row pointer)."""
        return np.repeat(np.arange(len(self.row) - 1), np.diff(self.row))


@nb.njit(cache=True)
def _max_displacement_sq(positions, reference):
    worst = 0.0
    for a in range(positions.shape[0]):
        dx = positions[a, 0] - reference[a, 0]
        dy = positions[a, 1] - reference[a, 1]
        dz = positions[a, 2] - reference[a, 2]
        d2 = dx * dx + dy * dy + dz * dz
        if d2 > worst:
            worst = d2
    return worst


def _rows(i, n):
    row = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(i, minlength=n), out=row[1:])
    return row


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
        self._vesin = vesin.NeighborList(
            cutoff=self.cutoff + self.skin, full_list=True, sorted=True
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
        return _max_displacement_sq(positions, self._reference) > (0.5 * self.skin) ** 2

    def update(self, positions, cell, pbc):
        """Make the list valid for ``positions``; return True if it was rebuilt."""
        positions = np.ascontiguousarray(positions, dtype=float)
        cell = np.asarray(cell, dtype=float)
        pbc = np.asarray(pbc, dtype=bool)
        if not self.needs_rebuild(positions, cell, pbc):
            return False
        n = len(positions)
        if n:
            i, j, s = self._vesin.compute(positions, cell, pbc, "ijS", copy=True)
        else:
            i = j = np.zeros(0, dtype=np.int64)
            s = np.zeros((0, 3))
        i = i.astype(np.int64)
        j = j.astype(np.int64)
        shift = np.ascontiguousarray(s @ cell) if len(s) else np.zeros((0, 3))
        self.pairs = PairList(_rows(i, n), j, shift, self.cutoff)
        self._pair_i = i
        self._dist = np.linalg.norm(positions[j] + shift - positions[i], axis=1)
        self._reference = positions.copy()
        self._cell = cell.copy()
        self._pbc = pbc.copy()
        self._sublists = {}
        self.builds += 1
        return True

    def sublist(self, cutoff, mask=None):
        """Pairs within ``cutoff + skin`` at the last build, between atoms where
        ``mask`` is True (all atoms if None). Cached until the next rebuild."""
        key = (float(cutoff), None if mask is None else mask.tobytes())
        cached = self._sublists.get(key)
        if cached is not None:
            return cached
        if cutoff >= self.cutoff and mask is None:
            sub = self.pairs
        else:
            keep = self._dist < cutoff + self.skin
            if mask is not None:
                keep &= mask[self._pair_i] & mask[self.pairs.j]
            n = len(self.pairs.row) - 1
            sub = PairList(
                _rows(self._pair_i[keep], n),
                np.ascontiguousarray(self.pairs.j[keep]),
                np.ascontiguousarray(self.pairs.shift[keep]),
                float(cutoff),
            )
        self._sublists[key] = sub
        return sub
