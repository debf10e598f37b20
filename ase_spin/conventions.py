"""The sets of conventions a scene can follow: physical (default), LAMMPS SPIN's, the paper's.

A Hamiltonian (and the calculator over it) carries one :class:`Conventions`
record; the integrators take their ħ and precession rate from it unless given
explicitly. Only two things differ between the sets:

- the Zeeman energy of a moment μ_i (μB) in a field **H** (tesla):
  physical E = −μ_i μB s_i·H; LAMMPS's ``fix precession/spin zeeman``
  E = −2 μB' μ_i s_i·H, with its rounded μB' (μ_i read as a spin length);
- the precession: physical ds_i/dt = −(g/(μ_i ħ)) s_i × B_i, B_i = −∂E/∂s_i
  (the Landau–Lifshitz equation of a moment μ_i μB: the Larmor frequency
  g μB H/ħ in a field, whatever μ_i, as Spirit and UppASD integrate);
  LAMMPS's ``fix nve/spin`` ds_i/dt = −(1/ħ') s_i × B_i, no 1/μ_i, with its
  rounded ħ'.

Everything else (exchange, anisotropies, DMI, the lattice) is in eV and the
same in both. The paper's reduced units (ħ = 1 eV·(ASE time), rate 1, the
spin convention ds/dt = +(1/ħ) s × B) are a third set, for its chain.
"""

from __future__ import annotations

from typing import NamedTuple

from .constants import G_ELECTRON, HBAR, HBAR_LAMMPS, MU_B, MU_B_LAMMPS

__all__ = ["Conventions", "PHYSICAL", "LAMMPS", "PAPER", "conventions"]


class Conventions(NamedTuple):
    """A set of conventions.

    ``hbar``: ħ in eV·(ASE time). ``mu_B``: the Bohr magneton in eV/T.
    ``zeeman_g``: the factor of the Zeeman energy E = −g μB μ_i s·H.
    ``gyromagnetic``: "moment" (precession rate g/(μ_i ħ)) or "lammps"
    (1/ħ). ``g``: the g-factor of the "moment" precession. ``precession``:
    "moment" (ds/dt = −r s × B, the sense of a magnetic moment) or "spin"
    (+r s × B, the paper's).
    """

    name: str
    hbar: float
    mu_B: float
    zeeman_g: float
    gyromagnetic: str
    g: float
    precession: str = "moment"


#: CODATA constants (those of ``ase.units``), the electron's g-factor, the
#: energy of a moment in a field and Larmor precession.
PHYSICAL = Conventions("physical", HBAR, MU_B, 1.0, "moment", G_ELECTRON)

#: LAMMPS SPIN's equations and rounded constants (metal units), step for step.
LAMMPS = Conventions("lammps", HBAR_LAMMPS, MU_B_LAMMPS, 2.0, "lammps", 2.0)

#: The paper's reduced units: ħ = 1 eV·(ASE time), rate 1, spin convention.
PAPER = Conventions("paper", 1.0, MU_B, 1.0, "lammps", 1.0, "spin")

_BY_NAME = {c.name: c for c in (PHYSICAL, LAMMPS, PAPER)}


def conventions(value):
    """The :class:`Conventions` named by ``value`` ("physical", "lammps" or
    "paper"), or ``value`` itself if it is one."""
    if isinstance(value, Conventions):
        return value
    if isinstance(value, str) and value in _BY_NAME:
        return _BY_NAME[value]
    raise ValueError(f'conventions must be "physical", "lammps" or "paper", got {value!r}')
