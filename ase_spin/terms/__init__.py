"""Hamiltonian terms: each states its energy and computes, over a pair list,
energy, forces, magnetic forces (spin terms) and virial."""

from .base import Term
from .exchange import BetheSlater, Coupling, Cubic, Exchange, ExchangeOperator
from .lennard_jones import LennardJones

__all__ = ["Term", "LennardJones", "Exchange", "Coupling", "BetheSlater", "Cubic",
           "ExchangeOperator"]
