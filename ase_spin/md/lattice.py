"""The lattice pieces every step uses: velocity Verlet when there are no
spins to move, the compensated (Kahan) kick and drift, the one lattice
evaluation of a step, the spin terms' lattice forces, the check that no atom
moved too far, and the Atoms' constraints applied to positions, forces and
momenta as ASE's VelocityVerlet applies them (all but FixSpins, which acts on
the spins' precession rates: the state's ``constraints``).

:class:`LatticeMotion` is a part of :class:`~ase_spin.md.base.SpinLatticeDynamics`
(its methods read ``self.atoms``, ``self.ev``, ``self._state``, ``self.masses``).
"""

from __future__ import annotations

import numpy as np
from ase import units

from .._jit import threads
from ..neighbors.checks import max_displacement
from ..terms.base import Want
from . import kernels
from .errors import UnstableStepError

__all__ = ["LatticeMotion"]

_FORCES = Want(forces=True)
_NO_FIELD = np.zeros((0, 3))
_NO_ENERGIES = np.zeros(0)
#: Want of the step's lattice evaluation, by (energy, virial)
_LATTICE = {(e, v): Want(forces=True, energy=e, virial=v)
            for e in (False, True) for v in (False, True)}


class LatticeMotion:
    """Lattice moves and constraints (see the module docstring)."""

    def _lattice_step(self, h, want_energy):
        """Velocity Verlet (no spins to move)."""
        st = self._state
        P = np.empty_like(st.p)
        kernels.kick(st.p, 0.5 * h, self._md_forces(st.FL, st.q), st.carry_p, P,
                     st.carry_mid)
        qt, P, st.carry_q = self._drift(st.q, P, h)
        self._check_displacement(st.q, qt, h)
        self._lattice_at(qt, want_energy)
        Ft = self._md_forces(st.FL, qt)
        kernels.kick(P, 0.5 * h, Ft, st.carry_mid, P, st.carry_p)
        st.q = qt
        st.p = self._adjust_momenta(P, qt)

    def _lattice_at(self, q, want_energy):
        """The one lattice evaluation of a step: F_L(q̃) (and E_L if logged)."""
        st = self._state
        virial = want_energy and getattr(self, "_frame_virial", False)
        res = self.ev.lattice(q, _LATTICE[bool(want_energy), bool(virial)])
        st.FL = res.forces
        st.EL = res.energy if want_energy else None
        st.EL_terms = res.energy_terms if want_energy else None
        st.VL = res.virial if virial else None

    def _spin_forces(self, operators, W, FL):
        """F_L + the spin terms' lattice forces at spins W, from prepared
        operators (a new array)."""
        F = FL.copy()
        # each operator adds its forces (SpinOperator.add): what Evaluator.spin
        # does, without its bookkeeping, several times a step
        for op in operators:
            op.add(W, _FORCES, _NO_FIELD, F, _NO_ENERGIES)
        return F

    def _kick_drift(self, F, q, h, reference, out=None):
        """The half kick P = p + (h/2) F(q) from the state's momenta and the
        drift q̃ = q + h P/m (:func:`kernels.kick` and :meth:`_drift`). Returns
        (q̃, P, the rounding error of q̃, max_i |q̃_i − q_i|, that atom,
        max |q̃ − reference|, max |q|). Without constraints in one compiled pass
        (:func:`kernels.kick_drift`, the same arithmetic), written into ``out``
        = (q̃, P, carry) buffers if given (none of them ``reference``)."""
        st = self._state
        if st.constraints:
            P = np.empty_like(st.p)
            kernels.kick(st.p, 0.5 * h, self._md_forces(F, q), st.carry_p, P, st.carry_mid)
            qt, P, carry = self._drift(q, P, h)
            moved, atom = max_displacement(q, qt)
            return (qt, P, carry, moved, atom, kernels.max_abs_difference(qt, reference),
                    float(np.abs(q).max()))
        if out is None:
            qt, P, carry = np.empty_like(q), np.empty_like(q), np.empty_like(q)
        else:
            qt, P, carry = out
        moved, atom, apart, largest = kernels.kick_drift(
            threads.count(), st.p, 0.5 * h, F, st.carry_p, P, st.carry_mid, q,
            self.masses[:, 0], h, st.carry_q, qt, carry, reference)
        return qt, P, carry, moved, atom, apart, largest

    def _check_displacement(self, q, qt, h):
        """One step may move an atom at most half the neighbour-list skin: that
        keeps one pair list valid at both q and q̃, and anything near it means the
        lattice integration has blown up (a Störmer–Verlet step moves atoms by
        ~1e-3 Å at ordinary temperatures and timesteps)."""
        moved, atom = max_displacement(q, qt)
        self._check_moved(moved, atom, h)

    def _check_moved(self, moved, atom, h):
        """:meth:`_check_displacement` given the largest displacement."""
        limit = 0.5 * self.ev.skin
        if moved != moved:  # NaN: a non-finite force or momentum, not a large move
            self._raise_nonfinite(0, atom)
        if not moved <= limit:
            raise UnstableStepError(
                f"atom {atom} moved {moved:.3g} Å in one step (at most half the "
                f"neighbour-list skin, {limit:.3g} Å, is allowed) at step {self.nsteps}: "
                f"the lattice integration is unstable at this timestep "
                f"({h / units.fs:.4g} fs); reduce it. The atoms keep the state before "
                f"this step.")

    def _drift(self, q, P, h):
        """q̃ = q + h P/m, with constraints applied as VelocityVerlet does
        (RATTLE's first half: P is recomputed from the constrained q̃).
        Returns (q̃, P, the rounding error of q̃ for the next drift); q's own
        carry is read from the state and left as it is."""
        qt = np.empty_like(q)
        st = self._state
        carry = np.empty_like(q)
        kernels.drift(q, P, self.masses[:, 0], h, st.carry_q, qt, carry)
        atoms = self.atoms
        if st.constraints:
            # positions set by constraints: nothing to compensate
            carry[:] = 0.0
            st.carry_p[:] = 0.0
            atoms.arrays["positions"][:] = q
            for c in st.constraints:
                c.adjust_positions(atoms, qt)
            P = (qt - q) * self.masses / h
        return qt, P, carry

    def _md_forces(self, F, q):
        """Forces as ``atoms.get_forces(md=True)`` would give them."""
        constraints = self._state.constraints
        if not constraints:
            return F
        atoms = self.atoms
        F = F.copy()
        atoms.arrays["positions"][:] = q
        for c in constraints:
            if hasattr(c, "redistribute_forces_md"):
                c.redistribute_forces_md(atoms, F)
            if hasattr(c, "adjust_potential_energy"):
                c.adjust_forces(atoms, F)
        return F

    def _adjust_momenta(self, p, q):
        constraints = self._state.constraints
        if not constraints:
            return p
        atoms = self.atoms
        atoms.arrays["positions"][:] = q
        for c in constraints:
            if hasattr(c, "adjust_momenta"):
                c.adjust_momenta(atoms, p)
        return p
