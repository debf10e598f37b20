r"""Rates of thermally activated spin transitions: harmonic transition-state
theory for spins (Bessarab, Uzdin and Jónsson, Phys. Rev. B 85, 184409
(2012)).

Near a stationary point (a minimum, or the first-order saddle point that a
climbing image finds) the energy in the 2n tangent coordinates x of the n
spins that turn is E ≈ E₀ + ½ xᵀHx, H the Hessian on (S²)ⁿ. Spins precess
without inertia, so the coordinates are their own phase space: linearised,
ds_i/dt = r_i (σ/ħ) s_i × B_i gives ẋ = A x with A = −σ D J H, D the
precession rates r_i/ħ (r_i = g/μ_i, or 1 under LAMMPS's conventions) and
J the quarter turn about each s_i. With H's eigenpairs (ε_k, e_k) at the
saddle, ε₁ < 0 the unstable mode, the flux through the dividing plane
e₁·x = 0 with the Boltzmann weight of the tangent space gives

.. math::

    k = \frac{1}{2\pi}\,\sqrt{\sum_{k\ge 2}' \frac{a_k^2}{ε_k}}\,
        \sqrt{\frac{\prod' λ_j}{\prod_{k\ge2}' ε_k}}\;
        \frac{V_s}{V_m}\Big(\frac{2\pi k_BT}{1}\Big)^{(n_m - n_s)/2}
        e^{-(E_s - E_m)/k_BT}, \qquad a_k = e_1^{\mathsf T} A\, e_k,

with λ_j the eigenvalues of the Hessian at the minimum. Primes leave out the
zero modes (|eigenvalue| ≤ ``zero_tolerance`` × the largest): n_m of them at
the minimum and n_s at the saddle, continuous symmetries whose Gaussian
integrals are replaced by the volumes V_m, V_s of the manifolds they span
(rad^n; given by the user: a rotation of all spins about an axis, say), which
makes the prefactor depend on temperature as T^{(n_m − n_s)/2}. For one spin
the prefactor reduces to ω₀/2π, ω₀ = √(det H_m)·r/ħ the ferromagnetic
resonance frequency at the minimum (checked in tests/test_landscapes.py
against the Stoner–Wohlfarth particle). A saddle whose only stable modes
are zero modes (a field along the axis of a uniaxial particle) has no flux:
k = 0 (the precession conserves the axial component; the transition then
needs damping, which HTST leaves out).

The Hessian is built from central differences of the magnetic forces along
geodesics, H v = P(−∂B/∂v) + (s·B) v per spin (the Riemannian Hessian on the
sphere), 4n evaluations of the fields, and symmetrised.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from ase import units

from ..spins import get_moments, split_moments
from ..validate import positive_scalar
from . import sphere
from .base import checked_fmax, largest_torque
from .objective import FrozenLattice

__all__ = ["tangent_basis", "spin_hessian", "HTST", "HTSTResult"]


def tangent_basis(s):
    """(e1_i, e2_i): orthonormal tangent vectors at unit spins s, shape
    (n, 2, 3), with e2_i = s_i × e1_i."""
    e1 = sphere.perpendicular(s)
    return np.stack([e1, np.cross(s, e1)], axis=1)


def spin_hessian(landscape, s, step=1e-5):
    """The Hessian of E on (S²)ⁿ at spins s (a stationary point) in the tangent
    coordinates of :func:`tangent_basis` of the free spins, shape (2n, 2n)
    (eV/rad²), and that basis. ``landscape``: a :class:`FrozenLattice`."""
    free = np.flatnonzero(landscape.free)
    basis = tangent_basis(s[free])
    _, B0 = landscape(s)
    along = sphere.dot(s[free], B0[free])  # s·B: the sphere's curvature term
    H = np.zeros((2 * len(free), 2 * len(free)))
    for k, i in enumerate(free):
        for c in range(2):
            v = basis[k, c]
            plus, minus = s.copy(), s.copy()
            plus[i] = sphere.exp_map(s[i], step * v)
            minus[i] = sphere.exp_map(s[i], -step * v)
            dB = (landscape(plus)[1] - landscape(minus)[1])[free] / (2 * step)
            H[:, 2 * k + c] = -np.einsum("nci,ni->nc", basis, dB).reshape(-1)
            H[2 * k + c, 2 * k + c] += along[k]
    return 0.5 * (H + H.T), basis


@dataclass
class HTSTResult:
    """What :meth:`HTST.rate` found: ``barrier`` E_s − E_m (eV); the Hessians'
    eigenvalues ``minimum_modes``, ``saddle_modes`` (eV/rad², ascending); the
    numbers of zero modes ``zero_modes`` = (n_m, n_s); ``prefactor(T)`` and
    ``rate(T)`` in 1/s."""

    barrier: float
    minimum_modes: np.ndarray
    saddle_modes: np.ndarray
    zero_modes: tuple
    log_prefactor_0: float  # ln of the prefactor (1/s) without its T^{(n_m−n_s)/2}
    flux: float  # Σ' a_k²/ε_k (1/(s² eV))

    def prefactor(self, temperature=None):
        """ν (1/s) of k = ν e^{−ΔE/k_BT}; needs T (K) when zero modes make it
        depend on temperature."""
        power = 0.5 * (self.zero_modes[0] - self.zero_modes[1])
        if power == 0.0:
            return float(np.exp(self.log_prefactor_0)) if self.flux > 0.0 else 0.0
        if temperature is None:
            raise ValueError("this prefactor depends on temperature (zero modes "
                             f"{self.zero_modes}): give temperature (K)")
        kT = units.kB * positive_scalar(temperature, "temperature (K)")
        if not self.flux > 0.0:
            return 0.0
        return float(np.exp(self.log_prefactor_0 + power * np.log(2 * np.pi * kT)))

    def rate(self, temperature):
        """k (1/s) at temperature T (K)."""
        kT = units.kB * positive_scalar(temperature, "temperature (K)")
        return self.prefactor(temperature) * float(np.exp(-self.barrier / kT))


class HTST:
    """Harmonic transition-state theory between a minimum and a first-order
    saddle point of the spins (module docstring).

    ``HTST(minimum, saddle)``: two Atoms with the same atoms, positions and
    moment lengths, each at its stationary point (torques ≈ 0): the minimum
    with its SpinLatticeCalculator, which serves both; the saddle's spins
    (a GNEB climbing image, ``band.images[band.climbing_image]``). ``hbar``, ``g``, ``gyromagnetic``
    (the precession: ds_i/dt = r_i (σ/ħ) s_i × B_i, r_i = g/μ_i or 1 for
    ``"lammps"``) default to the calculator's conventions, as the integrators'.
    ``.rate(volumes=(V_m, V_s), zero_tolerance=1e-6)`` returns an
    :class:`HTSTResult`; it refuses stationary points whose largest torque
    exceeds ``fmax`` (eV): the curvatures of the soft modes, and with them the
    prefactor, are wrong away from them (converge the band to ~1e-10 eV).
    """

    def __init__(self, minimum, saddle, *, hbar=None, g=None, gyromagnetic=None, step=1e-5,
                 fmax=1e-8):
        self.landscape = FrozenLattice(minimum, "HTST")
        if len(saddle) != len(minimum) or not np.array_equal(saddle.positions,
                                                             minimum.positions):
            raise ValueError("HTST: the saddle needs the minimum's atoms and positions "
                             "(spins on a frozen lattice)")
        s, mu = split_moments(get_moments(saddle))
        if not np.allclose(mu, self.landscape.mu, rtol=1e-12, atol=0.0):
            raise ValueError("HTST: the saddle's moments differ in length from the minimum's")
        self.s_minimum = self.landscape.s.copy()
        self.s_saddle = self.landscape.s.copy()
        self.s_saddle[self.landscape.free] = s[self.landscape.free]
        conventions = minimum.calc.hamiltonian.conventions
        self.hbar = conventions.hbar if hbar is None else positive_scalar(hbar, "hbar")
        self.g = conventions.g if g is None else positive_scalar(g, "g")
        self.gyromagnetic = conventions.gyromagnetic if gyromagnetic is None else gyromagnetic
        if self.gyromagnetic not in ("moment", "lammps"):
            raise ValueError(f"gyromagnetic must be 'moment' or 'lammps', got "
                             f"{self.gyromagnetic!r}")
        self.step = positive_scalar(step, "step (rad)")
        self.fmax = checked_fmax(fmax)

    def _rates(self):
        """r_i/ħ per tangent coordinate of the free spins (1/(eV·time))."""
        mu = self.landscape.mu[self.landscape.free]
        r = np.ones_like(mu) if self.gyromagnetic == "lammps" else self.g / mu
        return np.repeat(r / self.hbar, 2)

    def rate(self, volumes=None, zero_tolerance=1e-6):
        zero_tolerance = positive_scalar(zero_tolerance, "zero_tolerance")
        land = self.landscape
        Em, Bm = land(self.s_minimum)
        Es, Bs = land(self.s_saddle)
        for name, s, B in (("minimum", self.s_minimum, Bm), ("saddle", self.s_saddle, Bs)):
            torque = largest_torque(s, B, land.free)
            if torque > self.fmax:
                raise ValueError(f"HTST: the {name}'s largest torque is {torque:.3g} eV > fmax "
                                 f"= {self.fmax:g} eV: the harmonic approximation needs the "
                                 "stationary point; converge it further")
        Hm, _ = spin_hessian(land, self.s_minimum, self.step)
        Hs, _ = spin_hessian(land, self.s_saddle, self.step)
        lam = np.linalg.eigvalsh(Hm)
        eps, vecs = np.linalg.eigh(Hs)
        scale = max(np.abs(lam).max(), np.abs(eps).max())
        zero_m = np.abs(lam) <= zero_tolerance * scale
        zero_s = np.abs(eps) <= zero_tolerance * scale
        if (lam[~zero_m] < 0.0).any():
            raise ValueError(f"HTST: the minimum has {int((lam[~zero_m] < 0).sum())} "
                             "negative curvatures: relax it first")
        unstable = (eps < 0.0) & ~zero_s
        if unstable.sum() != 1:
            raise ValueError(f"HTST: the saddle has {int(unstable.sum())} negative "
                             "curvatures, not one: converge the climbing image")
        n_m, n_s = int(zero_m.sum()), int(zero_s.sum())
        if (n_m or n_s) and volumes is None:
            raise ValueError(f"HTST: {n_m} zero modes at the minimum and {n_s} at the saddle "
                             "(|curvature| ≤ zero_tolerance × the largest): give volumes="
                             "(V_m, V_s), the volumes (rad^n) of the manifolds they span")
        V_m, V_s = (1.0, 1.0) if volumes is None else (positive_scalar(v, "volume")
                                                       for v in volumes)
        # the velocity matrix A = −D J H at the saddle (σ drops out of a_k²)
        D = self._rates()
        JH = np.empty_like(Hs)
        JH[0::2], JH[1::2] = -Hs[1::2], Hs[0::2]  # J(p, q) = (−q, p) per spin
        A = -D[:, None] * JH
        e1 = vecs[:, 0]
        stable = ~zero_s & (eps > 0.0)
        a = e1 @ A @ vecs[:, stable]
        flux = float(np.sum(a**2 / eps[stable]))
        log_det = np.sum(np.log(lam[~zero_m])) - np.sum(np.log(eps[stable]))
        log_nu = (-np.log(2 * np.pi) + 0.5 * np.log(flux if flux > 0.0 else 1.0)
                  + 0.5 * log_det + np.log(V_s / V_m))
        # per ASE time unit -> per second
        log_nu += np.log(units.s)
        return HTSTResult(float(Es - Em), lam, eps, (n_m, n_s), float(log_nu), flux)
