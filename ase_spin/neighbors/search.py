"""The compiled pair search: a half pair list (each pair once, in the row of
its smaller index) within a reach, by a cell list; a sweep over atoms sorted
along x for boxes the grid cannot cover; and what is derived from a half list
(its full form, the sub-lists filtered from it at a shorter reach).

Pairs are searched on a grid of bins in coordinates u = r·A⁻¹ along a basis A
whose rows are the periodic cell vectors and, along open directions, unit
vectors orthogonal to them. A pair at distance |d| has |Δu_k| ≤ |d|·|b_k|
(b_k the k-th column of A⁻¹, |b_k| = 1/face distance), so the bins within R_k
of an atom's own hold all of its neighbours, whatever the cell's shape. The
list is written once, each pair in the row of its smaller index, in two passes
(count, fill): memory is the list itself (6 bytes a pair) plus a few arrays
per atom, never a pair list of int64 indices and shifts.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from .._jit import threads
from .._jit.cloning import prange_only
from .checks import face_distances, separation
from .pairs import group_by_key

__all__ = ["wrap_positions", "sweep_pairs", "grid_half", "half_from_full", "full_from_half",
           "filter_count", "filter_fill"]


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


#: Atoms farther than this many cells outside a periodic cell are refused: their
#: coordinates (≳ 1e9 Å) resolve distances no better than ~1e-6 Å.
_MAX_CELLS_AWAY = 2.0**31


def wrap_positions(positions, cell, pbc):
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


def sweep_pairs(positions, cell, pbc, cutoff):
    """Full pair list (i, j, integer shifts) for boxes the cell list cannot grid
    (an extent that is not finite); the reference the tests hold it to."""
    periodic = np.flatnonzero(pbc)
    reach = np.zeros(3, dtype=np.int64)
    if periodic.size:
        faces = face_distances(cell, pbc)
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


# -- the cell-list search (see the module docstring) ---------------------------

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


@nb.njit(cache=True, inline="always")
def _bin_along(c, n, periodic):
    """Bin c of a row of n along one axis: (the bin in the cell, the cell
    images it lies over, whether it exists — outside an open axis it does not)."""
    if periodic:
        shift = c // n
        return c - shift * n, shift, True
    return c, 0, 0 <= c < n


@nb.njit(cache=True)
def _grid_row(i, pos, cell, bins, off, start, order, psorted, osorted, nbins, rb, periodic,
              cut2, hw, fill, k0, j_out, img_out, s_out, lookup, present):
    """Visit atom i's neighbours j ≥ i (j = i: images with a lexicographically
    positive shift) within sqrt(cut2): count them, mark their shifts' keys in
    ``present`` (when not ``fill``), or write them from k0 on (j, and the image
    index ``lookup[key]``, or the shift itself when ``lookup`` is empty). One
    compiled function that both passes call (not inlined into each: compiled
    once, and a call per atom costs nothing beside its scan of the bins)."""
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
            counts[i + 1] = _grid_row(np.int64(i), pos, cell, bins, off, start, order, psorted,
                                      osorted, nbins, rb, periodic, cut2, hw, np.bool_(False),
                                      np.int64(0), empty_j, empty_img, empty_s, empty_img,
                                      present[c])


@nb.njit(cache=True, parallel=prange_only())
def _grid_fill(pos, cell, bins, off, start, order, psorted, osorted, nbins, rb, periodic,
               cut2, hw, row, j_out, img_out, s_out, lookup):
    n = pos.shape[0]
    none = np.zeros(0, dtype=np.bool_)
    for i in nb.prange(n):
        _grid_row(np.int64(i), pos, cell, bins, off, start, order, psorted, osorted, nbins, rb,
                  periodic, cut2, hw, np.bool_(True), np.int64(row[i]), j_out, img_out, s_out,
                  lookup, none)


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


def grid_half(positions, cell, pbc, reach):
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


def half_from_full(i, j, s, n):
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
def full_from_half(row, j, image, nimages):
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
def filter_count(positions, row, j, image, images, reach, mask, counts, nearest):
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
def filter_fill(positions, row, j, image, images, reach, mask, sub, sj, simage):
    """The pairs :func:`filter_count` counted, row a's from ``sub[a]`` on:
    partners into ``sj``, image indices into ``simage``."""
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

