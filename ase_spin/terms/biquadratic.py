"""Bilinear plus biquadratic exchange (LAMMPS ``pair_style spin/exchange/biquadratic``)."""

from __future__ import annotations

import numba as nb
import numpy as np

from ..neighbors import separation
from ..validate import flag
from .base import PairOperator, PairSpinTerm
from .couplings import BetheSlater
from .exchange import NO_ROWS, Exchange, copy_positions
from .lammps_form import LammpsPair, number_text
from .parameters import resolve_pairs

__all__ = ["BiquadraticExchange"]


@nb.njit(cache=True, inline="always")
def _field(k, a, b, s, data, reverse):
    """Field on spin a from spin b: [J + 2K (s_a·s_b)] s_b."""
    J = data[0]
    K = data[1]
    w = s[a, 0] * s[b, 0] + s[a, 1] * s[b, 1] + s[a, 2] * s[b, 2]
    c = J[k] + 2.0 * K[k] * w
    return c * s[b, 0], c * s[b, 1], c * s[b, 2]


@nb.njit(cache=True, inline="always")
def _energy(k, i, j, s, data):
    """e = −[J (w − c) + K (w² − c)], w = s_i·s_j; the force on j,
    f = (w − c) G + (w² − c) H with G = J' d/r, H = K' d/r; d_ij = (r_j − r_i)
    + S_k, recomputed from the positions the operator was prepared at.
    ``data``: J, K per pair; J'/r, K'/r per pair and G, H per pair (one of the
    two pairs of arrays empty: see exchange.PAIR_VECTORS_BELOW; G formed as
    (J'/r)·d, the same bits as stored); those positions, the image shifts and
    their index per pair (no positions: G, H kept and no virial wanted); c."""
    J, K, gJ, gK, GJ, GK, pos, images, image, c = data
    w = s[i, 0] * s[j, 0] + s[i, 1] * s[j, 1] + s[i, 2] * s[j, 2]
    a = w - c
    b = w * w - c
    e = -(J[k] * a + K[k] * b)
    if pos.shape[0] > 0:
        dx, dy, dz, r2 = separation(pos, images, i, j, image[k])
    else:  # G, H kept and no virial asked at preparation
        dx = dy = dz = 0.0
    if GJ.shape[0] > 0:
        fx = a * GJ[k, 0] + b * GK[k, 0]
        fy = a * GJ[k, 1] + b * GK[k, 1]
        fz = a * GJ[k, 2] + b * GK[k, 2]
    else:
        g = gJ[k]
        h = gK[k]
        fx = a * (g * dx) + b * (h * dx)
        fy = a * (g * dy) + b * (h * dy)
        fz = a * (g * dz) + b * (h * dz)
    return e, fx, fy, fz, dx, dy, dz


@nb.njit(cache=True, inline="always")
def _site(i, s, data):
    """B_i = Σ_j [J_ij + 2 K_ij (s_i·s_j)] s_j from the spins as they are (full list)."""
    row, nbr, J, K = data[0], data[1], data[2], data[3]
    bx = 0.0
    by = 0.0
    bz = 0.0
    for k in range(row[i], row[i + 1]):
        j = nbr[k]
        c = J[k] + 2.0 * K[k] * (s[i, 0] * s[j, 0] + s[i, 1] * s[j, 1] + s[i, 2] * s[j, 2])
        bx += c * s[j, 0]
        by += c * s[j, 1]
        bz += c * s[j, 2]
    return bx, by, bz


@nb.njit(cache=True)
def _self_curvature(row, nbr, J, K, W):
    """Σ_i Σ_t t·(∂B_i/∂s_i) t of the fields the pairs k = (i → j) of a list
    put on their atom i (see :meth:`BiquadraticOperator.self_curvature`)."""
    total = 0.0
    for i in range(len(row) - 1):
        li = W[i, 0] * W[i, 0] + W[i, 1] * W[i, 1] + W[i, 2] * W[i, 2]
        for k in range(row[i], row[i + 1]):
            j = nbr[k]
            if j == i:
                total += 2.0 * (J[k] + 2.0 * K[k]) * li
            else:
                lj = W[j, 0] * W[j, 0] + W[j, 1] * W[j, 1] + W[j, 2] * W[j, 2]
                w = W[i, 0] * W[j, 0] + W[i, 1] * W[j, 1] + W[i, 2] * W[j, 2]
                total += 2.0 * K[k] * (li * lj - w * w)
    return total


class BiquadraticOperator(PairOperator):
    """The biquadratic exchange's :class:`PairOperator`, with the dependence
    of each spin's field on that spin (:meth:`self_curvature`)."""

    __slots__ = ()

    def self_curvature(self, W):
        r"""Σ_i Σ_t t·(∂B_i/∂s_i) t: each pair's field on i, [J + 2K (s_i·s_j)] s_j,
        gives ∂B_i/∂s_i = 2K s_j s_jᵀ, whose trace over the two directions
        t ⊥ s_i is 2K (|s_i|²|s_j|² − (s_i·s_j)²); a pair of an atom with its
        own image (s_j = s_i), 2 (J + 2K)|s_i|². A half list's pair puts a
        field on both of its atoms, with the same value: twice the sum."""
        p = self.pairs
        total = _self_curvature(p.row, p.j, self.data[0], self.data[1],
                                np.ascontiguousarray(W))
        return (2.0 if p.half else 1.0) * total


