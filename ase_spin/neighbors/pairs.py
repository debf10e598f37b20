"""Pair lists in compressed-row form, and what is made from one: a greedy
colouring of the atoms, the rows copied in another order, a counting sort.

A :class:`PairList` is what :class:`~ase_spin.neighbors.cache.NeighborCache`
hands to the terms: *half* (each pair once, in the row of its smaller index)
for one-off evaluations, or *full* (i → j and j → i, rows sorted by j) for
passes that only gather into row i (see :mod:`ase_spin.neighbors`).
"""

from __future__ import annotations

import numba as nb
import numpy as np

__all__ = ["PairList", "greedy_colouring", "rows_in_order", "group_by_key"]


class PairList:
    """Pairs in compressed-row form: for atom i, neighbours ``j[row[i]:row[i+1]]``
    with Cartesian image shifts ``images[image[k]]`` (Å).

    Image shifts are stored as a small index into the table ``images`` of the
    distinct lattice translations (27 of them in a large cell), not as three
    doubles per pair: the kernels are bound by memory traffic over the pair
    list, and this cuts it from 32 to 6 bytes per pair.
    """

    __slots__ = ("row", "j", "image", "images", "cutoff", "half", "_colours")

    def __init__(self, row, j, image, images, cutoff, half=False):
        self.row = row
        self.j = j
        self.image = image
        self.images = images
        self.cutoff = cutoff
        self.half = half  # each unordered pair once (else both i → j and j → i)
        self._colours = None

    def __len__(self):
        return len(self.j)

    def colours(self):
        """``(order, starts)``: the atoms in colour order, colour c being
        ``order[starts[c]:starts[c + 1]]``, no two atoms of one colour paired
        (a greedy colouring, made once per list: :func:`greedy_colouring`).
        A full list only: the colour-ordered sweeps gather each row's whole
        field from its own row."""
        if self.half:
            raise ValueError("a colouring needs the full pair list (half=False)")
        if self._colours is None:
            self._colours = greedy_colouring(self.row, self.j)
        return self._colours

    @property
    def shift(self):
        """Cartesian image shift of every pair (an (npairs, 3) array)."""
        return self.images[self.image]

    @property
    def i(self):
        """First index of every pair (expanded from the row pointer)."""
        return np.repeat(np.arange(len(self.row) - 1), np.diff(self.row))


@nb.njit(cache=True)
def greedy_colouring(row, nbr):
    """Colour the atoms of a full pair list so that no pair joins two atoms of
    one colour: each atom in index order takes the smallest colour none of
    its coloured partners has (pairs of an atom with its own image are not
    counted). On a simple cubic lattice with an even number of cells, or
    fcc with nearest neighbours, this finds 2 and 4 colours. Returns
    ``(order, starts)``: the atoms sorted by colour (by index within one),
    colour c being ``order[starts[c]:starts[c + 1]]``."""
    n = len(row) - 1
    colour = np.full(n, -1, dtype=np.int64)
    taken = np.full(n + 1, -1, dtype=np.int64)  # taken[c] == i: a partner of i has c
    ncolours = 1 if n > 0 else 0
    for i in range(n):
        for k in range(row[i], row[i + 1]):
            j = nbr[k]
            if j != i and colour[j] >= 0:
                taken[colour[j]] = i
        c = 0
        while taken[c] == i:
            c += 1
        colour[i] = c
        if c + 1 > ncolours:
            ncolours = c + 1
    starts, order = group_by_key(colour, ncolours)
    return order, starts


@nb.njit(cache=True)
def rows_in_order(row, nbr, c, order):
    """The rows of a pair list (row pointer, partners, per-pair values ``c``)
    copied in ``order``: row a of the copy is row ``order[a]``, its pairs in
    their order. A colour-ordered sweep then reads each colour's rows as one
    stretch of memory instead of scattered over the list: a copy made only for
    speed (``benchmarks/frozen_before_after.py``; docs/benchmarks.md,
    "Why each fast path exists")."""
    n = len(order)
    prow = np.zeros(n + 1, dtype=np.int64)
    for a in range(n):
        i = order[a]
        prow[a + 1] = prow[a] + (row[i + 1] - row[i])
    pnbr = np.empty(prow[n], dtype=nbr.dtype)
    pc = np.empty(prow[n], dtype=c.dtype)
    for a in range(n):
        i = order[a]
        k0 = prow[a]
        for k in range(row[i], row[i + 1]):
            pnbr[k0] = nbr[k]
            pc[k0] = c[k]
            k0 += 1
    return prow, pnbr, pc


@nb.njit(cache=True)
def group_by_key(keys, nkeys):
    """``(start, order)``: the indices 0 … n−1 grouped by their ``keys`` (in
    0 … nkeys−1; a counting sort, by index within one key), key b holding
    ``order[start[b]:start[b + 1]]``."""
    n = keys.shape[0]
    start = np.zeros(nkeys + 1, dtype=np.int64)
    for a in range(n):
        start[keys[a] + 1] += 1
    for b in range(nkeys):
        start[b + 1] += start[b]
    fill = start[:-1].copy()
    order = np.empty(n, dtype=np.int64)
    for a in range(n):
        order[fill[keys[a]]] = a
        fill[keys[a]] += 1
    return start, order

