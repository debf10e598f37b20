"""The Dzyaloshinskii–Moriya interaction (LAMMPS ``pair_style spin/dmi``)."""

from __future__ import annotations

import numba as nb
import numpy as np

from .._jit.threads import threaded
from ..neighbors import separation
from ..validate import MAX_COUPLING, length, real_scalar, unit_vector, warn_implausible
from .base import PairSpinTerm, mean_buffer
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
    """e = −(e_ij × D + D_b e_ij)·(s_i × s_j) = −e_ij·c with c = D × (s_i × s_j)
    + D_b (s_i × s_j); the force on j, f = −∂e/∂r_j = (c − (c·e_ij) e_ij)/r_ij;
    d_ij. (D the interfacial vector, D_b the bulk strength: one of them zero.)"""
    U, E, R, types, Dtab = data
    r = R[k]
    if r == 0.0:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    ti = types[i]
    tj = types[j]
    Dx = Dtab[ti, tj, 0]
    Dy = Dtab[ti, tj, 1]
    Dz = Dtab[ti, tj, 2]
    Db = Dtab[ti, tj, 3]
    # w = s_i × s_j, c = D × w + D_b w
    wx = s[i, 1] * s[j, 2] - s[i, 2] * s[j, 1]
    wy = s[i, 2] * s[j, 0] - s[i, 0] * s[j, 2]
    wz = s[i, 0] * s[j, 1] - s[i, 1] * s[j, 0]
    cx = (Dy * wz - Dz * wy) + Db * wx
    cy = (Dz * wx - Dx * wz) + Db * wy
    cz = (Dx * wy - Dy * wx) + Db * wz
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
    U_k = e_k × D + D_b e_k (the bond's DM vector); zero beyond. With ``other`` given, Ubar_k = ½(other_k + U_k)."""
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
                Db = Dtab[ti, tj, 3]
                ux = (ey * Dz - ez * Dy) + Db * ex
                uy = (ez * Dx - ex * Dz) + Db * ey
                uz = (ex * Dy - ey * Dx) + Db * ez
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
    r"""The Dzyaloshinskii–Moriya interaction, with the DM vector of each bond
    **D**_ij built from the bond's direction **e**_ij:

    .. math::

        E = -\sum_{i<j} \mathbf D_{ij}\cdot(\mathbf s_i\times\mathbf s_j),
        \qquad \mathbf e_{ij} = \frac{\mathbf r_j - \mathbf r_i}{r_{ij}},
        \quad r_{ij} < r_c,

    each pair once, with

    - ``form="interfacial"`` (default; LAMMPS ``pair_style spin/dmi``, after
      Rohart and Thiaville): **D**_ij = **e**_ij × **D**, perpendicular to the
      bond; with **D** along the normal of a film this is the interfacial DMI
      that stabilises Néel skyrmions. ``D`` (eV) is its strength and
      ``direction`` (normalised here) the vector **D**/D;
    - ``form="bulk"``: **D**_ij = D **e**_ij, along the bond (B20 chiral
      magnets, FeGe, MnSi: Bloch skyrmions and helices; a chain with J and D
      has the helix turning by arctan(D/J) per bond). No ``direction``.

    In both, with **u**_ij = **D**_ij and **c** = **D** × (**s**_i × **s**_j)
    (interfacial) or D (**s**_i × **s**_j) (bulk),

    .. math::

        \mathbf B_i = \sum_j \mathbf s_j \times \mathbf u_{ij},
        \qquad
        \mathbf F_j = -\frac{\partial E}{\partial \mathbf r_j}
        = \frac{\mathbf c - (\mathbf c\cdot\mathbf e_{ij})\mathbf e_{ij}}{r_{ij}}.

    ``D`` and ``direction`` may be mappings keyed by pairs of chemical
    symbols. ``rc`` (Å) cuts it off. DM vectors given pair by pair (from DFT)
    are :class:`~ase_spin.terms.pair_couplings.PairCouplings`.

    LAMMPS's ``pair_coeff * * dmi rc D dx dy dz`` is the interfacial form and
    divides (dx, dy, dz) by its squared length: give it a unit direction.
    Energy and magnetic forces match LAMMPS; its mechanical forces do not
    (they are not −∂E/∂r: see docs/terms.md), so ours are the derivative of
    this energy. LAMMPS has no bulk form (``spin/dmi`` forms e_ij × D from a
    fixed vector): :meth:`lammps` refuses it.
    """

    name = "dmi"
    pair_field, pair_energy, pair_site = _field, _energy, _site

    _parameters = {"D": "D", "direction": "direction", "rc": "rc", "form": "form"}

    def __init__(self, D, direction=None, rc=None, form="interfacial"):
        if form not in ("interfacial", "bulk"):
            raise ValueError(f"DMI form must be 'interfacial' (D_ij = e_ij × D, LAMMPS spin/dmi) "
                             f"or 'bulk' (D_ij = D e_ij), got {form!r}")
        self.form = form
        self.D = pair_values(D, "DMI D", real_scalar)
        warn_implausible(self.D, MAX_COUPLING, "DMI |D|", "eV",
                         "Dzyaloshinskii–Moriya couplings are ~0.1 to a few meV per pair",
                         "energy")
        if form == "bulk":
            if direction is not None:
                raise ValueError("DMI form='bulk' takes no direction: the DM vector of each "
                                 "bond is D e_ij, along the bond")
            self.direction = None
        else:
            if direction is None:
                raise ValueError("DMI form='interfacial' needs a direction (the vector D/|D|, "
                                 "the film's normal for interfacial DMI)")
            self.direction = pair_values(direction, "DMI direction", unit_vector)
        if rc is None:
            raise ValueError("DMI needs rc (Å), the cutoff")
        self.rc = length(rc, "DMI rc")
        self.cutoff = self.rc
        self._finish()

    def __repr__(self):
        if self.form == "bulk":
            return f"DMI({self.D!r}, rc={self.rc}, form='bulk')"
        return f"DMI({self.D!r}, {self.direction!r}, rc={self.rc})"

    def lammps(self, types):
        """``pair_style spin/dmi rc`` with ``pair_coeff I J dmi rc D dx dy dz``
        per pair of types, (dx, dy, dz) a unit vector (LAMMPS divides it by its
        squared length). Energy and magnetic forces as here; LAMMPS's lattice
        force differs (see the class docstring). The bulk form has no LAMMPS
        counterpart."""

        if self.form == "bulk":
            raise NotImplementedError(
                "DMI form='bulk': LAMMPS's spin/dmi has only the interfacial form, the DM "
                "vector e_ij × D of a fixed D; no LAMMPS pair style has D_ij = D e_ij")
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
        bulk = self.form == "bulk"
        d = None if bulk else _pair_table(self.direction, symbols, "DMI direction")
        # (Dx, Dy, Dz, D_bulk): the interfacial vector, or the bulk strength
        Dtab = np.zeros((nt, nt, 4))
        for a in range(nt):
            for b in range(nt):
                if D[a, b] is None:
                    continue
                if bulk:
                    Dtab[a, b, 3] = D[a, b]
                elif d[a, b] is not None:
                    Dtab[a, b, :3] = D[a, b] * np.asarray(d[a, b])
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
        Ubar = mean_buffer(mean_with, pairs, Ubar, (n, 3))
        other = mean_with.data[0] if mean_with is not None else _NO_U
        _geometry(positions, pairs.row, pairs.j, pairs.image, pairs.images, types, rc2, Dtab,
                  U, E, R, other, Ubar if Ubar is not None else _NO_U)
        data = (U, E, R, types, Dtab)
        mean_data = (Ubar, E, R, types, Dtab) if Ubar is not None else None
        return self.operator(pairs, data, mean_data)
