"""Energy landscapes of spins and spin–lattice systems: minimisers (ground and
metastable states), joint spin–lattice relaxation with ASE's optimizers, and
minimum energy paths with their barriers (geodesic nudged elastic band).
See docs/landscapes.md."""

from ..md.relax import relax_spins
from . import sphere
from .base import SpinOptimizer
from .filter import SpinLatticeFilter
from .gneb import GNEB
from .htst import HTST, HTSTResult
from .lbfgs import SpinLBFGS
from .path import hermite_path, path_maximum
from .vp import SpinVP

__all__ = ["SpinOptimizer", "SpinLBFGS", "SpinVP", "SpinLatticeFilter", "GNEB", "HTST",
           "HTSTResult", "relax_spins", "sphere", "hermite_path", "path_maximum"]
