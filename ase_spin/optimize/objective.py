"""The energy landscape E(s) of the spins at fixed positions, as the minimisers
and the band see it: one call gives the energy and the magnetic forces
B = −∂E/∂s of any spins from the spin operators prepared once at the
positions (:meth:`~ase_spin.hamiltonian.Evaluator.spin`: one pass over the
spin terms, no neighbour search), and counts the calls."""

from __future__ import annotations

import numpy as np

from ..calculator import SpinLatticeCalculator
from ..constraints import pinned_spins
from ..spins import get_moments, split_moments
from ..terms.base import Want

__all__ = ["FrozenLattice", "spin_calculator"]

_ENERGY_FIELDS = Want(energy=True, magnetic_forces=True)


def spin_calculator(atoms, who):
    """``atoms.calc``, which must be an ase_spin SpinLatticeCalculator (TypeError
    naming ``who`` otherwise)."""
    calc = atoms.calc
    if not isinstance(calc, SpinLatticeCalculator):
        raise TypeError(f"{who} needs atoms.calc to be an ase_spin SpinLatticeCalculator, "
                        f"got {type(calc).__name__}")
    return calc


class FrozenLattice:
    """E(s) and B(s) = −∂E/∂s of ``atoms`` at their present positions.

    ``E = E_lattice + E_spin(s)``: the spin-independent part is evaluated once,
    so energies are those ``atoms.get_potential_energy()`` gives. ``free`` marks
    the spins that may turn: magnetic and not pinned by
    :class:`~ase_spin.constraints.FixSpins`. ``evaluations`` counts the calls
    (each one pass over the spin terms). ``moments`` are the Atoms' moment
    vectors when it was made, ``s`` and ``mu`` their directions and lengths.
    """

    def __init__(self, atoms, who="a spin minimiser"):
        calc = spin_calculator(atoms, who)
        self.atoms = atoms
        self.calc = calc
        self.moments = get_moments(atoms).copy()
        ev, _ = calc.bound_evaluator(atoms)
        self.evaluator = ev
        self.s, self.mu = split_moments(self.moments)
        self.positions = np.array(atoms.positions, dtype=float)
        self.fingerprint = calc.hamiltonian.fingerprint()
        self.lattice_energy = float(ev.lattice(self.positions, Want(energy=True)).energy)
        magnetic = ev.any_magnetic and bool(ev.hamiltonian.spin_terms)
        self.ops = ev.spin_operators(self.positions) if magnetic else None
        pinned = pinned_spins(atoms)
        self.free = ev.magnetic & (True if pinned is None else ~pinned) & magnetic
        self.evaluations = 0
        self.written = self.moments.copy()

    def __call__(self, s):
        """(E, B) at unit spins s, shape (N, 3) (zero rows where non-magnetic)."""
        self.evaluations += 1
        if self.ops is None:
            return self.lattice_energy, np.zeros_like(s)
        res = self.evaluator.spin(self.ops, s, _ENERGY_FIELDS)
        return self.lattice_energy + float(res.energy), res.magnetic_forces

    def current(self):
        """Whether the Atoms, their calculator and its parameters are still
        those this landscape was made from, but for spins written by
        :meth:`write` (a user who moved atoms or changed a term in between
        gets a new landscape)."""
        a = self.atoms
        return (a.calc is self.calc and len(a) == len(self.positions)
                and np.array_equal(a.positions, self.positions)
                and self.calc.hamiltonian.fingerprint() == self.fingerprint
                and np.array_equal(a.arrays.get("initial_magmoms"), self.written)
                and not self.evaluator.stale())

    def moments_of(self, s):
        """The moment vectors μ_i s_i for spins s; the rows of spins that do
        not turn (pinned, non-magnetic) bitwise as the Atoms held them."""
        m = self.moments.copy()
        m[self.free] = self.mu[self.free, None] * s[self.free]
        return m

    def write(self, s, energy=None, B=None):
        """Write spins s into the Atoms' ``initial_magmoms`` and, given, the
        energy and fields computed for them into the calculator's results
        (an observer reading them then costs no evaluation)."""
        m = self.moments_of(s)
        self.atoms.arrays["initial_magmoms"] = m
        self.written = m
        if energy is not None:
            self.calc.publish(self.atoms, {"energy": energy, "free_energy": energy,
                                           "magnetic_forces": B.copy()})
