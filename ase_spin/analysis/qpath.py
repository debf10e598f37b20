"""Wave vectors for spectra and spin waves: paths through the high-symmetry points
of a crystal (ASE's band paths), optionally only the q a periodic supercell can
hold.

Wave vectors q are Cartesian, in 1/Å, **with** the factor 2π: the phase of atom i
is q·r_i (ASE's band paths give k in units of the reciprocal cell without 2π;
q = 2π k here). A supercell with lattice vectors L_k (periodic directions) holds
the waves exp(iq·r) whose phase is the same in every periodic image, q·L_k ∈ 2πℤ:
only those q are resolved by a run in that cell (the others are not Bloch waves
of it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from ase.cell import Cell
from ase.dft.kpoints import BandPath, parse_path_string

from ..validate import integer, real_array

__all__ = ["QPath", "q_path"]

#: how far q·L_k/2π may be from an integer for q to count as held by a supercell
_COMMENSURATE_TOL = 1e-6


@dataclass(frozen=True)
class QPath:
    """Wave vectors along a path.

    ``q``: (M, 3) Cartesian wave vectors, 1/Å, with 2π (phase q·r).
    ``x``: (M,) the distance along the path (1/Å, with 2π), the abscissa of
    band plots; it does not advance across a break of the path (as ASE's
    ``get_linear_kpoint_axis``). ``special``: ((x, label), ...) the
    high-symmetry points passed (labels as ASE's, "G" for Γ; "H|P" at a
    break).
    """

    q: np.ndarray
    x: np.ndarray
    special: tuple = ()

    def __len__(self):
        return len(self.q)

    @classmethod
    def from_q(cls, q):
        """Any list of wave vectors (M, 3) (Cartesian, 1/Å, with 2π); ``x`` is
        the distance along them in order."""
        q = real_array(q, "q (wave vectors)")
        if q.ndim == 1 and q.shape == (3,):
            q = q[None, :]
        if q.ndim != 2 or q.shape[1] != 3 or len(q) == 0:
            raise ValueError(f"q must be an (M, 3) array of wave vectors with M >= 1, "
                             f"got shape {q.shape}")
        if not np.isfinite(q).all():
            raise ValueError("q must be finite")
        x = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(q, axis=0), axis=1))])
        return cls(q, x, ())

    def labels(self):
        """(positions, labels) of the special points for a plot's x axis, Γ for G."""
        xs = [x for x, _ in self.special]
        names = ["Γ" if s == "G" else s.replace("G", "Γ") for _, s in self.special]
        return xs, names


def as_qpath(q):
    """A :class:`QPath` from a QPath, an ASE ``BandPath`` or an (M, 3) array."""
    if isinstance(q, QPath):
        return q
    if isinstance(q, BandPath):
        return _from_bandpath(q)
    return QPath.from_q(q)


def _from_bandpath(path):
    # ASE's linear axis is already in 1/Å with 2π; its Cartesian k are without
    x, X, labels = path.get_linear_kpoint_axis()
    q = 2.0 * np.pi * path.cartesian_kpts()
    return QPath(q, np.asarray(x, dtype=float), _merged(np.asarray(X, dtype=float), labels))


def _merged(xs, labels):
    """Special points with labels at the same x (a break) joined as "A|B"."""
    out = []
    for x, label in zip(xs, labels):
        if out and abs(out[-1][0] - x) < 1e-12:
            out[-1] = (out[-1][0], f"{out[-1][1]}|{label}")
        else:
            out.append((float(x), label))
    return tuple(out)


def q_path(crystal, path=None, npoints=60, supercell=None, special_points=None):
    """Wave vectors along a path through the high-symmetry points of a crystal.

    ``crystal``: Atoms or a cell: the crystal's own cell (primitive or
    conventional, as ASE's ``cell.bandpath`` takes it), not a supercell of a
    run. ``path``: ASE's path string ("GHNGPH,PN"; default: ASE's for the
    lattice). ``special_points``: names → scaled coordinates, for a path
    through points of your own.

    Without ``supercell``: ``npoints`` points spread along the path (as
    ``cell.bandpath(path, npoints)``), for spin-wave bands. With
    ``supercell`` (the Atoms or cell of a periodic run): exactly the q on the
    path's segments that the supercell holds, q·L_k ∈ 2πℤ for its lattice
    vectors L_k (and ``npoints`` is not used): the q a run's S(q, ω) resolves.
    """
    cell = Cell.ascell(getattr(crystal, "cell", crystal))
    if cell.rank != 3:
        raise ValueError("q_path needs the crystal's cell with three lattice vectors")
    npoints = integer(npoints, "npoints", minimum=2)
    pbc = getattr(crystal, "pbc", True)
    band = cell.bandpath(path, npoints=0 if supercell is not None else npoints,
                         special_points=special_points, pbc=pbc)
    if supercell is None:
        return _from_bandpath(band)
    super_atoms = supercell
    lattice = np.asarray(getattr(super_atoms, "cell", super_atoms), dtype=float).reshape(3, 3)
    periodic = np.array(getattr(super_atoms, "pbc", [True] * 3), dtype=bool).reshape(-1)
    if periodic.size == 1:
        periodic = np.repeat(periodic, 3)
    lattice = lattice[periodic]
    icell = band.icell
    qs, xs, special = [], [], []
    x0 = 0.0
    for sub in parse_path_string(band.path):
        corners = [np.asarray(band.special_points[name]) @ icell for name in sub]
        special.append((x0, sub[0]))
        for k in range(len(sub) - 1):
            a, b = corners[k], corners[k + 1]
            length = 2.0 * np.pi * np.linalg.norm(b - a)
            for t in _held(lattice @ a, lattice @ (b - a)):
                q = 2.0 * np.pi * (a + t * (b - a))
                if k > 0 and qs and np.allclose(q, qs[-1], rtol=0.0, atol=1e-9):
                    continue  # the corner ended the previous segment
                qs.append(q)
                xs.append(x0 + t * length)
            x0 += length
            special.append((x0, sub[k + 1]))
    if not qs:
        raise ValueError(f"no wave vector on the path {band.path!r} is held by the supercell "
                         f"(q·L ∈ 2πℤ): is the supercell a repeat of the crystal's cell?")
    xs_special, names = zip(*special)
    return QPath(np.array(qs), np.array(xs), _merged(np.array(xs_special), names))


def _held(start, step):
    """The t in [0, 1] with start + t·step integer in every component (sorted):
    where a straight segment of the path meets the supercell's reciprocal
    lattice, in the supercell's scaled coordinates."""
    start, step = np.asarray(start, float), np.asarray(step, float)
    k = int(np.argmax(np.abs(step))) if len(step) else 0
    if len(step) == 0 or abs(step[k]) < _COMMENSURATE_TOL:
        whole = np.all(np.abs(start - np.round(start)) < _COMMENSURATE_TOL)
        return [0.0, 1.0] if whole else []
    lo, hi = sorted((start[k], start[k] + step[k]))
    found = []
    for n in range(int(np.ceil(lo - _COMMENSURATE_TOL)), int(np.floor(hi + _COMMENSURATE_TOL)) + 1):
        t = (n - start[k]) / step[k]
        y = start + t * step
        if np.all(np.abs(y - np.round(y)) < _COMMENSURATE_TOL):
            found.append(min(max(t, 0.0), 1.0))
    return sorted(found)
