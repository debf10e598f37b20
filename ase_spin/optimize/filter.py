r"""Joint spin–lattice relaxation with ASE's own optimizers: a filter that sets
the spins' rotation coordinates beside the positions.

``SpinLatticeFilter(atoms)`` (or ``SpinLatticeFilter(FrechetCellFilter(atoms))``
for the cell too) looks to ``ase.optimize.BFGS``, ``LBFGS``, ``FIRE`` like Atoms
with one more row per spin that may turn: the rows of the object it wraps
(positions, and a cell filter's cell rows), then for each free spin a rotation
vector φ_i (rad) from its direction s_i⁰ when the filter was made,
s_i = R(φ_i) s_i⁰ (:func:`~ase_spin.optimize.sphere.rotate`). Its force is
−∂E/∂φ_i = J(φ_i)ᵀ τ_i, τ_i = s_i × B_i the torque (eV) and J the left
Jacobian of the rotations,

.. math:: J(\boldsymbol φ) = I + \frac{1-\cos φ}{φ^2}[\boldsymbol φ]_\times
    + \frac{φ - \sin φ}{φ^3}[\boldsymbol φ]_\times^2

(δs = (J δφ) × s), so the optimizers descend the full Hamiltonian E(r, s) and
stop at a common minimum: forces and torques zero. For ASE's convergence test
and log (``fmax``) a spin row counts as its torque |τ_i| = |J⁻ᵀ f_i| (eV),
a position row as its force (eV/Å). ``FixAtoms`` and the other constraints
act through the wrapped Atoms; spins pinned by
:class:`~ase_spin.constraints.FixSpins` and non-magnetic atoms have no row.
"""

from __future__ import annotations

import numpy as np
from ase import Atoms

from ..constraints import pinned_spins
from ..spins import get_moments, split_moments
from . import sphere
from .objective import spin_calculator

try:  # ASE's optimizers ask filters for this interface from ASE 3.24
    from ase.filters import OptimizableFilter
except ImportError:  # pragma: no cover - older ASE reads the filter's methods
    OptimizableFilter = None

__all__ = ["SpinLatticeFilter", "rotation_jacobian"]


def rotation_jacobian(phi):
    """J(φ_i) of the module docstring for rotation vectors φ, shape (n, 3, 3)."""
    angle = sphere.norms(phi)
    small = angle < 1e-4
    a2 = np.where(small, 1.0, angle) ** 2
    c1 = np.where(small, 0.5 - angle**2 / 24.0, (1.0 - np.cos(angle)) / a2)
    c2 = np.where(small, 1.0 / 6.0 - angle**2 / 120.0,
                  (angle - np.sin(angle)) / (a2 * np.where(small, 1.0, angle)))
    X = np.zeros((len(phi), 3, 3))
    X[:, 0, 1], X[:, 0, 2], X[:, 1, 2] = -phi[:, 2], phi[:, 1], -phi[:, 0]
    X[:, 1, 0], X[:, 2, 0], X[:, 2, 1] = phi[:, 2], -phi[:, 1], phi[:, 0]
    return np.eye(3) + c1[:, None, None] * X + c2[:, None, None] * (X @ X)


class SpinLatticeFilter:
    """Positions (through ``atoms``: Atoms or an ASE filter of them) and spins
    as one set of coordinates for ASE's optimizers (module docstring)."""

    def __init__(self, atoms):
        self.inner = atoms
        self.atoms = atoms if isinstance(atoms, Atoms) else atoms.atoms
        self.calc = spin_calculator(self.atoms, "SpinLatticeFilter")
        moments = get_moments(self.atoms)
        self.reference, self.mu = split_moments(moments)
        pinned = pinned_spins(self.atoms)
        self.free = (self.mu > 0.0) & (True if pinned is None else ~pinned)
        self.phi = np.zeros((int(self.free.sum()), 3))
        self.inner_length = len(atoms)

    def spins(self):
        """The unit spins at the present coordinates."""
        s = self.reference.copy()
        s[self.free] = sphere.rotate(self.reference[self.free], self.phi)
        return s

    def _write_spins(self):
        m = get_moments(self.atoms).copy()
        m[self.free] = self.mu[self.free, None] * sphere.rotate(self.reference[self.free],
                                                                self.phi)
        self.atoms.arrays["initial_magmoms"] = m

    def get_positions(self):
        return np.concatenate([self.inner.get_positions(), self.phi])

    def set_positions(self, new, **kwargs):
        new = np.asarray(new, dtype=float)
        if new.shape != (len(self), 3):
            raise ValueError(f"SpinLatticeFilter positions must have shape ({len(self)}, 3), "
                             f"got {new.shape}")
        self.inner.set_positions(new[:self.inner_length], **kwargs)
        self.phi = new[self.inner_length:].copy()
        self._write_spins()

    def torques(self):
        """τ_i = s_i × B_i (eV) of the free spins, (n_free, 3)."""
        B = self.calc.get_magnetic_forces(self.atoms)
        s = sphere.rotate(self.reference[self.free], self.phi)
        return sphere.torque(s, B[self.free])

    def get_forces(self, *args, **kwargs):
        f = self.inner.get_forces(*args, **kwargs)
        J = rotation_jacobian(self.phi)
        spin = np.einsum("nji,nj->ni", J, self.torques())
        return np.concatenate([f, spin])

    def spin_rows_as_torques(self, rows):
        """|τ_i| from the spin rows f_i = Jᵀτ_i of a force (or gradient)."""
        if not len(rows):
            return np.zeros(0)
        J = rotation_jacobian(self.phi)
        return sphere.norms(np.linalg.solve(np.transpose(J, (0, 2, 1)), rows[..., None])[..., 0])

    def get_potential_energy(self, *args, **kwargs):
        return self.inner.get_potential_energy(*args, **kwargs)

    def __len__(self):
        return self.inner_length + len(self.phi)

    def iterimages(self):
        return self.inner.iterimages()

    def get_global_number_of_atoms(self):
        return len(self)

    def get_chemical_symbols(self):
        return self.atoms.get_chemical_symbols()

    def get_masses(self):
        return np.concatenate([np.broadcast_to(self.inner.get_masses(),
                                               (self.inner_length,)), np.ones(len(self.phi))])

    def __ase_optimizable__(self):
        if OptimizableFilter is None:  # pragma: no cover
            return self
        return _Optimizable(self)


if OptimizableFilter is not None:
    class _Optimizable(OptimizableFilter):
        """ASE's view of a filter, whose fmax reads the spin rows as torques."""

        def gradient_norm(self, gradient):
            rows = gradient.reshape(-1, 3)
            f = self.filterobj
            inner = sphere.norms(rows[:f.inner_length])
            spins = f.spin_rows_as_torques(rows[f.inner_length:])
            return float(np.concatenate([inner, spins, [0.0]]).max())
