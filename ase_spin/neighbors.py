"""Verlet pair lists built by a compiled cell list and kept across calls with a skin.

A :class:`NeighborCache` holds one *half* pair list (each pair once, in the row
of its smaller index) at the largest cutoff any term needs plus a skin, in
compressed-row form, rows sorted by (j, image shift). Terms ask it for sub-lists
at their own cutoffs (and, for spin terms, restricted to magnetic atoms), half
or full; the list at the largest cutoff is shared, not copied. Distances are never stored: kernels
recompute d_ij = r_j + S_ij − r_i from the current positions and the pair's
Cartesian image shift S_ij, so a list stays valid until some atom has moved more
than half the skin from where it was when the list was built.

Two levels of skin. The sub-lists a term gets are filtered from the list at
their own cutoff plus a finer skin (:data:`FINE_SKIN` of it), at the positions
of their last filtering, and filtered again (one pass over the list's pairs)
when an atom has moved more than half the gap between the cutoff and the
closest pair left out (at least half the fine skin); the list itself is
rebuilt by the cell search as before. A shell of neighbours just beyond a
term's cutoff then stays out of its list: fcc Co's exchange at 4.0 Å with the
skin of 0.3 Å took in, once thermal motion had spread the third shell (4.34
Å) across 4.3 Å, 11.3 pairs per atom of which 9 interact; with the fine skin,
9.0 — every pass of the exchange (the midpoint sweeps, the force passes, the
pair geometry) does that much less work (docs/benchmarks.md).

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

from ._jit import threads
from ._jit.cloning import prange_only
from .validate import real_array

__all__ = ["PairList", "NeighborCache"]

#: The sub-lists' skin as a fraction of the list's (see the module docstring):
#: half, so that they are filtered again about twice as often as the list would
#: be rebuilt (fcc Co at 300 K and 0.1 fs: every ~110 steps).
FINE_SKIN = 0.5


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
    stretch of memory instead of scattered over the list (docs/benchmarks.md,
    "Colour-ordered sweeps")."""
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
def max_displacement(positions, reference):
    """(largest |r_a − r_ref,a|, that atom's index); NaN if any distance is NaN."""
    worst = 0.0
    at = 0
    for a in range(positions.shape[0]):
        dx = positions[a, 0] - reference[a, 0]
        dy = positions[a, 1] - reference[a, 1]
        dz = positions[a, 2] - reference[a, 2]
        d2 = dx * dx + dy * dy + dz * dz
        if not d2 <= worst and worst == worst:  # a NaN stays
            worst = d2
            at = a
    return np.sqrt(worst), at


@nb.njit(cache=True)
def largest_displacements(positions, a_reference, b_reference):
    """(max_a |r_a − r_a of ``a_reference``|, the same from ``b_reference``)
    in one pass over ``positions``, NaN if any is NaN: :func:`max_displacement`
    without the atom, maxima without branches (half its time per reference)."""
    worst_a = worst_b = 0.0
    bad = False
    for a in range(positions.shape[0]):
        x = positions[a, 0]
        y = positions[a, 1]
        z = positions[a, 2]
        dx = x - a_reference[a, 0]
        dy = y - a_reference[a, 1]
        dz = z - a_reference[a, 2]
        d2 = dx * dx + dy * dy + dz * dz
        ex = x - b_reference[a, 0]
        ey = y - b_reference[a, 1]
        ez = z - b_reference[a, 2]
        e2 = ex * ex + ey * ey + ez * ez
        bad |= (d2 != d2) | (e2 != e2)
        worst_a = max(worst_a, d2)
        worst_b = max(worst_b, e2)
    if bad:
        return np.nan, np.nan
    return np.sqrt(worst_a), np.sqrt(worst_b)


@nb.njit(cache=True)
def all_finite(a):
    """No NaN or inf in a 2-D array (one compiled pass: cheaper than numpy's
    two for the few atoms of a small system, checked several times a step)."""
    for i in range(a.shape[0]):
        for c in range(a.shape[1]):
            if not np.isfinite(a[i, c]):
                return False
    return True


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


@nb.njit(cache=True, inline="always")
def separation(pos, images, i, j, m):
    """d_ij = (r_j − r_i) + S_m and |d_ij|² for pair (i, j) with image shift m.

    In this order of operations d_ji = −d_ij bitwise (negation is exact), so a
    pair at the cutoff is inside or outside for both of its atoms alike."""
    dx = (pos[j, 0] - pos[i, 0]) + images[m, 0]
    dy = (pos[j, 1] - pos[i, 1]) + images[m, 1]
    dz = (pos[j, 2] - pos[i, 2]) + images[m, 2]
    return dx, dy, dz, dx * dx + dy * dy + dz * dz


