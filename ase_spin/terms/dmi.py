"""The Dzyaloshinskii–Moriya interaction (LAMMPS ``pair_style spin/dmi``)."""

from __future__ import annotations

import numba as nb
import numpy as np

from .._jit.threads import threaded
from ..neighbors import separation
from ..validate import MAX_COUPLING, length, real_scalar, unit_vector, warn_implausible
from .base import PairSpinTerm
from .lammps_form import LammpsPair, number_text, vector_text
from .parameters import is_pair_mapping, pair_values, resolve_pairs

__all__ = ["DMI"]


@nb.njit(cache=True, inline="always")
def _field(k, a, b, s, data, reverse):
    """Field on spin a from spin b: s_b × u with u = e_ab × D (u_ji = −u_ij)."""
    U = data[0]
    ux = U[k, 0]
    uy = U[k, 1]
    uz = U[k, 2]
    if reverse:
        ux = -ux
        uy = -uy
        uz = -uz
    return (s[b, 1] * uz - s[b, 2] * uy, s[b, 2] * ux - s[b, 0] * uz,
            s[b, 0] * uy - s[b, 1] * ux)


@nb.njit(cache=True, inline="always")
def _energy(k, i, j, s, data):
    """e = −(e_ij × D)·(s_i × s_j) = −e_ij·c with c = D × (s_i × s_j); the
    force on j, f = −∂e/∂r_j = (c − (c·e_ij) e_ij)/r_ij; d_ij."""
    U, E, R, types, Dtab = data
    r = R[k]
    if r == 0.0:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    ti = types[i]
    tj = types[j]
    Dx = Dtab[ti, tj, 0]
    Dy = Dtab[ti, tj, 1]
    Dz = Dtab[ti, tj, 2]
    # w = s_i × s_j, c = D × w
    wx = s[i, 1] * s[j, 2] - s[i, 2] * s[j, 1]
    wy = s[i, 2] * s[j, 0] - s[i, 0] * s[j, 2]
    wz = s[i, 0] * s[j, 1] - s[i, 1] * s[j, 0]
    cx = Dy * wz - Dz * wy
    cy = Dz * wx - Dx * wz
    cz = Dx * wy - Dy * wx
    ex = E[k, 0]
    ey = E[k, 1]
    ez = E[k, 2]
    ce = cx * ex + cy * ey + cz * ez
    inv = 1.0 / r
    return (-ce, (cx - ce * ex) * inv, (cy - ce * ey) * inv, (cz - ce * ez) * inv,
            ex * r, ey * r, ez * r)


@nb.njit(cache=True, inline="always")
def _site(i, s, data):
    """B_i = Σ_j s_j × u_ij from the spins as they are (full pair list)."""
    row, nbr, U = data[0], data[1], data[2]
    bx = 0.0
    by = 0.0
    bz = 0.0
    for k in range(row[i], row[i + 1]):
        j = nbr[k]
        bx += s[j, 1] * U[k, 2] - s[j, 2] * U[k, 1]
        by += s[j, 2] * U[k, 0] - s[j, 0] * U[k, 2]
        bz += s[j, 0] * U[k, 1] - s[j, 1] * U[k, 0]
    return bx, by, bz


@threaded(always=True)
def _geometry(pos, row, nbr, image, images, types, rc2, Dtab, U, E, R, other, Ubar):
    """For every pair k = (i → j) within rc: e_k = d_ij/r_ij, R_k = r_ij,
    U_k = e_k × D_ij; zero beyond. With ``other`` given, Ubar_k = ½(other_k + U_k)."""
    n = len(row) - 1
    want_mean = other.shape[0] > 0
    for i in nb.prange(n):
        ti = types[i]
        for k in range(row[i], row[i + 1]):
            j = nbr[k]
            tj = types[j]
            dx, dy, dz, r2 = separation(pos, images, i, j, image[k])
            if r2 >= rc2[ti, tj] or r2 == 0.0:
                ux = uy = uz = ex = ey = ez = r = 0.0
            else:
                r = np.sqrt(r2)
                ex = dx / r
                ey = dy / r
                ez = dz / r
                Dx = Dtab[ti, tj, 0]
                Dy = Dtab[ti, tj, 1]
                Dz = Dtab[ti, tj, 2]
                ux = ey * Dz - ez * Dy
                uy = ez * Dx - ex * Dz
                uz = ex * Dy - ey * Dx
            U[k, 0] = ux
            U[k, 1] = uy
            U[k, 2] = uz
            E[k, 0] = ex
            E[k, 1] = ey
            E[k, 2] = ez
            R[k] = r
            if want_mean:
                for c in range(3):
                    Ubar[k, c] = 0.5 * (other[k, c] + U[k, c])


_NO_U = np.zeros((0, 3))


def _pair_table(value, symbols, what):
    """A per-pair parameter as an (ntypes, ntypes) object table (None: off)."""
    if is_pair_mapping(value):
        return resolve_pairs(value, symbols, what)
    table = np.empty((len(symbols), len(symbols)), dtype=object)
    for index in np.ndindex(table.shape):
        table[index] = value
    return table