class BiquadraticExchange(PairSpinTerm):
    r"""Bilinear and biquadratic exchange (LAMMPS ``pair_style
    spin/exchange/biquadratic``):

    .. math::

        E = -\sum_{i<j} \left[ J(r_{ij}) (\mathbf s_i\cdot\mathbf s_j - c)
            + K(r_{ij}) \big((\mathbf s_i\cdot\mathbf s_j)^2 - c\big) \right],
        \qquad c = 1 \text{ if offset else } 0,

    .. math::

        \mathbf B_i = \sum_j \left[J(r_{ij}) + 2K(r_{ij})\,
            (\mathbf s_i\cdot\mathbf s_j)\right] \mathbf s_j, \qquad
        \mathbf F_j = \left[J'(r_{ij})(\mathbf s_i\cdot\mathbf s_j - c)
            + K'(r_{ij})\big((\mathbf s_i\cdot\mathbf s_j)^2 - c\big)\right]
            \frac{\mathbf r_j - \mathbf r_i}{r_{ij}},

    each pair once, J and K zero beyond ``rc``. ``J`` and ``K`` are couplings
    as for :class:`~ase_spin.terms.exchange.Exchange` (LAMMPS's ``biquadratic
    rc J1 J2 J3 K1 K2 K3`` is ``J=BetheSlater(J1, J2, J3), K=BetheSlater(K1,
    K2, K3)``), or mappings keyed by pairs of chemical symbols. K > 0 favours
    collinear (parallel or antiparallel) pairs. ``offset=True`` is LAMMPS's
    ``offset yes``.
    """

    name = "biquadratic_exchange"
    pair_field, pair_energy, pair_site = _field, _energy, _site

    _parameters = {"J": "J", "K": "K", "rc": "rc", "offset": "offset"}

    def __init__(self, J, K, rc=None, offset=False):
        bilinear = Exchange(J, rc)
        self.offset = flag(offset, "BiquadraticExchange offset")
        self.J = bilinear.coupling
        self.K = Exchange(K, bilinear.rc).coupling
        self.rc = bilinear.rc
        self.cutoff = self.rc
        self._finish()

    def __repr__(self):
        return (f"BiquadraticExchange(J={self.J!r}, K={self.K!r}, rc={self.rc}, "
                f"offset={self.offset})")

    def lammps(self, types):
        """``pair_style spin/exchange/biquadratic rc`` with ``pair_coeff I J
        biquadratic rc J1 J2 J3 K1 K2 K3 [offset yes]``: Bethe–Slater J and K
        only (LAMMPS's form)."""
        tables = [resolve_pairs(c, types.symbols, f"BiquadraticExchange {what}")
                  for c, what in ((self.J, "J"), (self.K, "K"))]
        coeffs = []
        for i, j, si, sj in types.pairs():
            args = []
            for table in tables:
                c = table[i - 1, j - 1]
                if c is not None and type(c) is not BetheSlater:
                    raise NotImplementedError(
                        f"the {type(c).__name__} coupling of pair {si}-{sj}: LAMMPS's "
                        "spin/exchange/biquadratic takes only the Bethe–Slater form")
                if c is None or not (types.magnetic[i - 1] and types.magnetic[j - 1]):
                    args.append("0.0 0.0 1.0")
                else:
                    args.append(f"{number_text(c.J1)} {number_text(c.J2)} {number_text(c.J3)}")
            coeffs.append((i, j, f"biquadratic {number_text(self.rc)} {' '.join(args)}"
                           + (" offset yes" if self.offset else "")))
        return [LammpsPair("spin/exchange/biquadratic", number_text(self.rc), coeffs)]

    def operator(self, pairs, data, mean_data):
        return BiquadraticOperator(pairs, data, mean_data, self._compiled_pass(),
                                   type(self).pair_site)

    def _parts(self):
        """J and K each as an exchange term: their tables and pair geometry."""
        parts = self.__dict__.get("_parts_cache")
        if parts is None or parts[0] != self._version:
            parts = (self._version, Exchange(self.J, self.rc), Exchange(self.K, self.rc))
            self.__dict__["_parts_cache"] = parts
        return parts[1:]

    def bind(self, system):
        J, K = self._parts()
        return J.bind(system), K.bind(system)

    def prepare(self, positions, pairs, types, bound, *, virial=False, out=None,
                mean_with=None):
        """The operator at ``positions``: J, K and J' d/r, K' d/r per pair, or
        J'/r, K'/r (two exchange operators' arrays, see
        :class:`~ase_spin.terms.exchange.ExchangeOperator`), and one copy of the
        positions, shared by both, from which the passes recompute d."""
        J, K = self._parts()
        previous = out.extra if out is not None and out.pairs is pairs else (None, None)
        other = mean_with.extra if mean_with is not None else (None, None)
        opJ = J._operator(pairs, previous[0], len(positions), virial)
        opK = K._operator(pairs, previous[1], len(positions), virial)
        if opJ.pos is not None:
            # one copy for both (they are always prepared together, at the same q)
            opJ.pos = opK.pos = positions = copy_positions(positions, opJ.pos)
        J._fill(opJ, positions, types, bound[0], other[0])
        K._fill(opK, positions, types, bound[1], other[1])
        c = 1.0 if self.offset else 0.0
        geometry = (opJ.pos if opJ.pos is not None else NO_ROWS, pairs.images, pairs.image, c)
        vectors = (opJ.g, opK.g, opJ.G, opK.G)
        data = (opJ.J, opK.J, *vectors, *geometry)
        mean_data = ((opJ.Jbar, opK.Jbar, *vectors, *geometry) if opJ.Jbar is not None
                     else None)
        op = self.operator(pairs, data, mean_data)
        op.extra = (opJ, opK)
        return op