def check_cell(cell, pbc):
    """The cell as a float64 (3, 3) array and pbc as three bools, checked: finite,
    and along periodic directions non-zero, independent vectors (a periodic
    direction needs a period). Non-periodic directions may have zero vectors."""
    cell = real_array(cell, "cell")
    if cell.shape != (3, 3):
        cell = cell.reshape(3, 3) if cell.size == 9 else cell
        if cell.shape != (3, 3):
            raise ValueError(f"cell must be a 3x3 matrix, got shape {cell.shape}")
    if not np.isfinite(cell).all():
        raise ValueError(f"cell is not finite: {cell.tolist()}")
    pbc = np.asarray(pbc)
    if pbc.dtype.kind not in "bi" and pbc.dtype != object:
        raise TypeError(f"pbc must be booleans, got {pbc!r}")
    pbc = np.array([bool(x) for x in np.broadcast_to(pbc, (3,))])
    periodic = np.flatnonzero(pbc)
    if periodic.size:
        names = "abc"
        axes = "xyz"
        for k in periodic:
            if not np.any(cell[k]):
                raise ValueError(
                    f"pbc is True along {axes[k]} but cell vector {names[k]} is zero: give "
                    f"the atoms a cell (atoms.cell = ...) or set pbc False along {axes[k]}")
        vectors = cell[periodic]
        sv = np.linalg.svd(vectors / np.abs(vectors).max(), compute_uv=False)
        if sv.min() <= 1e-12 * sv.max():
            raise ValueError(
                f"the cell vectors {', '.join(names[k] for k in periodic)} of the periodic "
                f"directions are linearly dependent or of wildly different lengths (cell {cell.tolist()}): a periodic "
                f"direction needs an independent cell vector")
    return cell, pbc


#: Refuse cells so small along periodic directions that each atom would see more
#: periodic images of every other atom than this within the cutoff.
MAX_IMAGES = 100_000

def _face_distances(cell, pbc):
    """Distances between opposite faces of the cell along periodic directions."""
    out = np.full(3, np.inf)
    for k in np.flatnonzero(pbc):
        a, b = cell[(k + 1) % 3], cell[(k + 2) % 3]
        n = np.cross(a, b)
        if pbc.sum() < 3 or not np.any(n):
            # the other vectors may be open (zero): the period is the length of
            # this vector's component normal to the other periodic vectors
            others = cell[[p for p in np.flatnonzero(pbc) if p != k]]
            v = cell[k].copy()
            if len(others):
                q, _ = np.linalg.qr(others.T)
                v = v - q @ (q.T @ v)
            out[k] = np.linalg.norm(v)
        else:
            out[k] = abs(np.dot(n / np.linalg.norm(n), cell[k]))
    return out


#: Atoms farther than this many cells outside a periodic cell are refused: their
#: coordinates (≳ 1e9 Å) resolve distances no better than ~1e-6 Å.
_MAX_CELLS_AWAY = 2.0**31


def _wrap(positions, cell, pbc):
    """Positions moved into the cell along periodic directions, r − n·cell, and
    the integer n of every atom (zero along open directions)."""
    n = np.zeros((len(positions), 3), dtype=np.int64)
    if not pbc.any() or len(positions) == 0:
        return positions, n
    periodic = np.flatnonzero(pbc)
    # fractional coordinates along the periodic vectors (least squares handles
    # zero or dependent open vectors)
    frac = np.linalg.lstsq(cell[periodic].T, positions.T, rcond=None)[0].T
    shift = np.floor(frac)
    far = np.abs(shift) >= _MAX_CELLS_AWAY
    if far.any():
        atom, k = np.argwhere(far)[0]
        raise ValueError(
            f"atom {atom} lies {abs(frac[atom, k]):.3g} cells outside the periodic cell "
            f"along cell vector {'abc'[periodic[k]]}: its position keeps no precision for "
            f"distances at that range; wrap the atoms into the cell (atoms.wrap())")
    # the sweep takes atoms a cell or two outside as they are (without this copy and the
    # shift correction of every pair); only atoms farther out are moved here
    shift[np.abs(shift) <= 2.0] = 0.0
    if not shift.any():
        return positions, n
    n[:, periodic] = shift.astype(np.int64)
    return positions - n[:, periodic] @ cell[periodic], n


