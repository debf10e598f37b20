"""The ASE calculator: a thin facade over :class:`~ase_spin.hamiltonian.Evaluator`."""

from __future__ import annotations


import numpy as np
from ase.calculators.calculator import Calculator, PropertyNotImplementedError, all_changes, equal

from .conventions import conventions as as_conventions
from .hamiltonian import AtomsTooCloseError, Hamiltonian
from .serialize import decode_term, encode_term
from .spins import get_moments, split_moments
from .terms.base import Want
from .validate import warn_user

__all__ = ["SpinLatticeCalculator", "NoMomentsWarning"]


class NoMomentsWarning(UserWarning):
    """The Hamiltonian has spin terms but the atoms carry no magnetic moments."""


def _warn_no_moments(hamiltonian, mu):
    """Atoms read from a structure file usually carry no moments: with spin
    terms in the Hamiltonian that silently gives a non-magnetic system."""
    spin_terms = hamiltonian.spin_term_names
    if spin_terms and len(mu) and not (mu > 0.0).any():
        warn_user(
            f"the Hamiltonian has spin terms ({', '.join(spin_terms)}) but the atoms "
            "carry no magnetic moments, so these terms contribute nothing and no spin "
            "moves: set spins with ase_spin.set_spins(atoms, directions, magnitudes)",
            NoMomentsWarning)


def _system_changes(old, new, tol, ignored):
    """ASE's ``compare_atoms(old, new, tol, ignored)``: which of ASE's
    ``all_changes`` differ by more than ``tol`` (or exist in one only), the
    same list, each property first compared for exact equality, which is what
    an unchanged property is. ASE's own comparison (``np.allclose`` per
    property, at each of the three calls energy, forces, magnetic forces)
    cost more than the evaluation of a small system itself; the exact check
    first exists only for speed (``benchmarks/bench_calculator.py --parts``;
    docs/benchmarks.md, "Why each fast path exists")."""
    if old is None:
        return list(all_changes)
    check = [p for p in all_changes if p not in ignored]
    changes = []
    for prop in ("cell", "pbc"):
        if prop in check:
            a, b = getattr(old, prop), getattr(new, prop)
            a = a.array if prop == "cell" else a
            b = b.array if prop == "cell" else b
            if not (np.array_equal(a, b) or equal(a, b, atol=tol)):
                changes.append(prop)
    for prop in check:
        if prop in ("cell", "pbc"):
            continue
        a, b = old.arrays.get(prop), new.arrays.get(prop)
        if a is None and b is None:
            continue
        if a is None or b is None or not (
                (a.shape == b.shape and np.array_equal(a, b)) or equal(a, b, atol=tol)):
            changes.append(prop)
    return changes


#: Moment magnitudes closer than this (relative) to those bound are the same
#: moments: an integrator writes μ_i s_i back with |s_i| = 1 to round-off, and
#: |μ_i s_i| then differs from μ_i in its last bits (a few 1e-16).
MAGNITUDE_RTOL = 1e-14


def _same_magnitudes(bound, mu):
    """Whether the magnitudes ``mu`` read from the Atoms are those the evaluator
    is bound to, up to the last bits of a written-back μ_i s_i: then it is kept
    as it is, and an integrator holding it goes on from its own state (reading
    them afresh would change its moments in their last bits and make it start
    over: a calculation between two runs, or in an observer, would change the
    trajectory)."""
    if np.array_equal(bound, mu):
        return True
    if bound.shape != mu.shape or not np.array_equal(bound > 0.0, mu > 0.0):
        return False
    return bool(np.all(np.abs(mu - bound) <= MAGNITUDE_RTOL * bound))