class DMI(PairSpinTerm):
    r"""The Dzyaloshinskii–Moriya interaction in LAMMPS's form (``pair_style
    spin/dmi``, after Rohart and Thiaville):

    .. math::

        E = -\sum_{i<j} (\mathbf e_{ij}\times\mathbf D)\cdot(\mathbf s_i\times\mathbf s_j),
        \qquad \mathbf e_{ij} = \frac{\mathbf r_j - \mathbf r_i}{r_{ij}},
        \quad r_{ij} < r_c,

    .. math::

        \mathbf B_i = \sum_j \mathbf s_j \times (\mathbf e_{ij}\times\mathbf D),
        \qquad
        \mathbf F_j = -\frac{\partial E}{\partial \mathbf r_j}
        = \frac{\mathbf c - (\mathbf c\cdot\mathbf e_{ij})\mathbf e_{ij}}{r_{ij}},
        \quad \mathbf c = \mathbf D\times(\mathbf s_i\times\mathbf s_j),

    each pair once; the DM vector of a bond, **D**_ij = **e**_ij × **D**, lies
    perpendicular to it: with **D** along the normal of a film this is the
    interfacial DMI that stabilises Néel skyrmions. ``D`` (eV) is its
    strength and ``direction`` (normalised here) the vector **D**/D; both may
    be mappings keyed by pairs of chemical symbols. ``rc`` (Å) cuts it off.

    LAMMPS's ``pair_coeff * * dmi rc D dx dy dz`` divides (dx, dy, dz) by its
    squared length: give it a unit direction. Energy and magnetic forces match
    LAMMPS; its mechanical forces do not (they are not −∂E/∂r: see
    docs/terms.md), so ours are the derivative of this energy.
    """

    name = "dmi"
    pair_field, pair_energy, pair_site = _field, _energy, _site

    _parameters = {"D": "D", "direction": "direction", "rc": "rc"}

    def __init__(self, D, direction, rc):
        self.D = pair_values(D, "DMI D", real_scalar)
        warn_implausible(self.D, MAX_COUPLING, "DMI |D|", "eV",
                         "Dzyaloshinskii–Moriya couplings are ~0.1 to a few meV per pair",
                         "energy")
        self.direction = pair_values(direction, "DMI direction", unit_vector)
        self.rc = length(rc, "DMI rc")
        self.cutoff = self.rc
        self._finish()

    def __repr__(self):
        return f"DMI({self.D!r}, {self.direction!r}, rc={self.rc})"

    def lammps(self, types):
        """``pair_style spin/dmi rc`` with ``pair_coeff I J dmi rc D dx dy dz``
        per pair of types, (dx, dy, dz) a unit vector (LAMMPS divides it by its
        squared length). Energy and magnetic forces as here; LAMMPS's lattice
        force differs (see the class docstring)."""

        D = _pair_table(self.D, types.symbols, "DMI D")
        d = _pair_table(self.direction, types.symbols, "DMI direction")
        coeffs = []
        for i, j, _, _ in types.pairs():
            a, b = i - 1, j - 1
            if D[a, b] is None or d[a, b] is None or not (types.magnetic[a]
                                                          and types.magnetic[b]):
                strength, direction = 0.0, np.array([0.0, 0.0, 1.0])
            else:
                strength, direction = D[a, b], types.vector(d[a, b])
            coeffs.append((i, j, f"dmi {number_text(self.rc)} {number_text(strength)} {vector_text(direction)}"))
        return [LammpsPair("spin/dmi", number_text(self.rc), coeffs)]

    def bind(self, system):
        symbols = system.species.symbols
        nt = len(symbols)
        D = _pair_table(self.D, symbols, "DMI D")
        d = _pair_table(self.direction, symbols, "DMI direction")
        Dtab = np.zeros((nt, nt, 3))
        for a in range(nt):
            for b in range(nt):
                if D[a, b] is not None and d[a, b] is not None:
                    Dtab[a, b] = D[a, b] * np.asarray(d[a, b])
        rc2 = np.full((nt, nt), self.rc**2)
        return rc2, Dtab

    def prepare(self, positions, pairs, types, bound, *, virial=False, out=None,
                mean_with=None):
        rc2, Dtab = bound
        n = len(pairs)
        if out is not None and out.pairs is pairs:
            U, E, R = out.data[0], out.data[1], out.data[2]
            Ubar = out.mean_data[0] if out.mean_data is not None else None
        else:
            U, E, R, Ubar = np.empty((n, 3)), np.empty((n, 3)), np.empty(n), None
        if mean_with is not None:
            if mean_with.pairs is not pairs:
                raise ValueError("mean_with must be an operator on the same pair list")
            if Ubar is None:
                Ubar = np.empty((n, 3))
            other = mean_with.data[0]
        else:
            other, Ubar = _NO_U, None
        _geometry(positions, pairs.row, pairs.j, pairs.image, pairs.images, types, rc2, Dtab,
                  U, E, R, other, Ubar if Ubar is not None else _NO_U)
        data = (U, E, R, types, Dtab)
        mean_data = (Ubar, E, R, types, Dtab) if Ubar is not None else None
        return self.operator(pairs, data, mean_data)