@nb.njit(cache=True)
def _sweep_count_or_fill(order, x, pos, shifts, cut2, cut, i_out, j_out, m_out, fill):
    """Pairs (i, j, m) with |(r_j − r_i) + T_m| < cut, by a sweep over atoms sorted
    along x for each image shift T_m: memory O(N + pairs), whatever the extent."""
    n = len(order)
    count = 0
    for m in range(shifts.shape[0]):
        tx = shifts[m, 0]
        start = 0
        for a in range(n):
            i = order[a]
            xi = x[i] - tx  # atoms j with x_j + tx within cut of x_i
            while start < n and x[order[start]] < xi - cut:
                start += 1
            b = start
            while b < n and x[order[b]] <= xi + cut:
                j = order[b]
                b += 1
                if i == j and shifts[m, 0] == 0.0 and shifts[m, 1] == 0.0 \
                        and shifts[m, 2] == 0.0:
                    continue
                dx = (pos[j, 0] - pos[i, 0]) + shifts[m, 0]
                dy = (pos[j, 1] - pos[i, 1]) + shifts[m, 1]
                dz = (pos[j, 2] - pos[i, 2]) + shifts[m, 2]
                if dx * dx + dy * dy + dz * dz < cut2:
                    if fill:
                        i_out[count] = i
                        j_out[count] = j
                        m_out[count] = m
                    count += 1
    return count


def _sweep_pairs(positions, cell, pbc, cutoff):
    """Full pair list (i, j, integer shifts) for boxes the cell list cannot grid
    (an extent that is not finite); the reference the tests hold it to."""
    periodic = np.flatnonzero(pbc)
    reach = np.zeros(3, dtype=np.int64)
    if periodic.size:
        faces = _face_distances(cell, pbc)
        reach[periodic] = np.ceil(cutoff / faces[periodic]).astype(np.int64)
    grids = [np.arange(-r, r + 1) for r in reach]
    ints = np.array(np.meshgrid(*grids, indexing="ij")).reshape(3, -1).T
    shifts = np.ascontiguousarray(ints @ cell, dtype=float)
    x = np.ascontiguousarray(positions[:, 0])
    order = np.argsort(x, kind="stable")
    empty = np.zeros(0, dtype=np.int64)
    count = _sweep_count_or_fill(order, x, positions, shifts, cutoff * cutoff, cutoff,
                                 empty, empty, empty, False)
    i = np.empty(count, dtype=np.int64)
    j = np.empty(count, dtype=np.int64)
    m = np.empty(count, dtype=np.int64)
    _sweep_count_or_fill(order, x, positions, shifts, cutoff * cutoff, cutoff, i, j, m, True)
    return i, j, ints[m]


# -- the cell-list search ------------------------------------------------------
#
# Pairs are searched on a grid of bins in coordinates u = r·A⁻¹ along a basis A
# whose rows are the periodic cell vectors and, along open directions, unit
# vectors orthogonal to them. A pair at distance |d| has |Δu_k| ≤ |d|·|b_k|
# (b_k the k-th column of A⁻¹, |b_k| = 1/face distance), so the bins within R_k
# of an atom's own hold all of its neighbours, whatever the cell's shape. The
# list is written once, each pair in the row of its smaller index, in two passes
# (count, fill): memory is the list itself (6 bytes a pair) plus a few arrays
# per atom, never a pair list of int64 indices and shifts.

#: Bins allowed, as a multiple of the atoms (a sparse system gets wider bins).
_BINS_PER_ATOM = 2
#: Largest dense table of image shifts (keys); beyond, shifts are collected.
_DENSE_KEYS = 1 << 22


def _far_error(atom, cells, k):
    return ValueError(
        f"atom {atom} lies {cells:.3g} cells outside the periodic cell "
        f"along cell vector {'abc'[k]}: its position keeps no precision for "
        f"distances at that range; wrap the atoms into the cell (atoms.wrap())")


