"""Physical constants in the units this package uses (ASE's: eV, Å, ASE time, tesla).

One name for each constant, each in these units. ħ appears in the spin
equation of motion; LAMMPS metal units carry their own rounded ħ and μB, which
a side-by-side comparison must use (see :mod:`ase_spin.conventions`).
"""

from __future__ import annotations

import math

from ase import units

__all__ = ["HBAR", "HBAR_LAMMPS", "MU_B", "MU_B_LAMMPS", "G_ELECTRON"]

#: ħ in eV·(ASE time unit), CODATA (the set ase.units uses).
HBAR = units._hbar / units._e * units.s

#: LAMMPS's ħ in eV·(ASE time unit): metal units' ``force->hplanck / 2π``
#: = 4.135667403e-3/2π eV·ps, 6.3e-8 relative below CODATA.
HBAR_LAMMPS = 4.135667403e-3 / (2.0 * math.pi) * 1000.0 * units.fs

#: The Bohr magneton eħ/2mₑ in eV/T, CODATA (the set ase.units uses).
MU_B = units._hbar / (2.0 * units._me)

#: The Bohr magneton LAMMPS SPIN uses (``fix precession/spin``), eV/T.
MU_B_LAMMPS = 5.78901e-5

#: The magnitude of the electron's g-factor, CODATA 2014 (the set ase.units
#: uses): the Larmor frequency of a moment is G_ELECTRON·MU_B·H/HBAR.
G_ELECTRON = 2.00231930436182
