"""Verlet pair lists built by a compiled cell list and kept across calls with a skin.

A :class:`NeighborCache` holds one *half* pair list (each pair once, in the row
of its smaller index) at the largest cutoff any term needs plus a skin, in
compressed-row form, rows sorted by (j, image shift). Terms ask it for sub-lists
at their own cutoffs (and, for spin terms, restricted to magnetic atoms), half
or full; the list at the largest cutoff is shared, not copied. Distances are never stored: kernels
recompute d_ij = r_j + S_ij − r_i from the current positions and the pair's
Cartesian image shift S_ij, so a list stays valid until some atom has moved more
than half the skin from where it was when the list was built.

Two shapes of list serve two kinds of kernel:

- *half* lists (each pair once) for one-off evaluations of energy, forces and
  magnetic forces: threads take runs of rows of equal pair count and scatter
  into per-thread buffers summed at the end. Half the pair work of a full list,
  and half the exp() calls of a Bethe–Slater J(r).
- *full* lists (i→j and j→i, rows sorted by j) for passes that only gather
  into row i, such as B_i = Σ_j J_ij s_j from cached pair geometry: no buffers,
  no reduction, threads over atoms.

The modules: :mod:`~ase_spin.neighbors.pairs` (the lists, their colouring),
:mod:`~ase_spin.neighbors.checks` (displacements, finiteness, the cell, the pair
separation), :mod:`~ase_spin.neighbors.search` (the compiled search and
filtering), :mod:`~ase_spin.neighbors.cache` (the cache with its two skins).
"""

from .cache import FINE_SKIN, NeighborCache
from .checks import (MAX_IMAGES, all_finite, check_cell, face_distances, largest_displacements,
                     max_displacement, separation)
from .pairs import PairList, greedy_colouring, group_by_key, rows_in_order
from .search import sweep_pairs, wrap_positions

__all__ = ["PairList", "NeighborCache", "FINE_SKIN", "MAX_IMAGES", "all_finite", "check_cell",
           "face_distances", "greedy_colouring", "group_by_key", "largest_displacements",
           "max_displacement", "rows_in_order", "separation", "sweep_pairs", "wrap_positions"]
