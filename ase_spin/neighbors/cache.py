"""The neighbour cache: one half Verlet list kept across calls with a skin, and
the terms' sub-lists filtered from it with a finer skin.

Two levels of skin. The sub-lists a term gets are filtered from the list at
their own cutoff plus a finer skin (:data:`FINE_SKIN` of it), at the positions
of their last filtering, and filtered again (one pass over the list's pairs)
when an atom has moved more than half the gap between the cutoff and the
closest pair left out (at least half the fine skin); the list itself is
rebuilt by the cell search (:mod:`ase_spin.neighbors.search`). A shell of
neighbours just beyond a term's cutoff then stays out of its list once thermal
motion has spread it across the cutoff plus the skin, and every pass of the
term (the midpoint sweeps, the force passes, the pair geometry) skips it. The
finer skin exists only for that saving: ``benchmarks/bench_langevin.py --warmup
300`` measures steps past the first rebuild (docs/benchmarks.md, "Throughput
and scaling").
"""

from __future__ import annotations


import numpy as np

from ..validate import ImplausibleParameterWarning, MIN_DISTANCE, warn_user
from .checks import MAX_IMAGES, check_cell, closest_pair, face_distances, largest_displacements
from .pairs import PairList
from .search import (filter_count, filter_fill, full_from_half, grid_half, half_from_full,
                     sweep_pairs, wrap_positions)

__all__ = ["NeighborCache", "FINE_SKIN"]

#: The sub-lists' skin as a fraction of the list's (see the module docstring):
#: half, so that they are filtered again about twice as often as the list would
#: be rebuilt.
FINE_SKIN = 0.5


