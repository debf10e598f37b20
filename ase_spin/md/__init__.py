"""Integrators for spin–lattice dynamics (ASE ``MolecularDynamics``)."""

from .collective import HBAR, CollectivePRK, SpinConvergenceError
from .compositions import COMPOSITIONS
from .logger import SpinMDLogger

__all__ = ["CollectivePRK", "SpinConvergenceError", "SpinMDLogger", "HBAR", "COMPOSITIONS"]
