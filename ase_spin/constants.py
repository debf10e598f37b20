"""Physical constants in the units this package uses (ASE's: eV, Å, ASE time).

ħ appears in the spin equation of motion, ds/dt = (σ/ħ) s × B; LAMMPS metal
units carry their own rounded value, which a side-by-side comparison must use.
"""

from __future__ import annotations

import math

from ase import units

__all__ = ["HBAR", "HBAR_LAMMPS", "LAMMPS_HBAR_EV_PS", "MU_B", "MU_B_LAMMPS"]

#: ħ in eV·(ASE time unit), from CODATA via ase.units.
HBAR = units._hbar / units._e * units.s

#: ħ of LAMMPS metal units (``force->hplanck / 2π``) in eV·ps.
LAMMPS_HBAR_EV_PS = 4.135667403e-3 / (2.0 * math.pi)

#: LAMMPS's ħ in eV·(ASE time unit): pass ``hbar=HBAR_LAMMPS`` to follow LAMMPS
#: step for step.
HBAR_LAMMPS = LAMMPS_HBAR_EV_PS * 1000.0 * units.fs

#: The Bohr magneton in eV/T (CODATA via ase.units): eħ/2mₑ.
MU_B = units._hbar / (2.0 * units._me)

#: The Bohr magneton LAMMPS SPIN uses (``fix precession/spin``), eV/T.
MU_B_LAMMPS = 5.78901e-5
