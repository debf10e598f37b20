"""Magnetocrystalline anisotropy (LAMMPS ``fix precession/spin anisotropy`` and
``cubic``)."""

from __future__ import annotations

import numba as nb
import numpy as np

from ..validate import MAX_SITE_ENERGY, real_scalar, unit_vector, warn_implausible
from .base import SingleSiteTerm
from .lammps_form import LammpsFix, number_text, vector_text
from .parameters import per_atom, species_values

__all__ = ["UniaxialAnisotropy", "CubicAnisotropy"]


def _check_size(K, what):
    """ImplausibleParameterWarning for |K| above MAX_SITE_ENERGY eV per atom."""
    warn_implausible(K, MAX_SITE_ENERGY, what, "eV per atom",
                     "magnetocrystalline anisotropies are μeV to a few meV per atom",
                     "a value in meV, in J/m³ or per formula unit given as eV per atom? "
                     "ase_spin takes K in eV per magnetic atom")


@nb.njit(cache=True, inline="always")
def _uniaxial_field(i, s, data):
    K, n = data
    c = 2.0 * K[i] * (s[i, 0] * n[0] + s[i, 1] * n[1] + s[i, 2] * n[2])
    return c * n[0], c * n[1], c * n[2]


@nb.njit(cache=True, inline="always")
def _uniaxial_energy(i, s, data):
    K, n = data
    c = s[i, 0] * n[0] + s[i, 1] * n[1] + s[i, 2] * n[2]
    return -K[i] * c * c


class UniaxialAnisotropy(SingleSiteTerm):
    r"""Uniaxial anisotropy along the axis **n** (LAMMPS ``fix precession/spin
    anisotropy K x y z``):

    .. math::

        E = -\sum_i K_i (\mathbf s_i\cdot\mathbf n)^2, \qquad
        \mathbf B_i = 2 K_i (\mathbf s_i\cdot\mathbf n)\,\mathbf n .

    K in eV (per magnetic atom; a mapping ``{"Co": K}`` gives it per species);
    K > 0 is an easy axis, K < 0 an easy plane. ``axis``: any non-zero
    3-vector, normalised here.
    """

    name = "anisotropy"
    site_field = _uniaxial_field
    site_energy = _uniaxial_energy

    _parameters = {"K": "K", "axis": "axis"}

    def __init__(self, K, axis):
        self.K = species_values(K, "UniaxialAnisotropy K", real_scalar)
        _check_size(self.K, "UniaxialAnisotropy K")
        self.axis = unit_vector(axis, "UniaxialAnisotropy axis")
        self._finish()

    def __repr__(self):
        return f"UniaxialAnisotropy(K={self.K!r}, axis={self.axis.tolist()})"

    def lammps(self, types):
        """``fix precession/spin anisotropy K x y z``, one per magnetic species
        when K differs between them."""

        axis = vector_text(types.vector(self.axis))
        return [LammpsFix("precession/spin", f"anisotropy {number_text(K)} {axis}", group)
                for group, K in types.site_groups(self.K, "UniaxialAnisotropy K")]

    def bind(self, system):
        return (per_atom(self.K, system, "UniaxialAnisotropy K"), np.array(self.axis))


@nb.njit(cache=True, inline="always")
def _projections(i, s, n):
    return (s[i, 0] * n[0, 0] + s[i, 1] * n[0, 1] + s[i, 2] * n[0, 2],
            s[i, 0] * n[1, 0] + s[i, 1] * n[1, 1] + s[i, 2] * n[1, 2],
            s[i, 0] * n[2, 0] + s[i, 1] * n[2, 1] + s[i, 2] * n[2, 2])


@nb.njit(cache=True, inline="always")
def _cubic_field(i, s, data):
    K1, K2, n = data
    a, b, c = _projections(i, s, n)
    a2 = a * a
    b2 = b * b
    c2 = c * c
    k1 = 2.0 * K1[i]
    k2 = 2.0 * K2[i]
    # B = −∂E/∂s = Σ_k f_k n_k with f_k = −∂E/∂(s·n_k)
    fa = k1 * a * (b2 + c2) + k2 * a * b2 * c2
    fb = k1 * b * (a2 + c2) + k2 * b * a2 * c2
    fc = k1 * c * (a2 + b2) + k2 * c * a2 * b2
    return (fa * n[0, 0] + fb * n[1, 0] + fc * n[2, 0],
            fa * n[0, 1] + fb * n[1, 1] + fc * n[2, 1],
            fa * n[0, 2] + fb * n[1, 2] + fc * n[2, 2])


