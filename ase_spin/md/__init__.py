"""Integrators for spin–lattice dynamics (ASE ``MolecularDynamics``)."""

from .collective import (HBAR, CollectivePRK, IntegrationError, SpinConvergenceError,
                         UnstableStepError)
from .compositions import COMPOSITIONS
from .logger import SpinMDLogger
from .splitting import SuzukiTrotter

__all__ = ["CollectivePRK", "IntegrationError", "SpinConvergenceError", "UnstableStepError", "SpinMDLogger", "SuzukiTrotter", "HBAR", "COMPOSITIONS"]
