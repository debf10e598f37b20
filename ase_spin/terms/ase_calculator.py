"""Any ASE calculator as the spin-independent (lattice) part of the Hamiltonian."""

from __future__ import annotations

import pickle
import threading
import weakref

import numpy as np
from ase import Atoms
from ase.calculators.calculator import BaseCalculator, PropertyNotImplementedError

from ..validate import real_array
from .base import Term

__all__ = ["CalculatorTerm", "is_ase_calculator"]


# One lock per wrapped calculator: an ASE calculator keeps its results (and the
# Atoms they are of) in itself, so two threads using one calculator would read
# each other's results. Calculators that cannot be weakly referenced share one.
_LOCKS = weakref.WeakKeyDictionary()
_LOCKS_GUARD = threading.Lock()
_SHARED_LOCK = threading.RLock()


def _lock_of(calculator):
    with _LOCKS_GUARD:
        try:
            lock = _LOCKS.get(calculator)
            if lock is None:
                lock = _LOCKS[calculator] = threading.RLock()
            return lock
        except TypeError:  # not hashable, or not weakly referenceable
            return _SHARED_LOCK


def is_ase_calculator(obj):
    """True for an ASE calculator (anything with ASE's ``get_property``
    protocol), the objects :class:`CalculatorTerm` wraps."""
    return isinstance(obj, BaseCalculator) or (
        callable(getattr(obj, "get_property", None))
        and callable(getattr(obj, "get_forces", None)))