@nb.njit(cache=True, inline="always")
def _cubic_energy(i, s, data):
    K1, K2, n = data
    a, b, c = _projections(i, s, n)
    a2 = a * a
    b2 = b * b
    c2 = c * c
    return -K1[i] * (a2 * b2 + b2 * c2 + a2 * c2) - K2[i] * a2 * b2 * c2


class CubicAnisotropy(SingleSiteTerm):
    r"""Cubic anisotropy with axes n₁, n₂, n₃ (LAMMPS ``fix precession/spin
    cubic K1 K2c n1 n2 n3``):

    .. math::

        E = \sum_i \Big\{-K_1 \big[(\mathbf s_i\cdot\mathbf n_1)^2 (\mathbf s_i\cdot\mathbf n_2)^2
            + (\mathbf s_i\cdot\mathbf n_2)^2 (\mathbf s_i\cdot\mathbf n_3)^2
            + (\mathbf s_i\cdot\mathbf n_1)^2 (\mathbf s_i\cdot\mathbf n_3)^2\big]
            - K_2\, (\mathbf s_i\cdot\mathbf n_1)^2 (\mathbf s_i\cdot\mathbf n_2)^2
              (\mathbf s_i\cdot\mathbf n_3)^2\Big\},

    B_i = −∂E/∂s_i. K1, K2 in eV (per species with a mapping ``{"Fe": K}``).
    ``axes``: three non-zero 3-vectors, each normalised here (as LAMMPS, not
    orthogonalised); default the Cartesian axes. With this sign K1 < 0 makes
    the cube axes easy directions (bcc Fe), K1 > 0 the body diagonals (Ni).
    The signs are those of LAMMPS's code (checked against it in tests/test_lammps.py).
    """

    name = "cubic_anisotropy"
    site_field = _cubic_field
    site_energy = _cubic_energy

    _parameters = {"K1": "K1", "K2": "K2", "axes": "axes"}

    def __init__(self, K1, K2=0.0, axes=None):
        self.K1 = species_values(K1, "CubicAnisotropy K1", real_scalar)
        self.K2 = species_values(K2, "CubicAnisotropy K2", real_scalar)
        _check_size(self.K1, "CubicAnisotropy K1")
        _check_size(self.K2, "CubicAnisotropy K2")
        if axes is None:
            axes = np.eye(3)
        if np.ndim(axes) != 2 or len(axes) != 3:
            raise ValueError(f"CubicAnisotropy axes must be three 3-vectors, got {axes!r}")
        n = np.array([unit_vector(v, f"CubicAnisotropy axis {k + 1}")
                      for k, v in enumerate(axes)])
        n.setflags(write=False)
        self.axes = n
        self._finish()

    def __repr__(self):
        return f"CubicAnisotropy(K1={self.K1!r}, K2={self.K2!r}, axes={self.axes.tolist()})"

    def lammps(self, types):
        """``fix precession/spin cubic K1 K2 n1 n2 n3``, one per magnetic species
        when K1 or K2 differ between them."""
        from collections.abc import Mapping

        axes = " ".join(vector_text(types.vector(n)) for n in self.axes)
        if isinstance(self.K1, Mapping) or isinstance(self.K2, Mapping):
            both = {}
            for s, m in zip(types.symbols, types.magnetic):
                k = [K[s] if isinstance(K, Mapping) and s in K else K for K in (self.K1, self.K2)]
                if m and not any(isinstance(v, Mapping) for v in k):
                    both[s] = tuple(k)
            groups = types.site_groups(both, "CubicAnisotropy K1, K2")
        else:
            groups = types.site_groups((self.K1, self.K2), "CubicAnisotropy K1, K2")
        return [LammpsFix("precession/spin", f"cubic {number_text(K1)} {number_text(K2)} {axes}", group)
                for group, (K1, K2) in groups]

    def bind(self, system):
        return (per_atom(self.K1, system, "CubicAnisotropy K1"),
                per_atom(self.K2, system, "CubicAnisotropy K2"), np.array(self.axes))
