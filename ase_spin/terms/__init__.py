"""Hamiltonian terms: each states its energy and computes, over a pair list,
energy, forces, magnetic forces (spin terms) and virial."""

from .ase_calculator import CalculatorTerm
from .anisotropy import CubicAnisotropy, UniaxialAnisotropy
from .biquadratic import BiquadraticExchange
from .dipolar import DIPOLAR_CODATA, DIPOLAR_LAMMPS, Dipolar
from .dmi import DMI
from .base import SingleSiteTerm, SpinOperator, SpinTerm, Term
from .eam import EAM
from .couplings import BetheSlater, Coupling, Cubic
from .exchange import Exchange, ExchangeOperator
from .lennard_jones import LennardJones
from .neel import Neel
from .pair_couplings import PairCouplings
from .tabulated import ShellExchange, Tabulated
from .zeeman import Zeeman

__all__ = ["CalculatorTerm", "Term", "SpinTerm", "SingleSiteTerm", "SpinOperator", "LennardJones", "Exchange",
           "Coupling", "BetheSlater", "Cubic", "ExchangeOperator", "Zeeman",
           "UniaxialAnisotropy", "CubicAnisotropy", "DMI", "Dipolar", "DIPOLAR_CODATA",
           "DIPOLAR_LAMMPS",
           "BiquadraticExchange", "Tabulated", "ShellExchange", "EAM", "Neel", "PairCouplings"]
