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
    """d_ij = (r_j − r_i) + S_m and |d_ij|² for pair (i, j) with image shift m.

    In this order of operations d_ji = −d_ij bitwise (negation is exact), so a
    pair at the cutoff is inside or outside for both of its atoms alike."""
    dx = (pos[j, 0] - pos[i, 0]) + images[m, 0]
    dy = (pos[j, 1] - pos[i, 1]) + images[m, 1]
    dz = (pos[j, 2] - pos[i, 2]) + images[m, 2]
    return dx, dy, dz, dx * dx + dy * dy + dz * dz


@nb.njit(cache=True, parallel=True)
def _pair_distances(positions, row, j, image, images, out):
    n = len(row) - 1
    for a in nb.prange(n):
        for k in range(row[a], row[a + 1]):
            out[k] = np.sqrt(separation(positions, images, a, j[k], image[k])[3])


def _image_table(s, cell):
    """Distinct integer image shifts as a Cartesian table plus each pair's index
    into it (a counting pass: np.unique over rows would sort every pair; it is
    used only when the shifts span a range too wide to count, as for atoms far
    outside a periodic cell)."""
    if len(s) == 0:
        return np.zeros((1, 3)), np.zeros(0, dtype=np.int16)
    lo = s.min(axis=0)
    span = s.max(axis=0) - lo + 1
    if float(np.prod(span.astype(float))) <= 8.0 * len(s) + 4096:
        key = ((s[:, 0] - lo[0]) * span[1] + (s[:, 1] - lo[1])) * span[2] + (s[:, 2] - lo[2])
        present = np.flatnonzero(np.bincount(key, minlength=int(np.prod(span))))
        lookup = np.zeros(int(np.prod(span)), dtype=np.int64)
        lookup[present] = np.arange(len(present))
        distinct = np.column_stack(np.unravel_index(present, tuple(span))) + lo
        index = lookup[key]
    else:
        distinct, index = np.unique(s, axis=0, return_inverse=True)
        index = index.reshape(-1)
    index_type = np.int16 if len(distinct) < 32768 else np.int32
    return np.ascontiguousarray(distinct @ cell), index.astype(index_type)


def check_cell(cell, pbc):
    """The cell as a float64 (3, 3) array and pbc as three bools, checked: finite,
    and along periodic directions non-zero, independent vectors (a periodic
    direction needs a period). Non-periodic directions may have zero vectors."""
    from .validate import real_array

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

# vesin's cell list (cpu_cell_list.cpp) caps its cells at 1e5 by a formula that
# gives zero cells along a direction for very elongated boxes: it then divides by
# zero (SIGFPE). Such boxes are searched by _sweep_pairs instead.
_VESIN_MAX_CELLS = 1e5


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
    # vesin itself places atoms a cell or two outside (without this copy and the
    # shift correction of every pair); only atoms farther out are moved here
    shift[np.abs(shift) <= 2.0] = 0.0
    if not shift.any():
        return positions, n
    n[:, periodic] = shift.astype(np.int64)
    return positions - n[:, periodic] @ cell[periodic], n


def _vesin_can(positions, cell, pbc, cutoff):
    """Whether vesin's cell list will have at least one cell along every
    direction (its own formula, see _VESIN_MAX_CELLS)."""
    d = np.empty(3)
    faces = _face_distances(cell, pbc) if pbc.any() else None
    for k in range(3):
        if pbc[k]:
            d[k] = faces[k]
        else:
            lo, hi = (positions[:, k].min(), positions[:, k].max()) if len(positions) else (0, 0)
            span = hi - lo if hi - lo >= 1e-6 else 1.0
            d[k] = max(1.0, span * 1.01)
    if not np.isfinite(d).all():
        return False
    n = np.maximum(np.trunc(d / cutoff), 1.0)
    if n.prod() > _VESIN_MAX_CELLS:
        rxy, ryz = n[0] / n[1], n[1] / n[2]
        n2 = np.trunc(np.cbrt(_VESIN_MAX_CELLS / (rxy * ryz * ryz)))
        n1 = np.trunc(ryz * n2)
        n0 = np.trunc(rxy * n1)
        n = np.array([n0, n1, n2])
    return bool((n >= 1).all() and (n < 2**31).all())


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
    """Full pair list (i, j, integer shifts) for boxes vesin cannot grid."""
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
        self._vesin = self._new_vesin()
        self._reference = None
        self._cell = None
        self._pbc = None
        self._sublists = {}
        self.builds = 0
        self.pairs = None

    def _new_vesin(self):
        return vesin.NeighborList(
            cutoff=self.cutoff + self.skin, full_list=True, sorted=False, n_threads=1
        )

    def __getstate__(self):
        # vesin's handle holds ctypes pointers: not copied, made anew
        state = dict(self.__dict__)
        del state["_vesin"]
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._vesin = self._new_vesin()

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
        cell, pbc = check_cell(cell, pbc)
        n = len(positions)
        if n:
            i, j, s = self._search(positions, cell, pbc)
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

    def _search(self, positions, cell, pbc):
        """All pairs within cutoff + skin as (i, j, integer shifts S) with
        d_ij = r_j + S·cell − r_i for the positions as given (unwrapped).

        vesin searches positions wrapped into the cell (atoms any number of
        cells away cost nothing extra); boxes too elongated for its cell list
        (open directions with atoms far apart, a periodic vector of 1e8 Å) go
        to a sweep over atoms sorted along x instead."""
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
        wrapped, shift = _wrap(positions, cell, pbc)
        if _vesin_can(wrapped, cell, pbc, reach):
            i, j, s = self._vesin.compute(wrapped, cell, pbc, "ijS", copy=False)
            i = i.astype(np.int64)
            j = j.astype(np.int64)
            s = np.asarray(s, dtype=np.int64)
        else:
            i, j, s = _sweep_pairs(wrapped, cell, pbc, reach)
        if shift.any():
            s = s + shift[i] - shift[j]
        return i, j, s

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
