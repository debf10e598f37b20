"""ase_spin: coupled spin–lattice dynamics for the Atomic Simulation Environment."""

from ._jit import cache as _compilation  # noqa: F401 - announces first-use compilation
from .analysis import (StructureFactorRecorder, dynamical_structure_factor, magnon_bands, q_path,
                       read_spin_series)
from .calculator import SpinLatticeCalculator
from .analysis import (Fluctuations, SpinCorrelation, SpinTemperature, SublatticeMagnetisation,
                       TopologicalCharge, binder_crossing, block_average, topological_charge)
from .constants import G_ELECTRON, HBAR_LAMMPS, MU_B, MU_B_LAMMPS
from .constraints import FixSpins
from .hamiltonian import AtomsTooCloseError, Evaluator, Hamiltonian
from .interop.lammps import write_lammps
from .interop.lammps_dump import read_lammps_spin_dump
from .interop.symmetry import magnetic_symmetry, neighbor_shells
from .interop.pair_file import read_pairs, write_pairs
from .interop.tb2j import read_tb2j, read_tb2j_pairs
from .io.trajectories import complete_frames, recover_trajectory
from .io.viewing import plot_spins, spin_colors, write_ovito_xyz
from .md import (HBAR, CollectivePRK, IntegrationError, Langevin, MonteCarlo, SpinConvergenceError,
                 SpinLatticeDynamics, SpinMDLogger, SuzukiTrotter, UnstableStepError, relax_spins)
from .optimize import GNEB, HTST, SpinLatticeFilter, SpinLBFGS, SpinVP
from .spins import get_moments, get_spins, set_spins
from .terms import (DIPOLAR_CODATA, DIPOLAR_LAMMPS, DMI, EAM, BetheSlater, BiquadraticExchange,
                    CalculatorTerm, Coupling, Cubic, CubicAnisotropy, Dipolar, Exchange, LennardJones, Neel,
                    PairCouplings, ShellExchange, Tabulated, Term,
                    UniaxialAnisotropy, Zeeman)
from .terms.base import Want
from .validate import ImplausibleParameterWarning

__version__ = "0.1.0"

__all__ = [
    "SpinLatticeCalculator", "Hamiltonian", "Evaluator", "Want", "AtomsTooCloseError",
    "ImplausibleParameterWarning",
    "set_spins", "get_spins", "get_moments", "FixSpins",
    "CollectivePRK", "SuzukiTrotter", "SpinLatticeDynamics", "IntegrationError",
    "SpinConvergenceError", "UnstableStepError", "Langevin", "relax_spins", "SpinMDLogger", "HBAR", "HBAR_LAMMPS", "MU_B", "MU_B_LAMMPS", "G_ELECTRON",
    "recover_trajectory", "complete_frames", "write_lammps", "read_lammps_spin_dump",
    "Term", "LennardJones", "Exchange", "Coupling", "BetheSlater", "Cubic", "Zeeman",
    "UniaxialAnisotropy", "CubicAnisotropy", "DMI", "BiquadraticExchange", "CalculatorTerm", "EAM",
    "Dipolar", "DIPOLAR_CODATA", "DIPOLAR_LAMMPS", "Neel", "PairCouplings",
    "Tabulated", "ShellExchange", "neighbor_shells", "magnetic_symmetry", "read_tb2j",
    "read_tb2j_pairs", "read_pairs", "write_pairs",
    "write_ovito_xyz", "spin_colors", "plot_spins",
    "SpinLBFGS", "SpinVP", "SpinLatticeFilter", "GNEB", "HTST",
    "q_path", "StructureFactorRecorder", "read_spin_series", "dynamical_structure_factor",
    "magnon_bands",
    "MonteCarlo", "Fluctuations", "SpinCorrelation", "SpinTemperature", "SublatticeMagnetisation",
    "TopologicalCharge", "binder_crossing", "block_average", "topological_charge",
]
