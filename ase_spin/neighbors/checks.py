"""Checks of positions and cells, and the one pair separation every kernel
forms: largest displacements (is a list still valid?), finiteness, a cell's
validity, the distances between its faces, and d_ij from a pair's image shift.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from ..validate import real_array

__all__ = ["max_displacement", "largest_displacements", "all_finite", "separation",
           "check_cell", "MAX_IMAGES", "face_distances", "closest_pair"]


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
    without the atom, its maxima taken without branches (cheaper per
    reference: it runs at every step)."""
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


@nb.njit(cache=True, inline="always")
def separation(pos, images, i, j, m):
    """d_ij = (r_j − r_i) + S_m and |d_ij|² for pair (i, j) with image shift m.

    In this order of operations d_ji = −d_ij bitwise (negation is exact), so a
    pair at the cutoff is inside or outside for both of its atoms alike."""
    dx = (pos[j, 0] - pos[i, 0]) + images[m, 0]
    dy = (pos[j, 1] - pos[i, 1]) + images[m, 1]
    dz = (pos[j, 2] - pos[i, 2]) + images[m, 2]
    return dx, dy, dz, dx * dx + dy * dy + dz * dz


@nb.njit(cache=True)
def closest_pair(pos, row, j, image, images, below):
    """(i, j, r) of the closest pair of a half list in compressed-row form
    (-1, -1, inf without pairs), and how many pairs are closer than ``below``:
    one pass over the pairs, no search."""
    best = np.inf
    bi = bj = -1
    count = 0
    below2 = below * below
    for i in range(len(row) - 1):
        for k in range(row[i], row[i + 1]):
            _, _, _, d2 = separation(pos, images, i, j[k], image[k])
            if d2 < below2:
                count += 1
            if d2 < best:
                best = d2
                bi = i
                bj = j[k]
    return bi, bj, np.sqrt(best), count


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


def face_distances(cell, pbc):
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

