"""A Hamiltonian as a list of terms, and its fast evaluation interface.

    E(r, s) = E_lattice(r) + E_spin(r, s)

:class:`Hamiltonian` holds the terms and splits them into the spin-independent
(lattice) part and the spin-dependent part. :meth:`Hamiltonian.bind` ties it to
one system (species, cell, periodicity, which atoms are magnetic) and returns an
:class:`Evaluator`: the interface integrators call instead of
``atoms.get_forces()``. An evaluator takes plain arrays (positions, unit spins),
never copies Atoms, keeps the neighbour list across calls with a Verlet skin,
and lets the spin-dependent part be re-evaluated from cached pair geometry while
only the spins change.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace

import numpy as np

from ._jit.threads import threads_for
from .conventions import conventions as as_conventions
from .neighbors import NeighborCache, all_finite
from .terms.ase_calculator import CalculatorTerm, is_ase_calculator
from .terms.base import Species, System, Term, Want
from .terms.parameters import parameter_generation
from .validate import real_scalar, robust_norm

__all__ = ["Hamiltonian", "Evaluator", "Want", "Evaluation", "AtomsTooCloseError"]


class AtomsTooCloseError(ValueError):
    """Atoms overlap or are so close that forces are not finite."""


@dataclass
class Evaluation:
    """Results of one evaluation; fields not asked for are None."""

    energy: float | None = None
    energy_terms: dict | None = None
    energies: np.ndarray | None = None
    forces: np.ndarray | None = None
    magnetic_forces: np.ndarray | None = None
    virial: np.ndarray | None = None  # Voigt xx yy zz yz xz xy, eV (= stress * volume)


class Hamiltonian:
    """A sum of terms, e.g. ``Hamiltonian([LennardJones(...), Exchange(...)])``.

    An ASE calculator among the terms (``[EMT(), Exchange(...)]``) is wrapped
    as :class:`~ase_spin.terms.ase_calculator.CalculatorTerm`, the lattice part.

    ``skin`` (Å) is the Verlet skin of the neighbour lists its evaluators keep.
    ``conventions``: "physical" (default) or "lammps", the Zeeman energy and
    the integrators' precession and ħ (:mod:`ase_spin.conventions`).
    """

    def __init__(self, terms, skin=0.3, *, conventions="physical"):
        if isinstance(terms, Term) or is_ase_calculator(terms):
            terms = [terms]
        # an ASE calculator (EMT(), ...) is the lattice term CalculatorTerm(calc)
        terms = tuple(CalculatorTerm(t) if not isinstance(t, Term) and is_ase_calculator(t)
                      else t for t in terms)
        for t in terms:
            if not isinstance(t, Term):
                raise TypeError(f"Hamiltonian terms must be ase_spin Term objects or ASE "
                                f"calculators, got {t!r:.80}")
        if not terms:
            raise ValueError("a Hamiltonian needs at least one term")
        skin = real_scalar(skin, "skin")
        if not skin >= 0.0:
            raise ValueError(f"skin must be >= 0 Å, got {skin}")
        self.terms = terms
        self.skin = skin
        self.conventions = as_conventions(conventions)
        names = [t.name for t in terms]
        self.term_names = [
            n if names.count(n) == 1 else f"{n}_{names[:k].count(n)}"
            for k, n in enumerate(names)
        ]
        #: range of the neighbour list (0: no term needs pairs, none is built)
        self.cutoff = max((t.cutoff for t in terms if t.neighbor_list), default=0.0)
        self._fingerprint = None

    def fingerprint(self):
        """Changes whenever a parameter of a term (or of a coupling in it) is
        reassigned: what bound tables and integrator states compare. Kept
        while no parameter anywhere has been assigned (parameter_generation):
        the ASE calculator asks at every property call."""
        generation = parameter_generation()
        kept = getattr(self, "_fingerprint", None)
        if kept is None or kept[0] != generation or kept[1] is not self.terms:
            kept = self._fingerprint = (generation, self.terms,
                                        tuple(t.fingerprint() for t in self.terms))
        return kept[2]

    @property
    def lattice_terms(self):
        return [t for t in self.terms if not t.spin_dependent]

    @property
    def spin_term_names(self):
        """Names (keys of the energy by term) of the spin-dependent terms."""
        return [n for t, n in zip(self.terms, self.term_names) if t.spin_dependent]

    @property
    def spin_terms(self):
        return [t for t in self.terms if t.spin_dependent]

    def bind(self, numbers, cell, pbc, moments):
        """An :class:`Evaluator` for a system with these atomic numbers (or
        symbols), cell, periodicity and moment magnitudes μ_i (μB; zero for a
        non-magnetic atom; a boolean mask means 1 μB on the True atoms)."""
        return Evaluator(self, numbers, cell, pbc, moments)

    def __repr__(self):
        return (f"Hamiltonian({self.terms!r}, skin={self.skin}, "
                f"conventions={self.conventions.name!r})")


def _symbols(numbers):
    from ase.data import chemical_symbols

    numbers = np.asarray(numbers)
    if numbers.dtype.kind in "iu":
        return [chemical_symbols[z] for z in numbers]
    return [str(s) for s in numbers]


def _sized(method):
    """Run the kernels of an Evaluator method threaded, or serially for a small
    system (see ase_spin._jit.threads)."""

    @functools.wraps(method)
    def run(self, *args, **kwargs):
        with threads_for(self.natoms):
            return method(self, *args, **kwargs)

    return run


class Evaluator:
    """A :class:`Hamiltonian` bound to one system.

    The fast path for integrators:

    - :meth:`lattice` — energy / forces / virial of the spin-independent terms;
    - :meth:`spin_operators` — every spin term prepared at given positions, as
      a :class:`~ase_spin.terms.base.SpinOperator` whose magnetic forces for any
      spins cost one pass (for exchange: the pair geometry J(r_ij),
      J'(r_ij) d_ij/r_ij is cached in it; single-site terms need nothing);
    - :meth:`spin` — magnetic forces, lattice forces and energy of the spin
      terms for given spins from such operators, without touching distances;
    - :meth:`evaluate` — all of it at once (what the ASE calculator calls).

    Positions are (N, 3) Cartesian Å; spins are (N, 3) unit directions with zero
    rows for non-magnetic atoms. ``refresh`` keeps the neighbour list valid; it
    is called by the methods that take positions.
    """

    def __init__(self, hamiltonian, numbers, cell, pbc, moments):
        self.hamiltonian = hamiltonian
        self.species = Species.from_symbols(_symbols(numbers))
        self.types = self.species.types
        self.natoms = len(self.types)
        self._generation = parameter_generation()
        self._fingerprint = hamiltonian.fingerprint()
        # a scene whose terms need no pairs (single-site terms only) builds no list
        self.neighbors = (NeighborCache(hamiltonian.cutoff, hamiltonian.skin)
                          if hamiltonian.cutoff > 0.0 else None)
        self._changes = 0
        self.cell = self.pbc = self.moments = None
        self.set_cell(cell, pbc, bind=False)
        self.set_moments(moments)

    def stale(self):
        """True if a parameter of the Hamiltonian changed since this was bound
        (then its tables and cutoffs are out of date: bind again)."""
        generation = parameter_generation()
        if generation == self._generation:
            return False
        if self.hamiltonian.fingerprint() != self._fingerprint:
            return True
        self._generation = generation  # something else changed
        return False

    @property
    def state_token(self):
        """Changes whenever the cell, periodicity, moments or pair list change:
        what a holder of prepared operators compares."""
        if self.neighbors is None:
            return (self._changes, 0, 0)
        return (self._changes, self.neighbors.builds, self.neighbors.refilters)

    # -- system state -----------------------------------------------------
    def set_cell(self, cell, pbc, bind=True):
        cell = np.array(cell, dtype=float).reshape(3, 3)
        pbc = np.array(pbc, dtype=bool).reshape(3) if np.ndim(pbc) else np.array([pbc] * 3)
        _check_periodic_cell(cell, pbc)
        self.cell, self.pbc = cell, pbc
        if self.neighbors is not None:
            self.neighbors.invalidate()
        self._changes += 1
        if bind:
            self._bind()

    def set_moments(self, moments):
        """Moment magnitudes μ_i (μB, zero: non-magnetic; a boolean mask: 1 μB)."""
        moments = np.asarray(moments)
        if moments.shape != (self.natoms,):
            raise ValueError(f"moments must have shape ({self.natoms},), got {moments.shape}")
        self.moments = np.array(moments, dtype=float)
        self.magnetic = self.moments > 0.0
        self.any_magnetic = bool(self.magnetic.any())
        self._changes += 1
        self._bind()

    def _bind(self):
        self.system = System(self.species, self.moments, self.cell, self.pbc,
                             self.hamiltonian.conventions)
        self._tables = [t.bind(self.system) for t in self.hamiltonian.terms]

    def refresh(self, positions, also=None):
        """Make the pair lists valid for ``positions`` (and ``also``, other
        positions the lists will be used at, e.g. a step's start); True if a
        list changed (rebuilt, or a term's sub-list filtered again: what was
        prepared from them must be prepared again)."""
        if self.neighbors is None:
            return False
        return self.neighbors.update(positions, self.cell, self.pbc, also)

    def _pairs(self, term, half=False):
        if not term.neighbor_list:
            return None
        mask = self.magnetic if term.spin_dependent else None
        return self.neighbors.sublist(term.cutoff, mask, half)

    @property
    def skin(self):
        """The neighbour list's skin (Å); inf without a list (nothing to outrun)."""
        return np.inf if self.neighbors is None else self.neighbors.skin

    @property
    def volume(self):
        return abs(np.linalg.det(self.cell))

    # -- the fast interface -------------------------------------------------
    @_sized
    def lattice(self, positions, want, forces=None, energies=None):
        """Spin-independent terms at ``positions``.

        Forces (and per-atom energies) are *added* to ``forces``/``energies``
        when given, else returned in new arrays.
        """
        positions = _as_positions(positions, self.natoms)
        self.refresh(positions)
        ev = _new_evaluation(self.natoms, want, forces, energies)
        terms = self.hamiltonian.terms
        for t, name, table in zip(terms, self.hamiltonian.term_names, self._tables):
            if t.spin_dependent:
                continue
            e, w = t.compute(positions, self._pairs(t, half=True), self.types, table,
                             ev.forces if want.forces else _NO_ARRAY,
                             ev.energies if want.energies else _NO_ENERGIES, want)
            _accumulate(ev, name, e, w, want)
        _check_finite(ev, positions, self.neighbors)
        return ev

    @_sized
    def spin_operators(self, positions, virial=False, out=None, mean_with=None, half=False,
                       refreshed=False):
        """Every spin term prepared at ``positions`` (a list of
        :class:`~ase_spin.terms.base.SpinOperator`, one per spin term).
        ``out``: a previous result whose buffers are reused; ``mean_with``: the
        operators at the other end of a step, on the same pair lists, for the
        midpoint field ``field(W, out, mean=True)``. ``half``: pair terms on the
        half pair list (each pair once: half the work and memory; passes over
        it scatter into per-thread buffers) rather than the full one.
        ``refreshed``: the caller has just called :meth:`refresh` with these
        positions, or as its ``also`` (the pair lists' check, a pass over the
        atoms, is not repeated: with other positions it could filter the lists
        again for these alone)."""
        positions = _as_positions(positions, self.natoms)
        if not refreshed:
            self.refresh(positions)
        ops = []
        k = 0
        for t, table in zip(self.hamiltonian.terms, self._tables):
            if not t.spin_dependent:
                continue
            previous = out[k] if out is not None else None
            other = mean_with[k] if mean_with is not None else None
            ops.append(t.prepare(positions, self._pairs(t, half=half), self.types, table,
                                 virial=virial, out=previous, mean_with=other))
            k += 1
        return ops

    @_sized
    def spin(self, operators, spins, want, magnetic_forces=None, forces=None,
             energies=None):
        """Spin-dependent terms for unit ``spins`` from prepared ``operators``.

        Magnetic forces B_i = −∂E/∂s_i (eV), forces, energies are *added* into
        the given arrays when given, else returned in new arrays.
        """
        ev = _new_evaluation(self.natoms, want, forces, energies)
        if want.magnetic_forces:
            ev.magnetic_forces = (np.zeros((self.natoms, 3)) if magnetic_forces is None
                                  else magnetic_forces)
        b = ev.magnetic_forces if want.magnetic_forces else _NO_ARRAY
        f = ev.forces if want.forces else _NO_ARRAY
        energies = ev.energies if want.energies else _NO_ENERGIES
        for name, op in zip(self.hamiltonian.spin_term_names, operators):
            e, w = op.add(spins, want, b, f, energies)
            _accumulate(ev, name, e, w, want)
        return ev

    @_sized
    def evaluate(self, positions, spins, want):
        """Everything ``want`` asks for, lattice and spin parts together."""
        positions = _as_positions(positions, self.natoms)
        spins = np.ascontiguousarray(spins, dtype=float)
        if spins.shape != (self.natoms, 3):
            raise ValueError(f"spins must have shape ({self.natoms}, 3), got {spins.shape}")
        ev = self.lattice(positions, replace(want, magnetic_forces=False))
        ev.magnetic_forces = np.zeros((self.natoms, 3)) if want.magnetic_forces else None
        if self.any_magnetic:
            b = ev.magnetic_forces if want.magnetic_forces else _NO_ARRAY
            f = ev.forces if want.forces else _NO_ARRAY
            energies = ev.energies if want.energies else _NO_ENERGIES
            for t, name, table in zip(self.hamiltonian.terms, self.hamiltonian.term_names,
                                      self._tables):
                if t.spin_dependent:
                    e, w = t.compute(positions, self._pairs(t, half=True), self.types,
                                     table, spins, b, f, energies, want)
                    _accumulate(ev, name, e, w, want)
            _check_finite(ev, positions, self.neighbors)
        if want.energy:
            for name in self.hamiltonian.term_names:
                ev.energy_terms.setdefault(name, 0.0)
        return ev


_NO_ARRAY = np.zeros((0, 3))
_NO_ENERGIES = np.zeros(0)


def _check_periodic_cell(cell, pbc):
    """A periodic direction needs its cell vector: non-zero, and independent of
    the other periodic ones, |det(v̂_a v̂_bᵀ)|^½ > 1e-10 for the unit periodic
    vectors (else ValueError naming them)."""
    if not pbc.any():
        return
    axes = np.flatnonzero(pbc)
    vectors = cell[axes]
    if not np.isfinite(vectors).all():
        return  # the neighbour search names non-finite cells
    lengths = robust_norm(vectors)
    # the volume (area, length) they span relative to the product of their
    # lengths: the sine of the angles, scale-free (a 1e8 Å vector is fine)
    if (lengths > 0.0).all():
        unit = vectors / lengths[:, None]
        spanned = np.sqrt(max(np.linalg.det(unit @ unit.T), 0.0))
    else:
        spanned = 0.0
    if not spanned > 1e-10:
        names = "".join("abc"[a] for a in axes)
        raise ValueError(
            f"the atoms are periodic along {names} (pbc={pbc.tolist()}) but the cell "
            f"vectors {names} are {'zero' if not vectors.any() else 'degenerate'} "
            f"(cell={cell.tolist()}): set a cell (atoms.cell = ..., e.g. from "
            "ase.build) or make those directions non-periodic (atoms.pbc = False)")


def _as_positions(positions, n):
    positions = np.ascontiguousarray(positions, dtype=float)
    if positions.shape != (n, 3):
        raise ValueError(f"positions must have shape ({n}, 3), got {positions.shape}")
    if not all_finite(positions):
        bad = np.flatnonzero(~np.isfinite(positions).all(axis=1))
        raise ValueError(f"positions are not finite for atoms {bad[:10].tolist()}")
    return positions


def _new_evaluation(n, want, forces, energies):
    ev = Evaluation()
    if want.energy:
        ev.energy = 0.0
        ev.energy_terms = {}
    if want.forces:
        ev.forces = np.zeros((n, 3)) if forces is None else forces
    if want.energies:
        ev.energies = np.zeros(n) if energies is None else energies
    if want.virial:
        ev.virial = np.zeros(6)
    return ev


def _accumulate(ev, name, e, w, want):
    e = float(e)
    if want.energy:
        ev.energy += e
        ev.energy_terms[name] = ev.energy_terms.get(name, 0.0) + e
    if want.virial:
        ev.virial += w


def _check_finite(ev, positions, neighbors):
    """Turn a NaN/inf in any result into an error: atoms on top of each other
    (named, the closest pair) or, failing that, parameters that overflow."""
    parts = {"forces": ev.forces, "per-atom energies": ev.energies,
             "magnetic forces": ev.magnetic_forces, "stress": ev.virial,
             "energy": None if ev.energy is None else np.array([ev.energy])}
    bad_parts = [name for name, x in parts.items()
                 if x is not None and not (all_finite(x) if x.ndim == 2 else np.isfinite(x).all())]
    if not bad_parts:
        return
    what = " and ".join(bad_parts)
    pairs = None if neighbors is None else neighbors.pairs
    if pairs is None or len(pairs) == 0:
        raise ValueError(f"non-finite {what}: check the terms' parameters")
    i = pairs.i
    d = np.linalg.norm(positions[pairs.j] + pairs.shift - positions[i], axis=1)
    k = int(np.argmin(d))
    where = f"closest pair: atoms {i[k]} and {pairs.j[k]} at r = {d[k]:.3g} Å"
    if d[k] < _TOO_CLOSE:
        raise AtomsTooCloseError(
            f"non-finite {what}: atoms overlap or are unphysically close; {where}")
    raise ValueError(f"non-finite {what} ({where}): check the terms' parameters")


#: Below this distance (Å) a non-finite result is blamed on the atoms' positions.
_TOO_CLOSE = 0.1
