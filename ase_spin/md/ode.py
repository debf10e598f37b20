"""A high-accuracy reference: the equations of motion handed to a general ODE solver.

Used to check the integrators' convergence (tests, examples/paper_chain.py):

    dr_i/dt = p_i/m_i,   dp_i/dt = F_i(r, s),   ds_i/dt = (σ/ħ) s_i × B_i(r, s)

integrated with scipy's DOP853 (explicit Runge–Kutta of order 8) at tight
tolerances. Forces and magnetic forces come from the same Evaluator as the
integrators, so differences are integration error only.
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp

from ..constraints import pinned_spins
from ..spins import split_moments
from ..terms.base import Want

__all__ = ["reference_solution"]

_WANT = Want(forces=True, magnetic_forces=True)


def reference_solution(atoms, t_end, *, hbar=None, precession=None, gyromagnetic=None,
                       g=None, rtol=1e-13, atol=1e-14, frozen_lattice=False):
    """(positions, momenta, spins) at ``t_end`` (ASE time) from the state of ``atoms``.

    ``atoms.calc`` must be a SpinLatticeCalculator; the Atoms are not changed.
    ``hbar``, ``precession``, ``gyromagnetic`` and ``g`` default to the calculator's conventions,
    as in the integrators; ``gyromagnetic="moment"`` multiplies spin i's
    precession by g/μ_i; spins pinned by a FixSpins of ``atoms.constraints``
    precess at rate 0 (other constraints are not applied: pass atoms without).
    """
    conventions = atoms.calc.hamiltonian.conventions
    hbar = conventions.hbar if hbar is None else hbar
    precession = conventions.precession if precession is None else precession
    gyromagnetic = conventions.gyromagnetic if gyromagnetic is None else gyromagnetic
    g = conventions.g if g is None else g
    ev, moments = atoms.calc.bound_evaluator(atoms)
    spins, mu = split_moments(moments)
    rate = np.ones((len(mu), 1))
    if gyromagnetic == "moment":
        rate[mu > 0, 0] = g / mu[mu > 0]
    pinned = pinned_spins(atoms)
    if pinned is not None:
        rate[pinned, 0] = 0.0
    n = len(atoms)
    m = atoms.get_masses()[:, None]
    sigma = -1.0 if precession == "moment" else 1.0
    y0 = np.concatenate([atoms.positions.ravel(), atoms.get_momenta().ravel(), spins.ravel()])

    def rhs(_, y):
        q = y[: 3 * n].reshape(n, 3)
        p = y[3 * n: 6 * n].reshape(n, 3)
        s = y[6 * n:].reshape(n, 3)
        res = ev.evaluate(q, s, _WANT)
        dq = np.zeros_like(q) if frozen_lattice else p / m
        dp = np.zeros_like(p) if frozen_lattice else res.forces
        ds = (sigma / hbar) * rate * np.cross(s, res.magnetic_forces)
        return np.concatenate([dq.ravel(), dp.ravel(), ds.ravel()])

    sol = solve_ivp(rhs, (0.0, t_end), y0, method="DOP853", rtol=rtol, atol=atol)
    if not sol.success:
        raise RuntimeError(f"reference integration failed: {sol.message}")
    y = sol.y[:, -1]
    return y[: 3 * n].reshape(n, 3), y[3 * n: 6 * n].reshape(n, 3), y[6 * n:].reshape(n, 3)
