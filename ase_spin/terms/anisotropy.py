"""Magnetocrystalline anisotropy (LAMMPS ``fix precession/spin anisotropy`` and
``cubic``)."""

from __future__ import annotations

import numba as nb
import numpy as np

from ..validate import real_scalar, unit_vector
from .base import SingleSiteTerm, per_atom, species_values

__all__ = ["UniaxialAnisotropy"]


def _energy_value(value, what):
    return real_scalar(value, what)


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
        self.K = species_values(K, "UniaxialAnisotropy K", _energy_value)
        self.axis = unit_vector(axis, "UniaxialAnisotropy axis")
        self._finish()

    def __repr__(self):
        return f"UniaxialAnisotropy(K={self.K!r}, axis={self.axis.tolist()})"

    def bind(self, system):
        return (per_atom(self.K, system, "UniaxialAnisotropy K"), np.array(self.axis))
