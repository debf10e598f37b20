"""ase_spin: coupled spin–lattice dynamics for the Atomic Simulation Environment."""

from . import compilation as _compilation  # noqa: F401 - announces first-use compilation
from .calculator import SpinLatticeCalculator
from .hamiltonian import AtomsTooCloseError, Evaluator, Hamiltonian, Want
from .constants import HBAR_LAMMPS, MU_B, MU_B_LAMMPS
from .io import complete_frames, recover_trajectory
from .lammps import read_lammps_spin_dump, write_lammps
from .md import (HBAR, CollectivePRK, IntegrationError, SpinConvergenceError,
                 SpinLatticeDynamics, SpinMDLogger, SuzukiTrotter, UnstableStepError,
                 Langevin, relax_spins)
from .spins import get_moments, get_spins, set_spins
from .viewing import plot_spins, spin_colors, write_ovito_xyz
from .terms import (BetheSlater, BiquadraticExchange, CalculatorTerm, Coupling, Cubic, Exchange, LennardJones, Term,
                    CubicAnisotropy, DMI, EAM, UniaxialAnisotropy, Zeeman)
from .terms import ShellExchange, Tabulated
from .symmetry import magnetic_symmetry, neighbor_shells
from .tb2j import read_tb2j

__version__ = "0.1.0"

__all__ = [
    "SpinLatticeCalculator", "Hamiltonian", "Evaluator", "Want", "AtomsTooCloseError",
    "set_spins", "get_spins", "get_moments",
    "CollectivePRK", "SuzukiTrotter", "SpinLatticeDynamics", "IntegrationError",
    "SpinConvergenceError", "UnstableStepError", "Langevin", "relax_spins", "SpinMDLogger", "HBAR", "HBAR_LAMMPS", "MU_B", "MU_B_LAMMPS",
    "recover_trajectory", "complete_frames", "write_lammps", "read_lammps_spin_dump",
    "Term", "LennardJones", "Exchange", "Coupling", "BetheSlater", "Cubic", "Zeeman",
    "UniaxialAnisotropy", "CubicAnisotropy", "DMI", "BiquadraticExchange", "CalculatorTerm", "EAM",
    "Tabulated", "ShellExchange", "neighbor_shells", "magnetic_symmetry", "read_tb2j",
    "write_ovito_xyz", "spin_colors", "plot_spins",
]
