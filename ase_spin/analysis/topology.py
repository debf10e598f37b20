r"""The topological charge of a 2D spin texture on any layer of atoms
(Berg and Lüscher's lattice definition).

The layer's positions, projected on the plane normal to ``normal``, are
triangulated (Delaunay; with the in-plane periodic images when the layer is
periodic, each triangle of the periodic triangulation kept once). Each
triangle (a, b, c), counter-clockwise seen from +normal, carries the signed
solid angle of its three spins,

.. math:: \Omega_{abc} = 2\,\mathrm{atan2}\big(\mathbf s_a\cdot(\mathbf s_b\times\mathbf s_c),\;
          1 + \mathbf s_a\cdot\mathbf s_b + \mathbf s_b\cdot\mathbf s_c
          + \mathbf s_c\cdot\mathbf s_a\big) \in (-2\pi, 2\pi),

and Q = Σ Ω/(4π). On a periodic layer Q is an integer for any spins (the
triangles tile a closed surface; exact up to round-off, unless three spins
of a triangle span exactly a hemisphere's boundary), ±1 for one skyrmion
(sign: the core direction and the normal; Q = −1 for a core along −normal in
a background along +normal), 0 for a uniform state; it changes only when
the spins of some triangle pass through such a degenerate configuration,
which is what makes it a topological invariant of smooth dynamics.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import Delaunay

from ..spins import get_spins
from ..validate import real_array, unit_vector

__all__ = ["LayerTriangulation", "topological_charge", "solid_angles"]


def solid_angles(sa, sb, sc):
    """Signed solid angles Ω (sr) of spin triples (arrays (..., 3); formula in
    the module docstring)."""
    num = np.einsum("...k,...k->...", sa, np.cross(sb, sc))
    den = (1.0 + np.einsum("...k,...k->...", sa, sb) + np.einsum("...k,...k->...", sb, sc)
           + np.einsum("...k,...k->...", sc, sa))
    return 2.0 * np.arctan2(num, den)


class LayerTriangulation:
    """The triangles of one layer of ``atoms`` (all atoms, or ``indices``),
    made once for its positions: ``triangles`` (m, 3) atom indices,
    counter-clockwise about ``normal``.

    ``normal``: the layer's normal (default: a × b of the cell, the normal
    of a layer built by ase.build in the ab plane). The periodic cell vectors
    lying in the plane (|v̂·n̂| < 10⁻⁶) make the layer periodic along them
    (0, 1 or 2 of them); others are ignored (a layer in a 3D-periodic cell
    with vacuum along c)."""

    def __init__(self, atoms, indices=None, normal=None):
        n_atoms = len(atoms)
        if indices is None:
            indices = np.arange(n_atoms)
        indices = np.asarray(indices)
        if indices.dtype == bool:
            indices = np.flatnonzero(indices)
        if indices.ndim != 1 or indices.dtype.kind not in "iu" or len(indices) < 3:
            raise ValueError("indices must select at least 3 atoms of the layer")
        if np.any((indices < 0) | (indices >= n_atoms)) or len(np.unique(indices)) != len(indices):
            raise ValueError(f"indices must be distinct atom indices below {n_atoms}")
        cell = atoms.cell.array
        if normal is None:
            normal = np.cross(cell[0], cell[1])
            if not np.linalg.norm(normal) > 0:
                raise ValueError("the cell has no a × b to take as the layer normal: "
                                 "give normal=")
        n = unit_vector(normal, "normal")
        # in-plane orthonormal basis (e1, e2) with e1 × e2 = n
        axis = np.eye(3)[np.argmin(np.abs(n))]
        e1 = axis - (axis @ n) * n
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(n, e1)
        basis = np.array([e1, e2]).T
        pos = real_array(atoms.positions, "positions")[indices]
        xy = pos @ basis
        periodic = [cell[k] for k in range(3) if atoms.pbc[k] and np.linalg.norm(cell[k]) > 0
                    and abs(cell[k] @ n) < 1e-6 * np.linalg.norm(cell[k])]
        if len(periodic) > 2:
            raise ValueError("more than two periodic cell vectors lie in the layer's plane")
        vectors = np.array([v @ basis for v in periodic]).reshape(-1, 2)
        m = len(xy)
        shifts = np.array(np.meshgrid(*[[-1, 0, 1]] * len(vectors), indexing="ij")
                          ).reshape(len(vectors), -1).T if len(vectors) else np.zeros((1, 0))
        images = np.concatenate([xy + s @ vectors for s in shifts])
        source = np.tile(np.arange(m), len(shifts))
        tri = Delaunay(images).simplices
        if len(vectors):
            # keep each periodic triangle once: the image whose centroid is
            # in the home cell (fractional coordinates along the periodic
            # vectors in [0, 1) from the home atoms' smallest ones: a cell
            # with a whole layer of images around it, away from the hull)
            def fractional(points):
                return np.linalg.lstsq(vectors.T, points.T, rcond=None)[0].T

            origin = fractional(xy).min(axis=0) - 1e-9
            frac = fractional(images[tri].mean(axis=1)) - origin
            home = np.all((frac >= 0.0) & (frac < 1.0), axis=1)
            tri = tri[home]
        a, b, c = (images[tri[:, k]] for k in range(3))
        area = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
        tri = np.where((area < 0)[:, None], tri[:, [0, 2, 1]], tri)
        if len(vectors) == 2:
            total = abs(np.linalg.det(vectors))
            if not np.isclose(0.5 * np.abs(area).sum(), total, rtol=1e-6):
                raise ValueError("the layer's triangulation does not tile its periodic cell "
                                 "(atoms of several layers, or on top of each other?): "
                                 "select one layer with indices=")
        if len(np.unique(source[tri])) != m:
            raise ValueError("some atoms of the layer are in no triangle (atoms of several "
                             "layers on top of each other, or on a line?): select one layer "
                             "with indices=")
        self.triangles = indices[source[tri]]
        self.normal = n

    def charge_density(self, spins):
        """Ω/(4π) of every triangle for unit ``spins`` (N, 3) of all atoms."""
        s = np.asarray(spins, dtype=float)
        t = self.triangles
        return solid_angles(s[t[:, 0]], s[t[:, 1]], s[t[:, 2]]) / (4.0 * np.pi)

    def charge(self, spins):
        """Q = Σ Ω/(4π) for unit ``spins`` (N, 3) of all atoms."""
        return float(self.charge_density(spins).sum())


def topological_charge(atoms, spins=None, indices=None, normal=None):
    """Q of the spins of ``atoms`` (default: their own, ``get_spins``) on the
    layer ``indices`` (default all atoms) about ``normal`` (default a × b):
    :class:`LayerTriangulation` made for this call (make one and call its
    :meth:`~LayerTriangulation.charge` to evaluate many spin states)."""
    if spins is None:
        spins = get_spins(atoms)
    return LayerTriangulation(atoms, indices, normal).charge(spins)
