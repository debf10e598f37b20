"""Exchange from tables: a smooth tabulated J(r), and constants per neighbour shell.

Both plug into :class:`~ase_spin.terms.exchange.Exchange`'s machinery (they are
couplings evaluated by their own vectorised ``values(r)``), so they work with
the calculator and both integrators like any other exchange.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from ..validate import length, real_array
from .couplings import Coupling, check_size
from .exchange import Exchange
from .parameters import pair_key

__all__ = ["Tabulated", "ShellCoupling", "ShellExchange"]


def _frozen(a):
    a = np.array(a, dtype=float)
    a.setflags(write=False)
    return a


class Tabulated(Coupling):
    r"""A coupling J(r) (eV) through tabulated points (r_k, J_k), k = 0..n−1.

    Between the points, the cubic spline through them with a natural start
    (J''(r_0) = 0) and a clamped end (J'(r_{n−1}) = 0):

    .. math::

        J(r) = \begin{cases}
            J_0 + J'(r_0)\,(r - r_0) & r < r_0 \quad\text{(continued linearly)}\\
            S(r) & r_0 \le r \le r_{n-1}\\
            0 & r > r_{n-1}
        \end{cases}

    J_{n−1} must be 0, so J and J' are continuous everywhere (J'' at r_0 too):
    forces are the exact derivative of the energy and a moving lattice
    conserves energy. ``rc`` is the last point. Distances in Å, strictly
    increasing; at least three points.

    The spline's J'(r) is what the lattice feels (magneto-elastic forces). With
    points only at a crystal's shell distances (one DFT calculation), J' between
    them is an interpolation, not data: for a frozen or nearly frozen lattice
    use :class:`ShellExchange`, and tabulate J(r) from calculations at several
    volumes when the forces matter.
    """

    _parameters = {"r": "r", "J": "J"}

    def __init__(self, r, J):
        r = real_array(r, "Tabulated r")
        J = real_array(J, "Tabulated J")
        if r.ndim != 1 or r.shape != J.shape:
            raise ValueError(f"Tabulated r and J must be 1-d arrays of one length; got shapes "
                             f"{r.shape} and {J.shape}")
        if len(r) < 3:
            raise ValueError(f"Tabulated needs at least three points; got {len(r)}")
        if not (np.isfinite(r).all() and np.isfinite(J).all()):
            raise ValueError("Tabulated r and J must be finite")
        if r[0] < 0.0 or (np.diff(r) <= 0.0).any():
            k = int(np.argmax(np.diff(r) <= 0.0)) if r[0] >= 0.0 else 0
            raise ValueError(f"Tabulated r must be non-negative and strictly increasing; "
                             f"r[{k}] = {r[k]}, r[{k + 1}] = {r[min(k + 1, len(r) - 1)]}")
        if J[-1] != 0.0:
            raise ValueError(
                f"Tabulated J must be 0 at the last point (J is zero beyond it); got "
                f"J({r[-1]} Å) = {J[-1]} eV: add a point where the coupling has decayed")
        check_size(J, "Tabulated J")
        self.r = _frozen(r)
        self.J = _frozen(J)
        self.rc = float(r[-1])
        from scipy.interpolate import CubicSpline  # here: a third of ase_spin's import time

        self._spline = CubicSpline(r, J, bc_type=("natural", (1, 0.0)))
        self._dspline = self._spline.derivative()
        self._slope0 = float(self._dspline(r[0]))
        self._finish()

    def values(self, r):
        r = np.asarray(r, dtype=float)
        inside = (r >= self.r[0]) & (r <= self.rc)
        J = np.where(inside, self._spline(np.clip(r, self.r[0], self.rc)), 0.0)
        dJ = np.where(inside, self._dspline(np.clip(r, self.r[0], self.rc)), 0.0)
        below = r < self.r[0]
        J = np.where(below, self.J[0] + self._slope0 * (r - self.r[0]), J)
        dJ = np.where(below, self._slope0, dJ)
        return J, dJ

    def __repr__(self):
        return f"Tabulated(r={self.r.tolist()}, J={self.J.tolist()})"


class ShellCoupling(Coupling):
    r"""Constants per neighbour shell: J(r) = J_n for |r − d_n| ≤ tol, J' = 0.

    ``shells``: a sequence of (d_n, J_n) pairs (Å, eV), in any order. J is
    zero beyond the last window (r > d_max + tol). A distance below that but
    in no window (between shells, or closer than the first) is an error: the
    lattice has moved further from the reference positions than the
    tolerance, and the table says nothing about such a pair.
    """

    _parameters = {"shells": "shells", "tol": "tol"}

    def __init__(self, shells, tol=0.1):
        self.tol = length(tol, "ShellCoupling tol")
        table = _shell_table(shells, "ShellCoupling shells")
        d, J = table[:, 0], table[:, 1]
        check_size(J, "ShellCoupling J")
        gaps = np.diff(d)
        if len(gaps) and gaps.min() <= 2.0 * self.tol:
            k = int(np.argmin(gaps))
            raise ValueError(
                f"ShellCoupling: shells at {d[k]} and {d[k + 1]} Å are closer than twice the "
                f"tolerance {self.tol} Å: their windows overlap; give a smaller tol")
        if d[0] <= self.tol:
            raise ValueError(f"ShellCoupling: a shell at {d[0]} Å is within tol of r = 0")
        self.shells = tuple((float(a), float(b)) for a, b in table)
        self._d = d
        self._J = J
        self.rc = float(d[-1] + self.tol)
        self._finish()

    def values(self, r):
        r = np.asarray(r, dtype=float)
        k = np.clip(np.searchsorted(self._d, r), 1, len(self._d) - 1) if len(self._d) > 1 \
            else np.zeros(r.shape, dtype=int)
        # nearest shell of each distance
        if len(self._d) > 1:
            k = np.where(np.abs(r - self._d[k - 1]) <= np.abs(r - self._d[k]), k - 1, k)
        near = np.abs(r - self._d[k]) <= self.tol
        beyond = r > self.rc
        lost = ~near & ~beyond
        if lost.any():
            x = float(r[np.argmax(lost)])
            raise ValueError(
                f"ShellCoupling: a pair at r = {x:.4f} Å is in no shell (shells at "
                f"{', '.join(f'{v:.4f}' for v in self._d)} Å, ± {self.tol} Å): the lattice has "
                "moved beyond the tolerance from its reference positions; use a larger tol, "
                "or a Tabulated coupling for a moving lattice")
        return np.where(near, self._J[k], 0.0), np.zeros(r.shape)

    def __repr__(self):
        return f"ShellCoupling({list(self.shells)}, tol={self.tol})"


def _shell_table(shells, what):
    """(n, 2) array of (distance, J) sorted by distance, checked."""
    if isinstance(shells, Mapping):
        shells = list(shells.items())
    table = real_array(shells, what)
    if table.ndim != 2 or table.shape[1] != 2 or len(table) == 0:
        raise ValueError(f"{what}: give a list of (distance in Å, J in eV) pairs; got shape "
                         f"{table.shape}")
    if not np.isfinite(table).all():
        raise ValueError(f"{what} must be finite")
    table = table[np.argsort(table[:, 0])]
    if (table[:, 0] <= 0.0).any():
        raise ValueError(f"{what}: shell distances must be positive")
    dup = np.diff(table[:, 0]) == 0.0
    if dup.any():
        raise ValueError(f"{what}: the shell at {table[np.argmax(dup), 0]} Å is given twice")
    return table


class ShellExchange(Exchange):
    r"""Heisenberg exchange with one constant per neighbour shell (from DFT, e.g.
    TB2J: see :func:`ase_spin.read_tb2j`), for a lattice near its reference
    positions:

    .. math::

        E = -\sum_{i<j} J_{n(ij)}\, (\mathbf s_i\cdot\mathbf s_j - c), \qquad
        \mathbf B_i = \sum_j J_{n(ij)}\, \mathbf s_j,

    n(ij) the shell whose distance d_n is within ``tol`` of r_ij (J = 0 beyond
    the last shell), J > 0 ferromagnetic, eV, each pair once.

    ``shells``: a list of (distance Å, J eV) pairs, or a mapping from pairs of
    chemical symbols to such lists (``{("Fe", "Fe"): [(2.485, 0.0191), ...],
    ("Fe", "Co"): ...}``; None switches a pair of species off).

    Forces: none. A constant per shell has no dJ/dr, so this term gives no
    lattice forces or stress (J' = 0): the energy is exactly constant under
    displacements within the windows, so energy is conserved, but there is no
    magneto-elastic coupling. It is meant for spin dynamics on a frozen lattice
    or on one vibrating by less than ``tol``; a pair found in no window (the
    lattice has moved too far) is an error, not a silent J = 0. For a moving
    lattice with magneto-elastic forces use ``Exchange(Tabulated(r, J))`` with
    J(r) known between the shells.
    """

    _parameters = {"shells": "shells", "tol": "tol", "offset": "offset"}

    def __init__(self, shells, tol=0.1, offset=False):
        tol = length(tol, "ShellExchange tol")
        if isinstance(shells, Mapping) and shells and all(_is_pair(k) for k in shells):
            couplings = {key: None if v is None else ShellCoupling(v, tol)
                         for key, v in shells.items()}
            kept = {pair_key(key): None if c is None else c.shells
                    for key, c in couplings.items()}
        else:
            couplings = ShellCoupling(shells, tol)
            kept = couplings.shells
        # set before Exchange's checks end construction (_finish)
        self.shells = kept
        self.tol = tol
        super().__init__(couplings, offset=offset)

    def __repr__(self):
        return f"ShellExchange({self.shells!r}, tol={self.tol}, offset={self.offset})"


def _is_pair(key):
    """A key naming a pair of species ("Fe-Co" or ("Fe", "Co")), not a distance."""
    if isinstance(key, str):
        return True
    return isinstance(key, tuple) and len(key) == 2 and all(isinstance(x, str) for x in key)