class NeighborCache:
    """A half Verlet list at ``max(cutoffs) + skin``, rebuilt only when needed,
    and the terms' sub-lists at ``cutoff + fine_skin``, filtered from it.

    The list is rebuilt when an atom has moved more than ``skin / 2`` since the
    last build, or when the cell, the periodicity or the number of atoms
    changed; ``builds`` counts the builds. The sub-lists are filtered from it at
    the positions of their last filtering, :attr:`fine_reference`, with reach
    ``cutoff + fine_skin`` (plus twice the distance of the positions passed as
    ``also`` to :meth:`update`, which must stay covered too), and filtered again
    when an atom has moved more than :attr:`fine_radius` from there — half the
    gap between a sub-list's cutoff and the closest pair it left out, at least
    ``fine_skin / 2`` (``refilters`` counts the filterings that dropped a
    sub-list). Why both are safe: a pair not in the list was farther apart than
    ``max(cutoffs) + skin`` at the build and is still beyond ``max(cutoffs)``;
    a pair in the list but not in a sub-list is still beyond its cutoff.

    Only the half list (each pair once, 6 bytes a pair) and the positions of the
    build and of the filtering are kept: sub-lists at shorter cutoffs, for
    magnetic atoms, or full (each pair both ways) are derived on demand,
    recomputing the distances at those positions rather than storing them. The
    half list at the largest cutoff for all atoms is the list itself, shared.
    """

    def __init__(self, cutoff, skin=0.3, fine_skin=None):
        if not cutoff > 0.0:
            raise ValueError(f"neighbour-list cutoff must be positive, got {cutoff}")
        if not skin >= 0.0:
            raise ValueError(f"skin must be >= 0, got {skin}")
        fine_skin = FINE_SKIN * skin if fine_skin is None else fine_skin
        if not 0.0 <= fine_skin <= skin:
            raise ValueError(f"fine_skin must be between 0 and the skin ({skin}), "
                             f"got {fine_skin}")
        self.cutoff = float(cutoff)
        self.skin = float(skin)
        self.fine_skin = float(fine_skin)
        self._reference = None
        self._fine_reference = None
        self._margin = 0.0  # what the sub-lists' reach adds for `also`
        self._radii = {}  # per filtered sub-list (key as _sublists): see fine_radius
        self._cell = None
        self._pbc = None
        self._sublists = {}
        self.builds = 0
        self.refilters = 0
        self.half = None

    @property
    def pairs(self):
        """The full list (i → j and j → i) within cutoff + skin, made on first use."""
        if self.half is None:
            return None
        return self.sublist(self.cutoff)

    def __setstate__(self, state):
        self.__dict__.update(state)
        if "_cell_key" not in state:  # pickled by an older version: rebuild
            self._reference = None

    def invalidate(self):
        self._reference = None

    @property
    def reference(self):
        """Positions of the last build (None before one): the list itself
        stays valid while no atom is farther than ``skin / 2`` from here."""
        return self._reference

    @property
    def fine_radius(self):
        """How far from :attr:`fine_reference` an atom may move with the
        sub-lists still valid: for each, half the gap between its cutoff and
        the closest pair it left out (at least ``fine_skin / 2``; unbounded if
        it left none out, as on a perfect lattice whose next shell lies beyond
        the list); with none, ``fine_skin / 2`` (where the filtering positions
        move on, so that a sub-list made later holds where the atoms are)."""
        return min(self._radii.values(), default=0.5 * self.fine_skin)

    @property
    def fine_reference(self):
        """Positions the sub-lists were filtered at: they stay valid while no
        atom is farther than :attr:`fine_radius` from here (and the list
        itself is valid)."""
        return self._fine_reference

    def update(self, positions, cell, pbc, also=None):
        """Make the lists valid for ``positions`` (and for the positions
        ``also``, if given: e.g. the start of a step whose end is
        ``positions``); return True if the list was rebuilt or a sub-list
        filtered again (what was prepared from them is stale)."""
        positions = np.ascontiguousarray(positions, dtype=float)
        cell = np.asarray(cell, dtype=float)
        pbc = np.asarray(pbc, dtype=bool)
        if (self._reference is None or positions.shape != self._reference.shape
                or cell.tobytes() != self._cell_key or pbc.tobytes() != self._pbc_key):
            # a structure seen for the first time (or a new cell): its closest pair checked
            return self._build(positions, cell, pbc, also, check=True)
        # NaN positions: no rebuild, as before (the integrators report them)
        moved_since_build, moved = largest_displacements(positions, self._reference,
                                                         self._fine_reference)
        if moved_since_build > 0.5 * self.skin:
            return self._build(positions, cell, pbc, also)
        if not moved > self.fine_radius:
            return False
        # filter the sub-lists again here (lazily: on their next request)
        dropped = bool(self._radii)
        for key in self._radii:
            del self._sublists[key]
        self._radii = {}
        self._fine_reference = positions.copy()
        self._margin = self._also_margin(positions, also)
        self.refilters += dropped
        return dropped

    @staticmethod
    def _also_margin(positions, also):
        if also is None:
            return 0.0
        also = np.ascontiguousarray(also, dtype=float)
        return 2.0 * largest_displacements(also, positions, positions)[0]

    def _build(self, positions, cell, pbc, also, check=False):
        cell, pbc = check_cell(cell, pbc)
        # the old list and its sub-lists go before the new one is built
        self.half = None
        self._sublists = {}
        self._radii = {}
        n = len(positions)
        if n:
            row, j, image, ints = self._search_half(positions, cell, pbc)
        else:
            row, j = np.zeros(1, dtype=np.int64), np.zeros(0, dtype=np.int32)
            image, ints = np.zeros(0, dtype=np.int16), np.zeros((1, 3), dtype=np.int64)
        images = np.ascontiguousarray(ints @ cell)
        self.half = PairList(row, j, image, images, self.cutoff, half=True)
        self._ints = ints
        self._reference = self._fine_reference = positions.copy()
        self._margin = self._also_margin(positions, also)
        self._cell = cell.copy()
        self._pbc = pbc.copy()
        self._cell_key = np.asarray(self._cell, dtype=float).tobytes()
        self._pbc_key = np.asarray(self._pbc, dtype=bool).tobytes()
        self.builds += 1
        if check and n > 1:
            self._check_distances(positions)
        return True

    def _check_distances(self, positions):
        """ImplausibleParameterWarning when two atoms of a structure seen for the
        first time are closer than MIN_DISTANCE (Å): one pass over the list
        just built (not at the rebuilds of a run: atoms in a collision may
        come that close)."""
        half = self.half
        i, j, r, count = closest_pair(positions, half.row, half.j, half.image, half.images,
                                      MIN_DISTANCE)
        if count:
            others = f" ({count} pairs closer than {MIN_DISTANCE:g} Å)" if count > 1 else ""
            warn_user(ImplausibleParameterWarning(
                f"atoms {i} and {j} are {r:.3g} Å apart{others}: closer than "
                f"{MIN_DISTANCE:g} Å, where no two atoms of a solid or molecule are; "
                "a duplicated atom, or positions in other units than Å (nm, bohr, "
                "fractional coordinates given as Cartesian)?"))

    def _search_half(self, positions, cell, pbc):
        """The half list within cutoff + skin as (row, j, image, shifts table)
        with d_ij = r_j + S·cell − r_i for the positions as given (unwrapped):
        a cell list (:func:`grid_half`); boxes whose extent is not finite go
        to a sweep over atoms sorted along x."""
        reach = self.cutoff + self.skin
        periodic = np.flatnonzero(pbc)
        if periodic.size:
            faces = face_distances(cell, pbc)[periodic]
            images = float(np.prod(2.0 * np.ceil(reach / faces) + 1.0))
            if images > MAX_IMAGES:
                raise ValueError(
                    f"the cell is too small along its periodic directions for the cutoff "
                    f"{reach:.3g} Å (distances between faces {faces.round(6).tolist()} Å): "
                    f"each atom would see ~{images:.3g} periodic images of every other atom")
        found = grid_half(positions, cell, pbc, reach)
        if found is not None:
            return found
        wrapped, shift = wrap_positions(positions, cell, pbc)
        i, j, s = sweep_pairs(wrapped, cell, pbc, reach)
        if shift.any():
            s = s + shift[i] - shift[j]
        return half_from_full(i, j, s, len(positions))

    def _search(self, positions, cell, pbc):
        """All pairs within cutoff + skin as (i, j, integer shifts S), both ways,
        with d_ij = r_j + S·cell − r_i for the positions as given."""
        cell, pbc = check_cell(cell, pbc)
        row, j, image, ints = self._search_half(np.ascontiguousarray(positions, dtype=float),
                                                cell, pbc)
        row, j, image = full_from_half(row, j, image, len(ints))
        i = np.repeat(np.arange(len(row) - 1), np.diff(row))
        return i, j.astype(np.int64), ints[image]

    def sublist(self, cutoff, mask=None, half=False):
        """Pairs within ``cutoff + fine_skin`` at :attr:`reference`, between
        atoms where ``mask`` is True (all atoms if None); with ``half``, each
        unordered pair once (row of the smaller index). Cached until the next
        rebuild or filtering (:meth:`update`). At the largest cutoff for all
        atoms: the list itself (its reach, cutoff + skin), or its full form."""
        if mask is not None and mask.all():
            mask = None  # every atom: the same list as without a mask
        key = (float(cutoff), None if mask is None else mask.tobytes(), half)
        cached = self._sublists.get(key)
        if cached is not None:
            return cached
        master = self.half
        radius = None
        if cutoff >= self.cutoff and mask is None:
            row, j, image = master.row, master.j, master.image
        else:
            n = len(master.row) - 1
            row = np.zeros(n + 1, dtype=np.int64)
            m = np.zeros(0, dtype=np.bool_) if mask is None else np.ascontiguousarray(
                mask, dtype=np.bool_)
            reach = cutoff + self.fine_skin + self._margin
            nearest = np.empty(n)
            filter_count(self._fine_reference, master.row, master.j, master.image,
                          master.images, reach, m, row, nearest)
            # it holds until a pair left out can come within the cutoff
            # (nothing left out: as long as the list itself)
            radius = 0.5 * (nearest.min(initial=np.inf) - cutoff)
            np.cumsum(row, out=row)
            j = np.empty(row[-1], dtype=master.j.dtype)
            image = np.empty(row[-1], dtype=master.image.dtype)
            filter_fill(self._fine_reference, master.row, master.j, master.image,
                         master.images, reach, m, row, j, image)
        if half and j is master.j:
            sub = master  # shared, not copied: the list itself
        elif half:
            sub = PairList(row, j, image, master.images, float(cutoff), True)
        else:
            row, j, image = full_from_half(row, j, image, len(master.images))
            sub = PairList(row, j, image, master.images, float(cutoff), False)
        self._sublists[key] = sub
        if radius is not None:
            self._radii[key] = radius
        return sub

