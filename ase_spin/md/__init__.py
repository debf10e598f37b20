"""Integrators for spin–lattice dynamics (ASE ``MolecularDynamics``)."""

from ..constants import HBAR
from .base import SpinLatticeDynamics
from .collective import CollectivePRK
from .compositions import COMPOSITIONS
from .errors import IntegrationError, SpinConvergenceError, UnstableStepError
from .langevin import Langevin
from .relax import relax_spins
from .logger import SpinMDLogger
from .montecarlo import MonteCarlo
from .splitting import SuzukiTrotter

__all__ = ["SpinLatticeDynamics", "CollectivePRK", "IntegrationError", "SpinConvergenceError", "UnstableStepError", "SpinMDLogger", "SuzukiTrotter", "HBAR", "COMPOSITIONS", "Langevin", "relax_spins", "MonteCarlo"]