def _grid_plan(positions, cell, pbc, reach):
    """Bins of every atom, its whole-cell offset n_i (u = n_i + fractional part
    along periodic directions), bins per direction, the reach R_k in bins, and
    the half-width L_k of the box of possible image shifts. None if the
    extent is not finite (the sweep takes such boxes)."""
    n = len(positions)
    periodic = np.flatnonzero(pbc)
    basis = np.zeros((3, 3))
    basis[periodic] = cell[periodic]
    open_ = np.flatnonzero(~pbc)
    if open_.size:
        if periodic.size:
            q, _ = np.linalg.qr(cell[periodic].T, mode="complete")
            basis[open_] = q[:, periodic.size:].T
        else:
            basis[open_] = np.eye(3)[open_]
    inverse = np.linalg.inv(basis)
    dual = np.sqrt((inverse**2).sum(axis=0))  # |b_k|
    u = positions @ inverse
    off = np.zeros((n, 3), dtype=np.int64)
    for k in periodic:
        f = np.floor(u[:, k])
        far = np.abs(f) >= _MAX_CELLS_AWAY
        if far.any():
            atom = int(np.argmax(far))
            raise _far_error(atom, abs(u[atom, k]), k)
        off[:, k] = f.astype(np.int64)
        u[:, k] -= f
    nbins = np.ones(3, dtype=np.int64)
    lo = np.zeros(3)
    span = np.ones(3)
    for k in range(3):
        x = reach * dual[k]  # largest |Δu_k| of a pair
        if pbc[k]:
            nbins[k] = max(1, int(min(np.floor(1.0 / (x * (1.0 + 1e-6))), 1 << 20)))
        else:
            lo[k] = u[:, k].min() if n else 0.0
            span[k] = (u[:, k].max() - lo[k]) if n else 0.0
            if not np.isfinite(span[k]):
                return None
            nbins[k] = max(1, int(min(np.floor(span[k] / (x * (1.0 + 1e-6))), 1 << 20)))
    while nbins.prod() > max(_BINS_PER_ATOM * n, 4096):
        k = int(np.argmax(nbins))
        nbins[k] = max(1, nbins[k] // 2)
    reach_bins = np.zeros(3, dtype=np.int64)
    bins = np.empty((n, 3), dtype=np.int64)
    for k in range(3):
        width = 1.0 / nbins[k] if pbc[k] else span[k] / nbins[k]
        if nbins[k] == 1:
            bins[:, k] = 0
            reach_bins[k] = int(np.ceil(reach * dual[k] * (1.0 + 1e-9) + 1e-12)) if pbc[k] else 0
        else:
            bins[:, k] = np.clip(np.floor((u[:, k] - lo[k]) / width), 0, nbins[k] - 1)
            reach_bins[k] = int(np.ceil(reach * dual[k] / width * (1.0 + 1e-9) + 1e-12))
    del u
    # image shifts S = s + n_i − n_j with s the wrap of the bin offset
    half_width = np.zeros(3, dtype=np.int64)
    for k in periodic:
        s_lo = -((reach_bins[k] + nbins[k] - 1) // nbins[k])
        s_hi = (nbins[k] - 1 + reach_bins[k]) // nbins[k]
        spread = int(off[:, k].max() - off[:, k].min()) if n else 0
        half_width[k] = max(-s_lo, s_hi) + spread
    return bins, off, nbins, reach_bins, half_width


@nb.njit(cache=True)
def _bin_sort(bins, nbins):
    """Atoms grouped by bin (a counting sort, by index within a bin): bin b holds
    ``order[start[b]:start[b + 1]]``."""
    n = bins.shape[0]
    ids = np.empty(n, dtype=np.int64)
    for a in range(n):
        ids[a] = (bins[a, 0] * nbins[1] + bins[a, 1]) * nbins[2] + bins[a, 2]
    return group_by_key(ids, nbins[0] * nbins[1] * nbins[2])


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


@nb.njit(cache=True, inline="always")
def _bin_along(c, n, periodic):
    """Bin c of a row of n along one axis: (the bin in the cell, the cell
    images it lies over, whether it exists — outside an open axis it does not)."""
    if periodic:
        shift = c // n
        return c - shift * n, shift, True
    return c, 0, 0 <= c < n


@nb.njit(cache=True, inline="always")
def _grid_row(i, pos, cell, bins, off, start, order, psorted, osorted, nbins, rb, periodic,
              cut2, hw, fill, k0, j_out, img_out, s_out, lookup, present):
    """Visit atom i's neighbours j ≥ i (j = i: images with a lexicographically
    positive shift) within sqrt(cut2): count them, mark their shifts' keys in
    ``present`` (when not ``fill``), or write them from k0 on (j, and the image
    index ``lookup[key]``, or the shift itself when ``lookup`` is empty)."""
    b0 = bins[i, 0]
    b1 = bins[i, 1]
    b2 = bins[i, 2]
    xi = pos[i, 0]
    yi = pos[i, 1]
    zi = pos[i, 2]
    o0 = off[i, 0]
    o1 = off[i, 1]
    o2 = off[i, 2]
    sp1 = 2 * hw[1] + 1
    sp2 = 2 * hw[2] + 1
    dense = present.shape[0] > 0 or lookup.shape[0] > 0
    count = 0
    for d0 in range(-rb[0], rb[0] + 1):
        c0, s0, inside = _bin_along(b0 + d0, nbins[0], periodic[0])
        if not inside:
            continue
        for d1 in range(-rb[1], rb[1] + 1):
            c1, s1, inside = _bin_along(b1 + d1, nbins[1], periodic[1])
            if not inside:
                continue
            for d2 in range(-rb[2], rb[2] + 1):
                c2, s2, inside = _bin_along(b2 + d2, nbins[2], periodic[2])
                if not inside:
                    continue
                b = (c0 * nbins[1] + c1) * nbins[2] + c2
                for t in range(start[b], start[b + 1]):
                    j = order[t]
                    if j < i:
                        continue
                    S0 = s0 + o0 - osorted[t, 0]
                    S1 = s1 + o1 - osorted[t, 1]
                    S2 = s2 + o2 - osorted[t, 2]
                    if j == i and not (S0 > 0 or (S0 == 0 and (S1 > 0 or (S1 == 0
                                                                           and S2 > 0)))):
                        continue
                    tx = S0 * cell[0, 0] + S1 * cell[1, 0] + S2 * cell[2, 0]
                    ty = S0 * cell[0, 1] + S1 * cell[1, 1] + S2 * cell[2, 1]
                    tz = S0 * cell[0, 2] + S1 * cell[1, 2] + S2 * cell[2, 2]
                    dx = (psorted[t, 0] - xi) + tx
                    dy = (psorted[t, 1] - yi) + ty
                    dz = (psorted[t, 2] - zi) + tz
                    if not dx * dx + dy * dy + dz * dz < cut2:
                        continue
                    key = ((S0 + hw[0]) * sp1 + (S1 + hw[1])) * sp2 + (S2 + hw[2])
                    if fill:
                        j_out[k0 + count] = j
                        if dense:
                            img_out[k0 + count] = lookup[key]
                        else:
                            s_out[k0 + count, 0] = S0
                            s_out[k0 + count, 1] = S1
                            s_out[k0 + count, 2] = S2
                    elif dense:
                        present[key] = True
                    count += 1
    return count


@nb.njit(cache=True, parallel=prange_only())
def _grid_count(pos, cell, bins, off, start, order, psorted, osorted, nbins, rb, periodic,
                cut2, hw, present, counts):
    """Pairs per row (into counts[1:]) and, per chunk of rows, the shift keys seen."""
    n = pos.shape[0]
    nchunks = present.shape[0]
    empty_j = np.zeros(0, dtype=np.int32)
    empty_img = np.zeros(0, dtype=np.int32)
    empty_s = np.zeros((0, 3), dtype=np.int64)
    for c in nb.prange(nchunks):
        for i in range(n * c // nchunks, n * (c + 1) // nchunks):
            counts[i + 1] = _grid_row(i, pos, cell, bins, off, start, order, psorted, osorted,
                                      nbins, rb, periodic, cut2, hw, False, 0, empty_j,
                                      empty_img, empty_s, empty_img, present[c])


@nb.njit(cache=True, parallel=prange_only())
def _grid_fill(pos, cell, bins, off, start, order, psorted, osorted, nbins, rb, periodic,
               cut2, hw, row, j_out, img_out, s_out, lookup):
    n = pos.shape[0]
    none = np.zeros(0, dtype=np.bool_)
    for i in nb.prange(n):
        _grid_row(i, pos, cell, bins, off, start, order, psorted, osorted, nbins, rb,
                  periodic, cut2, hw, True, row[i], j_out, img_out, s_out, lookup, none)


@nb.njit(cache=True, parallel=prange_only())
def _sort_pairs(row, j, img):
    """Sort each row by (neighbour, image index) in place: neighbours in memory
    order for the kernels' gathers; image indices follow the lexicographic
    order of the shifts, so rows are sorted by (j, S)."""
    n = len(row) - 1
    for a in nb.prange(n):
        lo = row[a]
        for x in range(lo + 1, row[a + 1]):
            kj = j[x]
            km = img[x]
            y = x - 1
            while y >= lo and (j[y] > kj or (j[y] == kj and img[y] > km)):
                j[y + 1] = j[y]
                img[y + 1] = img[y]
                y -= 1
            j[y + 1] = kj
            img[y + 1] = km


def _index_type(nimages):
    return np.int16 if nimages < 32768 else np.int32


def _grid_half(positions, cell, pbc, reach):
    """The half list (each pair once, in the row of its smaller index) within
    ``reach`` by the cell-list search: (row, j, image, integer shifts table);
    None where the grid cannot be laid (non-finite extent)."""
    plan = _grid_plan(positions, cell, pbc, reach)
    if plan is None:
        return None
    bins, off, nbins, rb, hw = plan
    n = len(positions)
    start, order = _bin_sort(bins, nbins)
    psorted = positions[order]
    osorted = off[order]
    periodic = np.asarray(pbc, dtype=np.bool_)
    cut2 = reach * reach
    sizes = 2 * hw + 1
    nkeys = int(np.prod(sizes.astype(float)))
    dense = nkeys <= _DENSE_KEYS
    nchunks = threads.chunks() if n >= 64 else 1
    present = np.zeros((nchunks, nkeys if dense else 0), dtype=np.bool_)
    row = np.zeros(n + 1, dtype=np.int64)
    _grid_count(positions, cell, bins, off, start, order, psorted, osorted, nbins, rb,
                periodic, cut2, hw, present, row)
    np.cumsum(row, out=row)
    npairs = int(row[-1])
    j = np.empty(npairs, dtype=np.int32)
    if dense:
        seen = present.any(axis=0)
        del present
        seen |= seen[::-1]  # key(−S) = nkeys − 1 − key(S): the table holds ±S
        keys = np.flatnonzero(seen)
        if len(keys) == 0:
            keys = np.array([nkeys // 2])  # the zero shift: a table is never empty
        ints = np.column_stack(np.unravel_index(keys, tuple(sizes))) - hw
        itype = _index_type(len(keys))
        lookup = np.zeros(nkeys, dtype=itype)
        lookup[keys] = np.arange(len(keys), dtype=itype)
        image = np.empty(npairs, dtype=itype)
        _grid_fill(positions, cell, bins, off, start, order, psorted, osorted, nbins, rb,
                   periodic, cut2, hw, row, j, image, np.zeros((0, 3), dtype=np.int64),
                   lookup)
    else:
        del present
        s = np.empty((npairs, 3), dtype=np.int64)
        _grid_fill(positions, cell, bins, off, start, order, psorted, osorted, nbins, rb,
                   periodic, cut2, hw, row, j, np.zeros(0, dtype=np.int32), s,
                   np.zeros(0, dtype=np.int32))
        ints, index = np.unique(np.concatenate([s, -s]), axis=0, return_inverse=True)
        image = index.reshape(-1)[:npairs].astype(_index_type(len(ints)))
    _sort_pairs(row, j, image)
    return row, j, image, ints.astype(np.int64)


def _half_from_full(i, j, s, n):
    """(row, j, image, shifts table) of the half list from a full list (i, j, S)."""
    first = (j > i) | ((j == i) & ((s[:, 0] > 0) | ((s[:, 0] == 0) & (
        (s[:, 1] > 0) | ((s[:, 1] == 0) & (s[:, 2] > 0))))))
    if len(s):
        ints, index = np.unique(s, axis=0, return_inverse=True)  # ±S: the list is full
    else:
        ints, index = np.zeros((1, 3), dtype=np.int64), np.zeros(0, dtype=np.int64)
    i, j, image = i[first], j[first].astype(np.int32), index.reshape(-1)[first]
    image = image.astype(_index_type(len(ints)))
    row = _rows(i, n)
    order = _bucket_by_row(i, row)
    j, image = j[order], image[order]
    _sort_pairs(row, j, image)
    return row, j, image, ints.astype(np.int64)


@nb.njit(cache=True)
def _expand(row, j, image, nimages):
    """The full list (each pair as i → j and j → i, rows sorted by (j, S)) of a
    half list; the image −S has index nimages − 1 − m (the table is symmetric
    and in lexicographic order)."""
    n = len(row) - 1
    full = np.zeros(n + 1, dtype=np.int64)
    for a in range(n):
        for k in range(row[a], row[a + 1]):
            full[a + 1] += 1
            full[j[k] + 1] += 1
    for a in range(n):
        full[a + 1] += full[a]
    fill = full[:-1].copy()
    fj = np.empty(full[n], dtype=j.dtype)
    fm = np.empty(full[n], dtype=image.dtype)
    for a in range(n):
        for k in range(row[a], row[a + 1]):
            b = j[k]
            fj[fill[a]] = b
            fm[fill[a]] = image[k]
            fill[a] += 1
            fj[fill[b]] = a
            fm[fill[b]] = nimages - 1 - image[k]
            fill[b] += 1
    return full, fj, fm


@nb.njit(cache=True, parallel=prange_only())
def _filter_count(positions, row, j, image, images, reach, mask, counts, nearest):
    """counts[a + 1]: row a's pairs closer than ``reach`` (both atoms in
    ``mask``, if given); nearest[a]: the distance of its closest pair left out
    (inf if none)."""
    n = len(row) - 1
    masked = mask.shape[0] > 0
    for a in nb.prange(n):
        c = 0
        near = np.inf
        if not masked or mask[a]:
            for k in range(row[a], row[a + 1]):
                b = j[k]
                if masked and not mask[b]:
                    continue
                r = np.sqrt(separation(positions, images, a, b, image[k])[3])
                if r < reach:
                    c += 1
                else:
                    near = min(near, r)
        counts[a + 1] = c
        nearest[a] = near


@nb.njit(cache=True, parallel=prange_only())
def _filter_fill(positions, row, j, image, images, reach, mask, sub, sj, simage):
    n = len(row) - 1
    masked = mask.shape[0] > 0
    for a in nb.prange(n):
        if masked and not mask[a]:
            continue
        c = sub[a]
        for k in range(row[a], row[a + 1]):
            b = j[k]
            if masked and not mask[b]:
                continue
            if np.sqrt(separation(positions, images, a, b, image[k])[3]) < reach:
                sj[c] = b
                simage[c] = image[k]
                c += 1


class NeighborCache:
    """A half Verlet list at ``max(cutoffs) + skin``, rebuilt only when needed,
    and the terms' sub-lists at ``cutoff + fine_skin``, filtered from it.

    The list is rebuilt when an atom has moved more than ``skin / 2`` since the
    last build, or when the cell, the periodicity or the number of atoms
    changed; ``builds`` counts the builds. The sub-lists are filtered from it at
    the positions of their last filtering, :attr:`fine_reference`, with reach
    ``cutoff + fine_skin`` (plus twice the distance of the positions passed as
    ``also`` to :meth:`update`, which must stay covered too), and filtered again
    when an atom has moved more than :attr:`fine_radius` from there — half the
    gap between a sub-list's cutoff and the closest pair it left out, at least
    ``fine_skin / 2`` (``refilters`` counts the filterings that dropped a
    sub-list). Why both are safe: a pair not in the list was farther apart than
    ``max(cutoffs) + skin`` at the build and is still beyond ``max(cutoffs)``;
    a pair in the list but not in a sub-list is still beyond its cutoff.

    Only the half list (each pair once, 6 bytes a pair) and the positions of the
    build and of the filtering are kept: sub-lists at shorter cutoffs, for
    magnetic atoms, or full (each pair both ways) are derived on demand,
    recomputing the distances at those positions rather than storing them. The
    half list at the largest cutoff for all atoms is the list itself, shared.
    """

    def __init__(self, cutoff, skin=0.3, fine_skin=None):
        if not cutoff > 0.0:
            raise ValueError(f"neighbour-list cutoff must be positive, got {cutoff}")
        if not skin >= 0.0:
            raise ValueError(f"skin must be >= 0, got {skin}")
        fine_skin = FINE_SKIN * skin if fine_skin is None else fine_skin
        if not 0.0 <= fine_skin <= skin:
            raise ValueError(f"fine_skin must be between 0 and the skin ({skin}), "
                             f"got {fine_skin}")
        self.cutoff = float(cutoff)
        self.skin = float(skin)
        self.fine_skin = float(fine_skin)
        self._reference = None
        self._fine_reference = None
        self._margin = 0.0  # what the sub-lists' reach adds for `also`
        self._radii = {}  # per filtered sub-list (key as _sublists): see fine_radius
        self._cell = None
        self._pbc = None
        self._sublists = {}
        self.builds = 0
        self.refilters = 0
        self.half = None

    @property
    def pairs(self):
        """The full list (i → j and j → i) within cutoff + skin, made on first use."""
        if self.half is None:
            return None
        return self.sublist(self.cutoff)

    def __setstate__(self, state):
        self.__dict__.update(state)
        if "_cell_key" not in state:  # pickled by an older version: rebuild
            self._reference = None

    def invalidate(self):
        self._reference = None

    @property
    def reference(self):
        """Positions of the last build (None before one): the list itself
        stays valid while no atom is farther than ``skin / 2`` from here."""
        return self._reference

    @property
    def fine_radius(self):
        """How far from :attr:`fine_reference` an atom may move with the
        sub-lists still valid: for each, half the gap between its cutoff and
        the closest pair it left out (at least ``fine_skin / 2``; unbounded if
        it left none out, as on a perfect lattice whose next shell lies beyond
        the list); with none, ``fine_skin / 2`` (where the filtering positions
        move on, so that a sub-list made later holds where the atoms are)."""
        return min(self._radii.values(), default=0.5 * self.fine_skin)

    @property
    def fine_reference(self):
        """Positions the sub-lists were filtered at: they stay valid while no
        atom is farther than :attr:`fine_radius` from here (and the list
        itself is valid)."""
        return self._fine_reference

    def update(self, positions, cell, pbc, also=None):
        """Make the lists valid for ``positions`` (and for the positions
        ``also``, if given: e.g. the start of a step whose end is
        ``positions``); return True if the list was rebuilt or a sub-list
        filtered again (what was prepared from them is stale)."""
        positions = np.ascontiguousarray(positions, dtype=float)
        cell = np.asarray(cell, dtype=float)
        pbc = np.asarray(pbc, dtype=bool)
        if (self._reference is None or positions.shape != self._reference.shape
                or cell.tobytes() != self._cell_key or pbc.tobytes() != self._pbc_key):
            return self._build(positions, cell, pbc, also)
        # NaN positions: no rebuild, as before (the integrators report them)
        moved_since_build, moved = largest_displacements(positions, self._reference,
                                                         self._fine_reference)
        if moved_since_build > 0.5 * self.skin:
            return self._build(positions, cell, pbc, also)
        if not moved > self.fine_radius:
            return False
        # filter the sub-lists again here (lazily: on their next request)
        dropped = bool(self._radii)
        for key in self._radii:
            del self._sublists[key]
        self._radii = {}
        self._fine_reference = positions.copy()
        self._margin = self._also_margin(positions, also)
        self.refilters += dropped
        return dropped

    @staticmethod
    def _also_margin(positions, also):
        if also is None:
            return 0.0
        also = np.ascontiguousarray(also, dtype=float)
        return 2.0 * largest_displacements(also, positions, positions)[0]

    def _build(self, positions, cell, pbc, also):
        cell, pbc = check_cell(cell, pbc)
        # the old list and its sub-lists go before the new one is built
        self.half = None
        self._sublists = {}
        self._radii = {}
        n = len(positions)
        if n:
            row, j, image, ints = self._search_half(positions, cell, pbc)
        else:
            row, j = np.zeros(1, dtype=np.int64), np.zeros(0, dtype=np.int32)
            image, ints = np.zeros(0, dtype=np.int16), np.zeros((1, 3), dtype=np.int64)
        images = np.ascontiguousarray(ints @ cell)
        self.half = PairList(row, j, image, images, self.cutoff, half=True)
        self._ints = ints
        self._reference = self._fine_reference = positions.copy()
        self._margin = self._also_margin(positions, also)
        self._cell = cell.copy()
        self._pbc = pbc.copy()
        self._cell_key = np.asarray(self._cell, dtype=float).tobytes()
        self._pbc_key = np.asarray(self._pbc, dtype=bool).tobytes()
        self.builds += 1
        return True

    def _search_half(self, positions, cell, pbc):
        """The half list within cutoff + skin as (row, j, image, shifts table)
        with d_ij = r_j + S·cell − r_i for the positions as given (unwrapped):
        a cell list (:func:`_grid_half`); boxes whose extent is not finite go
        to a sweep over atoms sorted along x."""
        reach = self.cutoff + self.skin
        periodic = np.flatnonzero(pbc)
        if periodic.size:
            faces = _face_distances(cell, pbc)[periodic]
            images = float(np.prod(2.0 * np.ceil(reach / faces) + 1.0))
            if images > MAX_IMAGES:
                raise ValueError(
                    f"the cell is too small along its periodic directions for the cutoff "
                    f"{reach:.3g} Å (distances between faces {faces.round(6).tolist()} Å): "
                    f"each atom would see ~{images:.3g} periodic images of every other atom")
        found = _grid_half(positions, cell, pbc, reach)
        if found is not None:
            return found
        wrapped, shift = _wrap(positions, cell, pbc)
        i, j, s = _sweep_pairs(wrapped, cell, pbc, reach)
        if shift.any():
            s = s + shift[i] - shift[j]
        return _half_from_full(i, j, s, len(positions))

    def _search(self, positions, cell, pbc):
        """All pairs within cutoff + skin as (i, j, integer shifts S), both ways,
        with d_ij = r_j + S·cell − r_i for the positions as given."""
        cell, pbc = check_cell(cell, pbc)
        row, j, image, ints = self._search_half(np.ascontiguousarray(positions, dtype=float),
                                                cell, pbc)
        row, j, image = _expand(row, j, image, len(ints))
        i = np.repeat(np.arange(len(row) - 1), np.diff(row))
        return i, j.astype(np.int64), ints[image]

    def sublist(self, cutoff, mask=None, half=False):
        """Pairs within ``cutoff + fine_skin`` at :attr:`reference`, between
        atoms where ``mask`` is True (all atoms if None); with ``half``, each
        unordered pair once (row of the smaller index). Cached until the next
        rebuild or filtering (:meth:`update`). At the largest cutoff for all
        atoms: the list itself (its reach, cutoff + skin), or its full form."""
        if mask is not None and mask.all():
            mask = None  # every atom: the same list as without a mask
        key = (float(cutoff), None if mask is None else mask.tobytes(), half)
        cached = self._sublists.get(key)
        if cached is not None:
            return cached
        master = self.half
        radius = None
        if cutoff >= self.cutoff and mask is None:
            row, j, image = master.row, master.j, master.image
        else:
            n = len(master.row) - 1
            row = np.zeros(n + 1, dtype=np.int64)
            m = np.zeros(0, dtype=np.bool_) if mask is None else np.ascontiguousarray(
                mask, dtype=np.bool_)
            reach = cutoff + self.fine_skin + self._margin
            nearest = np.empty(n)
            _filter_count(self._fine_reference, master.row, master.j, master.image,
                          master.images, reach, m, row, nearest)
            # it holds until a pair left out can come within the cutoff
            # (nothing left out: as long as the list itself)
            radius = 0.5 * (nearest.min(initial=np.inf) - cutoff)
            np.cumsum(row, out=row)
            j = np.empty(row[-1], dtype=master.j.dtype)
            image = np.empty(row[-1], dtype=master.image.dtype)
            _filter_fill(self._fine_reference, master.row, master.j, master.image,
                         master.images, reach, m, row, j, image)
        if half and j is master.j:
            sub = master  # shared, not copied: the list itself
        elif half:
            sub = PairList(row, j, image, master.images, float(cutoff), True)
        else:
            row, j, image = _expand(row, j, image, len(master.images))
            sub = PairList(row, j, image, master.images, float(cutoff), False)
        self._sublists[key] = sub
        if radius is not None:
            self._radii[key] = radius
        return sub