class CalculatorTerm(Term):
    r"""An ASE calculator (``EMT()``, an EAM, a machine-learned potential, ...) as a
    lattice term: :math:`E_\mathrm{lattice}(\mathbf r)` is what the calculator
    gives for the atoms at positions r, whatever their spins.

    ``SpinLatticeCalculator([EMT(), Exchange(...)])`` wraps a bare calculator in
    this term by itself. The term keeps one private :class:`~ase.Atoms` (the
    system's species, cell and periodicity, no spins) and writes the positions
    it is asked about into it; the calculator's own cache (``check_state``)
    decides whether to compute, so asking twice at the same positions, or for
    the energy after the forces, costs no second calculation. All the
    properties a call needs are requested at once: one ``calculate`` per
    evaluation, so one per integrator step.

    What it gives: energy (eV), forces F = −∂E/∂r, per-atom energies when the
    calculator offers ``energies``, and the virial W = V σ (eV, Voigt xx yy zz
    yz xz xy, σ the calculator's stress, ASE's sign: W = ∂E/∂ε). For a system
    periodic in no direction the virial is W_ab = −Σ_i r_ia F_ib (symmetrised),
    exact for a finite system, and no stress is asked of the calculator.

    The calculator sees chemical symbols, positions, cell and periodicity
    only: it must not depend on the spins (use it for the spin-independent
    part; spin terms are ase_spin terms).

    Checked on every call: the calculator is handed a copy of the term's
    Atoms, and one that changes its cell, periodicity or atomic numbers is
    refused (its results are not of this system); the energy must be one
    real number, forces an (N, 3) and per-atom energies an (N,) array of
    real numbers, the stress 6 or 9 of them (a TypeError or ValueError
    naming the calculator otherwise: no broadcasting of a wrong shape). Calls
    into one calculator are serialised by a lock, so that threads sharing it
    (two Atoms with one calculator, in two threads) do not read each other's
    results.
    """

    name = "calculator"
    spin_dependent = False
    neighbor_list = None  # it brings its own
    cutoff = 0.0

    _parameters = {"calculator": "calculator"}

    def __init__(self, calculator):
        # a spin–lattice calculator (this package's, by the property it adds)
        if "magnetic_forces" in getattr(calculator, "implemented_properties", ()):
            raise TypeError("a SpinLatticeCalculator cannot be a term of a Hamiltonian: "
                            "give its terms (calc.hamiltonian.terms) instead")
        if not is_ase_calculator(calculator):
            raise TypeError(f"CalculatorTerm wraps an ASE calculator (e.g. "
                            f"ase.calculators.emt.EMT()), got {calculator!r:.80}")
        self.calculator = calculator
        self.name = _calculator_name(calculator)
        self._finish()

    def __repr__(self):
        return f"CalculatorTerm({self.calculator!r})"

    def __getstate__(self):
        """Pickle and deepcopy: the calculator as it is if it can be pickled,
        else a fresh one made from its parameters (``type(calc)(**calc.todict())``:
        ASE's EMT, for one, keeps unpicklable caches after a calculation)."""
        state = dict(self.__dict__)
        calc = self.calculator
        try:
            pickle.dumps(calc)
        except Exception as err:  # noqa: BLE001 - any failure: rebuild from parameters
            try:
                state["calculator"] = type(calc)(**calc.todict())
            except Exception:  # noqa: BLE001
                raise TypeError(f"{type(calc).__name__} cannot be pickled or copied ({err}) "
                                "nor rebuilt from its todict()") from err
        return state

    def bind(self, system):
        symbols = np.asarray(system.species.symbols, dtype=object)[system.types]
        return Atoms(symbols=list(symbols), positions=np.zeros((system.natoms, 3)),
                     cell=system.cell, pbc=system.pbc)

    def compute(self, positions, pairs, types, atoms, forces, energies, want):
        """Add F_i and E_i of the wrapped calculator into ``forces``/``energies``;
        return (E, W) with W the virial (see the class docstring)."""
        periodic = bool(atoms.pbc.any())
        virial_from_forces = want.virial and not periodic
        if want.virial and periodic and atoms.cell.rank < 3:
            raise PropertyNotImplementedError(
                f"the virial of {self.name} needs a cell with three independent vectors "
                f"(the system is periodic along {np.flatnonzero(atoms.pbc).tolist()})")
        props = ["energy"]
        if want.forces or virial_from_forces:
            props.append("forces")
        if want.energies:
            props.append("energies")
        if want.virial and periodic:
            props.append("stress")
        # a copy: the calculator never sees our arrays, nor can it change the
        # Atoms the next call is made with
        work = atoms.copy()
        work.arrays["positions"][:] = positions
        with _lock_of(self.calculator):
            results = self._checked(self._results(work, props), props, len(atoms))
        if not (np.array_equal(work.cell.array, atoms.cell.array)
                and np.array_equal(work.pbc, atoms.pbc)
                and np.array_equal(work.numbers, atoms.numbers)):
            raise ValueError(f"{self.name} ({type(self.calculator).__name__}) changed the cell, "
                             "periodicity or atomic numbers of the Atoms it was given: its "
                             "results are not those of the system")
        if want.forces:
            forces += results["forces"]
        if want.energies:
            energies += results["energies"]
        virial = np.zeros(6)
        if virial_from_forces:
            f = results["forces"]
            w = -np.einsum("ia,ib->ab", positions, f)
            w = 0.5 * (w + w.T)
            virial = w[[0, 1, 2, 1, 0, 0], [0, 1, 2, 2, 2, 1]]
        elif want.virial:
            virial = results["stress"].reshape(-1)
            if virial.shape == (9,):
                virial = virial.reshape(3, 3)[[0, 1, 2, 1, 0, 0], [0, 1, 2, 2, 2, 1]]
            virial = virial * abs(np.linalg.det(atoms.cell.array))
        return results["energy"], virial

    def _checked(self, results, props, natoms):
        """Copies of the calculator's ``props`` as float64, of the shapes the
        term adds up; TypeError/ValueError naming the calculator otherwise."""
        name = f"{self.name} ({type(self.calculator).__name__})"
        out = {}
        for p in props:
            what = f"the {p} {name} gave"
            value = real_array(results[p], what)
            if p == "energy":
                if value.size != 1:
                    raise ValueError(f"{what} must be one number, got shape {value.shape}")
                out[p] = float(value.reshape(-1)[0])
                continue
            shape = {"forces": (natoms, 3), "energies": (natoms,)}.get(p)
            if shape is not None and value.shape != shape:
                raise ValueError(f"{what} must have shape {shape} (one row per atom), got "
                                 f"{value.shape}")
            if p == "stress" and value.shape not in ((6,), (9,), (3, 3)):
                raise ValueError(f"{what} must have 6 (Voigt) or 3x3 components, got shape "
                                 f"{value.shape}")
            out[p] = value.copy()
        return out

    def _results(self, atoms, props):
        """The calculator's results for ``props`` at ``atoms``: ASE's
        ``get_property`` logic, with every property asked for in one
        ``calculate``."""
        calc = self.calculator
        missing = [p for p in props if p not in getattr(calc, "implemented_properties",
                                                        props)]
        if missing:
            raise PropertyNotImplementedError(
                f"{self.name} ({type(calc).__name__}) does not give {', '.join(missing)}"
                + (" (per-atom energies)" if "energies" in missing else ""))
        if not (hasattr(calc, "check_state") and hasattr(calc, "calculate")
                and isinstance(getattr(calc, "results", None), dict)):
            return {p: calc.get_property(p, atoms) for p in props}
        changes = calc.check_state(atoms)
        if changes:
            calc.reset()
        if any(p not in calc.results for p in props):
            calc.calculate(atoms, props, changes)
        results = calc.results
        for p in props:
            if p not in results:
                raise PropertyNotImplementedError(
                    f"{self.name} ({type(calc).__name__}) gave no {p!r}")
        return results


def _calculator_name(calc):
    name = getattr(calc, "name", None)
    if not isinstance(name, str) or not name or name == "unknown":
        name = type(calc).__name__.lower()
    return name