class SpinLatticeCalculator(Calculator):
    """ASE calculator for a spin–lattice Hamiltonian.

    Parameters
    ----------
    terms : list of Term, or Hamiltonian
        e.g. ``[LennardJones(0.4, 2.2742, 4.7, cutoff="shift"),
        Exchange(BetheSlater(0.0446928, 0.003496, 1.4885), rc=4.0)]``.
    skin : float
        Verlet skin (Å) of the neighbour list kept between calls.
    conventions : "physical" (default), "lammps" or "paper"
        The Zeeman energy and the integrators' default precession and ħ
        (:mod:`ase_spin.conventions`): physical by default (−μ_i μB s·H, Larmor
        precession, CODATA); "lammps" follows LAMMPS SPIN step for step.

    Spins are read from ``atoms`` (``initial_magmoms``, (N, 3), see
    :func:`ase_spin.set_spins`). Properties:

    - ``energy``, ``free_energy`` (eV), ``energies`` (eV per atom),
      ``forces`` (eV/Å), ``stress`` (eV/Å³, Voigt, ASE's sign: ∂E/∂ε / V);
    - ``magnetic_forces``: B_i = −∂E/∂s_i (eV) with s_i the unit direction,
      the effective field in energy units (LAMMPS's ``fm`` is B/ħ); zero rows
      for non-magnetic atoms;
    - ``magmoms``: the (N, 3) moment vectors μ_i s_i;
    - ``magmom``: ASE's total moment, a scalar: |Σ_i μ_i s_i| (μB), the length
      of the total moment (whatever its direction; the vector is
      :meth:`get_magnetic_moment_vector`, ``results['magmom_vector']``).

    ``results['energy_terms']`` splits the energy by term. Energy, forces and
    magnetic forces come from one pass whenever any of them is asked for (as
    ASE's own calculators compute energy and forces together: an optimiser or
    ASE's MD asks for both every step); per-atom energies and stress only
    when asked for.
    """

    implemented_properties = ["energy", "free_energy", "energies", "forces", "stress",
                              "magmoms", "magmom", "magnetic_forces"]
    nolabel = True

    def __init__(self, terms, skin=0.3, *, conventions=None, label=None, atoms=None,
                 directory="."):
        # no **kwargs: ASE's Calculator would store a misspelt keyword and ignore it
        if isinstance(terms, Hamiltonian):
            if conventions is not None and as_conventions(conventions) != terms.conventions:
                raise ValueError(f"conventions={conventions!r} differ from the given "
                                 f"Hamiltonian's ({terms.conventions.name!r})")
            self.hamiltonian = terms
        else:
            self.hamiltonian = Hamiltonian(terms, skin, conventions=conventions or "physical")
        super().__init__(label=label, atoms=atoms, directory=directory)
        self.evaluator = None
        self._numbers = None
        self._fingerprint = None
        self._spins = None

    def check_state(self, atoms, tol=1e-15):
        """ASE's comparison of the atoms (:func:`_system_changes`), plus the
        term parameters: results computed before ``lj.epsilon = ...`` are not
        reused after it."""
        try:
            changes = _system_changes(self.atoms, atoms, tol, self.ignored_changes)
        except TypeError:  # ASE's comparison fails on object arrays: treat as changed
            changes = list(all_changes)
        if self._fingerprint != self.hamiltonian.fingerprint():
            changes.append("parameters")
        return changes

    def todict(self):
        """The Hamiltonian as JSON-ready data (what a trajectory keeps as this
        calculator's parameters): :meth:`from_dict` rebuilds it."""
        return {"terms": [encode_term(t) for t in self.hamiltonian.terms],
                "skin": self.hamiltonian.skin,
                "conventions": self.hamiltonian.conventions.name}

    @classmethod
    def from_dict(cls, data, allow=None):
        """The calculator of :meth:`todict`'s data, e.g. of a trajectory frame:
        ``SpinLatticeCalculator.from_dict(read('md.traj').calc.parameters)``.

        Data builds ase_spin's own terms and couplings only. A wrapped ASE
        calculator (``EMT()`` among the terms), or a term class of your own, is
        built only when you allow it, for data you trust: ``allow=[EMT]``
        (classes), or ``allow={"EMT": factory}`` (the name the data gives, as
        ``"module:Class"`` or the bare class name, mapped to a callable that
        takes the written parameters as keywords; it may change them).
        Anything else named in the data is a ValueError naming it, before any
        module is imported (docs/errors.md, "What data may run")."""
        if not isinstance(data, dict) or "terms" not in data:
            raise ValueError("from_dict needs the dict of SpinLatticeCalculator.todict() "
                             f"(with 'terms'), got {data!r:.80}")
        if not isinstance(data["terms"], list):
            raise TypeError(f"from_dict: 'terms' must be a list, got {data['terms']!r:.80}")
        return cls([decode_term(t, allow) for t in data["terms"]], skin=data.get("skin", 0.3),
                   conventions=data.get("conventions", "physical"))

    def get_magnetic_moment_vector(self, atoms=None):
        """The total moment Σ_i μ_i s_i (μB), shape (3,); ``get_magnetic_moment``
        gives its length."""
        self.get_property("magmom", atoms)
        return self.results["magmom_vector"].copy()

    def publish(self, atoms, results):
        """Take ``results`` as computed for ``atoms`` as they are now (what an
        integrator does before a frame is written; see
        :meth:`~ase_spin.md.observables.Observables.publish_results`)."""
        self.results = dict(results)
        self.atoms = atoms.copy()
        self._fingerprint = self.hamiltonian.fingerprint()

    def get_magnetic_forces(self, atoms=None):
        """B_i = −∂E/∂s_i (eV), shape (N, 3)."""
        return self.get_property("magnetic_forces", atoms)

    def bound_evaluator(self, atoms):
        """The :class:`Evaluator` for ``atoms``, rebuilt only when species,
        cell, periodicity or moment magnitudes changed."""
        moments = get_moments(atoms)
        # the directions are kept for calculate(): one split per evaluation
        self._spins, mu = split_moments(moments)
        ev = self.evaluator
        if ev is None or ev.stale() or not np.array_equal(self._numbers, atoms.numbers):
            ev = self.evaluator = self.hamiltonian.bind(
                atoms.numbers, atoms.cell.array, atoms.pbc, mu)
            self._numbers = atoms.numbers.copy()
            _warn_no_moments(self.hamiltonian, mu)
        else:
            if not (np.array_equal(ev.cell, atoms.cell.array)
                    and np.array_equal(ev.pbc, atoms.pbc)):
                ev.set_cell(atoms.cell.array, atoms.pbc)
            if not _same_magnitudes(ev.moments, mu):
                ev.set_moments(mu)
                _warn_no_moments(self.hamiltonian, mu)
        return ev, moments

    def calculate(self, atoms=None, properties=("energy",), system_changes=all_changes):
        super().calculate(atoms, properties, system_changes)
        self._fingerprint = self.hamiltonian.fingerprint()
        atoms = self.atoms
        want_stress = "stress" in properties
        if want_stress and atoms.cell.rank < 3:
            raise PropertyNotImplementedError(
                "stress needs a cell with three non-zero, independent vectors")
        ev, moments = self.bound_evaluator(atoms)
        spins = self._spins
        # one pass over the pairs gives energy, forces and magnetic forces
        # together for little more than any one of them
        together = bool({"energy", "free_energy", "forces", "magnetic_forces"}
                        & set(properties))
        want = Want(
            energy=together or bool({"energies", "stress"} & set(properties)),
            energies="energies" in properties,
            forces=together,
            magnetic_forces=together,
            virial=want_stress,
        )
        try:
            res = ev.evaluate(atoms.positions, spins, want)
        except AtomsTooCloseError:
            if {"energy", "free_energy", "forces", "energies", "stress"} & set(properties):
                raise
            # overlapping atoms: energy and forces are infinite, B = −∂E/∂s is
            # not (J(0) is finite) and was all that was asked for
            want = Want(magnetic_forces=True)
            res = ev.evaluate(atoms.positions, spins, want)
        if want.energy:
            self.results["energy"] = self.results["free_energy"] = res.energy
            self.results["energy_terms"] = dict(res.energy_terms)
        if want.energies:
            self.results["energies"] = res.energies
        if want.forces:
            self.results["forces"] = res.forces
        if want.magnetic_forces:
            self.results["magnetic_forces"] = res.magnetic_forces
        if want_stress:
            self.results["stress"] = res.virial / atoms.get_volume()
        if "magmoms" in properties:
            self.results["magmoms"] = moments.copy()
        if "magmom" in properties:
            total = moments.sum(axis=0)
            self.results["magmom"] = float(np.sqrt(total @ total))
            self.results["magmom_vector"] = total
