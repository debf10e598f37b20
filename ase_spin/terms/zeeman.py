"""An external magnetic field (LAMMPS ``fix precession/spin zeeman``)."""

from __future__ import annotations

import numba as nb
import numpy as np

from ..constants import MU_B_LAMMPS
from ..validate import (MAX_FIELD_T, positive_scalar, real_array, real_scalar, unit_vector,
                        warn_implausible)
from .base import SingleSiteTerm
from .lammps_form import LammpsFix, number_text, vector_text

__all__ = ["Zeeman"]


@nb.njit(cache=True, inline="always")
def _field(i, s, data):
    h = data[0]
    return h[i, 0], h[i, 1], h[i, 2]


@nb.njit(cache=True, inline="always")
def _energy(i, s, data):
    h = data[0]
    return -(h[i, 0] * s[i, 0] + h[i, 1] * s[i, 1] + h[i, 2] * s[i, 2])


class Zeeman(SingleSiteTerm):
    r"""A uniform external field **H** (tesla) acting on every magnetic atom:

    .. math::

        E = -g\,\mu_B \sum_i \mu_i\, \mathbf s_i\cdot\mathbf H, \qquad
        \mathbf B_i = -\frac{\partial E}{\partial \mathbf s_i} = g\,\mu_B\,\mu_i\,\mathbf H,

    with μ_i the atom's moment magnitude (|initial_magmoms|, μB) and μ_B in
    eV/T. ``g`` and ``mu_B`` follow the Hamiltonian's conventions unless
    given: physical (default) g = 1 and CODATA μB, the energy −μ_i μB s·H of
    a moment μ_i μB; LAMMPS's ``fix precession/spin zeeman`` g = 2 and its
    μB' = 5.78901e-5 eV/T (it reads μ_i as a spin length, its moment then
    g μ_i μB'). See :mod:`ase_spin.conventions`.

    ``field``: the field in tesla, a 3-vector, or its magnitude with
    ``direction`` (any non-zero 3-vector, normalised here) as in LAMMPS's
    ``zeeman H x y z``.
    """

    name = "zeeman"
    site_field = _field
    site_energy = _energy

    _parameters = {"field": "field", "direction": "direction", "g": "g", "mu_B": "mu_B"}

    def __init__(self, field, direction=None, *, g=None, mu_B=None):
        if direction is None:
            H = real_array(field, "Zeeman field").reshape(-1)
            if H.shape != (3,) or not np.isfinite(H).all():
                raise ValueError("Zeeman field must be three finite numbers (tesla), or a "
                                 f"magnitude with a direction; got {field!r}")
        else:
            field = real_scalar(field, "Zeeman field")
            direction = unit_vector(direction, "Zeeman direction")
            H = field * direction
        warn_implausible(float(np.sqrt(H @ H)), MAX_FIELD_T, "Zeeman field |H|", "T",
                         "laboratory fields reach ~45 T static, ~100 T pulsed", "field")
        self.field = H if direction is None else field
        self.direction = direction
        H.setflags(write=False)  # edited in place, bound tables would go stale unnoticed
        #: the field vector (T)
        self.H = H
        #: as given (None: from the Hamiltonian's conventions)
        self.g = None if g is None else real_scalar(g, "Zeeman g")
        self.mu_B = None if mu_B is None else positive_scalar(mu_B, "Zeeman mu_B")
        self._finish()

    def __repr__(self):
        return f"Zeeman({self.H.tolist()}, g={self.g}, mu_B={self.mu_B})"

    def energy_scale(self, conventions):
        """g μB (eV/T) under ``conventions`` (a :class:`~ase_spin.conventions.Conventions`)
        where not given explicitly."""
        g = conventions.zeeman_g if self.g is None else self.g
        mu_B = conventions.mu_B if self.mu_B is None else self.mu_B
        return g * mu_B

    def lammps(self, types):
        """``fix precession/spin zeeman H x y z``: LAMMPS's energy is
        −2 μB' μ_i s·H with its μB' = 5.78901e-5 eV/T, so H is written scaled by
        g μB / (2 μB') (exactly H under LAMMPS's conventions)."""
        scale = self.energy_scale(types.conventions) / (2.0 * MU_B_LAMMPS)
        if self.direction is not None:
            magnitude, direction = self.field, self.direction
        else:
            magnitude = float(np.linalg.norm(self.H))
            direction = self.H if magnitude > 0 else np.array([0.0, 0.0, 1.0])
        magnitude = magnitude if scale == 1.0 else magnitude * scale
        return [LammpsFix("precession/spin", f"zeeman {number_text(magnitude)} "
                          f"{vector_text(types.vector(direction))}")]

    def bind(self, system):
        h = self.energy_scale(system.conventions) * system.moments[:, None] * self.H[None, :]
        return (np.ascontiguousarray(h),)
