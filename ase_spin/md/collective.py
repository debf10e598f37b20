"""The collective symplectic partitioned Runge–Kutta method for spin–lattice dynamics.

Bogfjellmo, *Collective symplectic integrators on S²ⁿ × T*Rᵐ*: Störmer–Verlet
for positions and momenta, the spherical midpoint method for the spins, with
matching b-coefficients, implicit in the midpoint spins W.
"""

from __future__ import annotations

import copy
from collections import deque

import numpy as np
from ase import units
from ase.constraints import FixAtoms
from ase.md.md import MolecularDynamics

from .. import threads
from ..calculator import SpinLatticeCalculator
from ..hamiltonian import Want
from ..io import check_trajectory_target
from ..neighbors import max_displacement
from ..spins import _name_atoms, split_moments
from ..terms.exchange import ExchangeGeometry
from ..validate import flag, integer, positive_scalar, real_array, real_scalar
from . import kernels
from .compositions import composition_coefficients
from .logger import SpinMDLogger

__all__ = ["CollectivePRK", "IntegrationError", "SpinConvergenceError", "UnstableStepError",
           "HBAR"]

#: ħ in eV·(ASE time unit), from CODATA via ase.units.
HBAR = units._hbar / units._e * units.s

_EPS = np.finfo(float).eps
_FORCES = Want(forces=True)
_MAX_OUTER = 12




def _same(a, b):
    if a is None or b is None:
        return a is b
    return a.shape == b.shape and a.dtype == b.dtype and kernels.same(a, b)


def _equal(x, y):
    """Deep equality of constraint contents (arrays, containers, attributes)."""
    if type(x) is not type(y):
        return False
    if isinstance(x, np.ndarray):
        return x.shape == y.shape and x.dtype == y.dtype and bool(
            np.array_equal(x, y, equal_nan=x.dtype.kind in "fc"))
    if isinstance(x, (list, tuple)):
        return len(x) == len(y) and all(_equal(a, b) for a, b in zip(x, y))
    if isinstance(x, dict):
        return x.keys() == y.keys() and all(_equal(x[k], y[k]) for k in x)
    if hasattr(x, "__dict__") and not callable(x):
        return _equal(vars(x), vars(y))
    try:
        return bool(x == y)
    except Exception:  # noqa: BLE001 - incomparable: treat as changed
        return False


#: Tightest and loosest stopping tolerances of the midpoint iteration (on unit vectors).
TOL_RANGE = (1e-16, 1e-3)


class IntegrationError(RuntimeError):
    """A step could not be taken; the Atoms keep the state before it."""


class SpinConvergenceError(IntegrationError):
    """The implicit equation for the midpoint spins was not solved."""


class UnstableStepError(IntegrationError):
    """An atom moved implausibly far in one step: the lattice integration blew up."""


class _State:
    """What the integrator holds between steps (design.md, "one step as data")."""

    __slots__ = ("q", "p", "s", "mu", "FL", "Gq", "EL", "EL_terms", "written",
                 "carry_q", "carry_p", "carry_s",
                 "history", "predictor_order", "theta", "observables")


class CollectivePRK(MolecularDynamics):
    r"""Spin–lattice dynamics with the collective symplectic PRK method.

    Equations of motion (ASE units; B = −∂E/∂s the magnetic forces, eV):

    .. math::

        \dot{\mathbf r}_i = \mathbf p_i/m_i, \qquad
        \dot{\mathbf p}_i = \mathbf F_i, \qquad
        \dot{\mathbf s}_i = \frac{\sigma}{\hbar}\, \mathbf s_i \times \mathbf B_i .

    One step of size h (the paper's scheme (4), with its spin line derived from
    these equations; the printed sign is the opposite, see docs/paper.md):

    .. math::

        \mathbf P &= \mathbf p + \tfrac h2 \mathbf F(\mathbf q, \mathbf W), \qquad
        \tilde{\mathbf q} = \mathbf q + h M^{-1} \mathbf P, \\
        \tilde{\mathbf s} &= \mathbf s + \frac{h\sigma}{\hbar} \mathbf W \times
            \tfrac12 [\mathbf B(\mathbf q, \mathbf W) + \mathbf B(\tilde{\mathbf q}, \mathbf W)],
        \qquad \mathbf W = \frac{\mathbf s + \tilde{\mathbf s}}{|\mathbf s + \tilde{\mathbf s}|}, \\
        \tilde{\mathbf p} &= \mathbf P + \tfrac h2 \mathbf F(\tilde{\mathbf q}, \mathbf W).

    Parameters
    ----------
    atoms : Atoms
        With a :class:`~ase_spin.SpinLatticeCalculator` and spins set by
        :func:`~ase_spin.set_spins` (atoms with zero moment are non-magnetic).
    timestep : float
        In ASE time units (``0.1 * ase.units.fs``).
    hbar : float, optional
        ħ in eV·(ASE time); default the physical value :data:`HBAR`. The paper's
        reduced units are ``hbar=1``.
    precession : "moment" or "spin"
        σ = −1 (LAMMPS SPIN, ds/dt = ω × s with ω = B/ħ; the default) or σ = +1
        (the paper's spin convention).
    order : 2, 4 or 6
        4 and 6 are symmetric compositions of the second-order step (Suzuki's
        five-stage and Kahan–Li's nine-stage); ``composition`` picks another
        (see :data:`~ase_spin.md.compositions.COMPOSITIONS`).
    tol : float
        Stop the midpoint iteration when no spin component changes by more than
        this (default 1e-15, round-off for unit vectors). Spin lengths do not
        depend on it: the end point is the reflection of s about the converged
        midpoint (see :func:`~ase_spin.md.kernels.midpoint_solve`).
    max_iter : int
        Midpoint iterations allowed per solve (default 100). Not converging
        raises :class:`SpinConvergenceError`; the atoms keep the last good state.
    lattice : "moving" or "frozen"
        ``"frozen"`` integrates the spins only (as does fixing every atom with
        ``FixAtoms``); pair geometry is then computed once.
    trajectory, logfile, loginterval, **kwargs
        As for every ASE ``MolecularDynamics``, except that a ``trajectory`` file
        name that exists is refused (FileExistsError) unless
        ``append_trajectory=True``: see docs/restart.md. The log is a
        :class:`~ase_spin.md.logger.SpinMDLogger` line.

    Attributes
    ----------
    half_lists : bool
        Keep the exchange pair geometry on the half pair list (each pair once,
        per-thread buffers; the default) or on the full list (gather only).
    iterations : int
        Midpoint sweeps (over all spins) in the last step, all stages.
    geometry_evaluations : int
        Evaluations of the exchange pair geometry at q̃ in the last step.
    """

    half_lists = True

    def __init__(self, atoms, timestep, *, hbar=None, precession="moment", order=2,
                 composition=None, tol=None, max_iter=None, lattice="moving",
                 trajectory=None, logfile=None, loginterval=1, **kwargs):
        if not isinstance(precession, str) or precession not in ("moment", "spin"):
            raise ValueError(f'precession must be "moment" or "spin", got {precession!r}')
        if not isinstance(lattice, str) or lattice not in ("moving", "frozen"):
            raise ValueError(f'lattice must be "moving" or "frozen", got {lattice!r}')
        timestep = real_scalar(timestep, "timestep")
        if timestep == 0.0:
            raise ValueError("timestep must be non-zero")
        self.precession = precession
        self.sigma = -1.0 if precession == "moment" else 1.0
        self.hbar = HBAR if hbar is None else positive_scalar(hbar, "hbar")
        self.order, self.gammas = composition_coefficients(order, composition)
        self.tol = 1e-15 if tol is None else real_scalar(tol, "tol")
        if not TOL_RANGE[0] <= self.tol <= TOL_RANGE[1]:
            raise ValueError(f"tol must lie between {TOL_RANGE[0]:g} and {TOL_RANGE[1]:g} "
                             f"(a change of a unit spin component), got {self.tol:g}")
        self.max_iter = 100 if max_iter is None else integer(max_iter, "max_iter", minimum=1)
        self.frozen_lattice = lattice == "frozen"
        check_trajectory_target(trajectory, flag(kwargs.get("append_trajectory", False),
                                                 "append_trajectory"))
        super().__init__(atoms, timestep, trajectory=trajectory, logfile=None,
                         loginterval=loginterval, **kwargs)
        if logfile:
            logger = self.closelater(SpinMDLogger(self, logfile))
            self.attach(logger, loginterval)
        self.iterations = 0
        self.geometry_evaluations = 0
        self.total_iterations = 0
        self.total_steps = 0
        self._state = None

    def todict(self):
        return {**super().todict(), "order": self.order, "precession": self.precession,
                "hbar": self.hbar}

    # -- set-up and staleness --------------------------------------------------
    def _initialize(self):
        atoms = self.atoms
        calc = atoms.calc
        if not isinstance(calc, SpinLatticeCalculator):
            raise TypeError(f"{type(self).__name__} needs atoms.calc to be an ase_spin "
                            f"SpinLatticeCalculator, got {type(calc).__name__}")
        if not calc.hamiltonian.skin > 0.0:
            raise ValueError("CollectivePRK needs a neighbour-list skin > 0 (the "
                             "calculator's skin=...): one pair list serves q and q̃")
        masses = _checked_masses(atoms)
        momenta = _checked_momenta(atoms)
        ev, moments = calc.bound_evaluator(atoms)
        self._calc = calc
        self.ev = ev
        spins, mu = split_moments(moments)
        self.masses = masses[:, None]
        self._spin_terms = [t for t in ev.hamiltonian.terms if t.spin_dependent]
        self.magnetic = ev.any_magnetic and bool(self._spin_terms)
        self.frozen = self.frozen_lattice or self._all_fixed()
        st = _State()
        st.q = real_array(atoms.positions, "positions").copy()
        st.p = momenta
        st.s = np.ascontiguousarray(spins)
        st.mu = mu
        st.EL = st.EL_terms = None
        st.observables = None
        # rounding errors of the last updates (compensated summation)
        st.carry_q, st.carry_p, st.carry_s = (np.zeros_like(st.q) for _ in range(3))
        self._carry_mid = np.zeros_like(st.q)
        st.FL = np.zeros_like(st.q) if self.frozen else ev.lattice(st.q, _FORCES).forces
        st.Gq = ev.exchange_geometry(st.q, half=self.half_lists) if self.magnetic else None
        st.history = [deque(maxlen=4) for _ in self.gammas]
        st.predictor_order = [0 for _ in self.gammas]
        st.theta = [1.0 for _ in self.gammas]
        magnetic_rows = np.flatnonzero(ev.magnetic)
        self._probe = magnetic_rows[:: max(1, len(magnetic_rows) // 64)]
        self._Gqt = None
        self._Wnext = np.zeros_like(st.s)
        self._state = st
        self._remember_written()

    def _all_fixed(self):
        fixed = np.zeros(len(self.atoms), dtype=bool)
        for c in self.atoms.constraints:
            if isinstance(c, FixAtoms):
                fixed[c.index] = True
        return bool(fixed.all()) and len(self.atoms) > 0

    def _remember_written(self):
        """Snapshot of everything the cached state was derived from. Kept by
        value (copies), not by identity: Python reuses ids and arrays are edited
        in place."""
        a = self.atoms
        arrays = a.arrays
        self._written = (arrays["positions"].copy(), _copy(arrays.get("momenta")),
                         _copy(arrays.get("initial_magmoms")), _copy(arrays.get("masses")),
                         a.cell.array.copy(), a.pbc.tolist(), a.numbers.copy(),
                         copy.deepcopy(a.constraints) if a.constraints else [],
                         self.ev.state_token)

    def _in_sync(self):
        """True if the Atoms, their calculator and its terms are as this
        integrator left them (else every cache is stale: a user moved atoms; set
        spins, momenta, masses, cell or constraints; changed a term's parameter;
        or the calculator served other Atoms in between)."""
        if self._state is None:
            return False
        a = self.atoms
        pos, mom, mag, masses, cell, pbc, numbers, cons, token = self._written
        arrays = a.arrays
        calc = self._calc
        # cheapest tests first: this runs before every step
        return (a.calc is calc and calc.evaluator is self.ev
                and self.ev.state_token == token and not self.ev.stale()
                and len(a) == len(numbers) and a.pbc.tolist() == pbc
                and _same(a.cell.array, cell)
                and _same(arrays["positions"], pos)
                and _same(arrays.get("momenta"), mom)
                and _same(arrays.get("initial_magmoms"), mag)
                and _same(arrays.get("masses"), masses)
                and _same(arrays["numbers"], numbers)
                and (not cons and not a.constraints or _equal(list(a.constraints), cons)))

    def _sync(self):
        if not self._in_sync():
            self._state = None
            self._initialize()
        return self._state

    def _restore(self, snapshot):
        """Put the Atoms back as they were at ``snapshot`` (after a failed or
        interrupted step), in place where possible."""
        pos, mom, mag, *_ = snapshot
        arrays = self.atoms.arrays
        for name, saved in (("positions", pos), ("momenta", mom), ("initial_magmoms", mag)):
            now = arrays.get(name)
            if saved is None:
                arrays.pop(name, None)
            elif now is not None and now.shape == saved.shape and now.dtype == saved.dtype:
                now[:] = saved
            else:
                arrays[name] = saved.copy()

    # -- the step ---------------------------------------------------------------
    def step(self):
        """Advance by one time step (all composition stages)."""
        with threads.threads_for(len(self.atoms)):
            self._step()

    def irun(self, steps=50):
        """ASE's ``MolecularDynamics.irun``, with the step counter advanced
        together with the Atoms: an interrupt (Ctrl-C) leaves both at the state
        before a step or both after it."""
        self.max_steps = self.nsteps + steps
        if self.nsteps == 0:
            self._refresh_properties()
            self.log()
            self.call_observers()
        yield self.nsteps == self.max_steps
        while self.nsteps < self.max_steps:
            with threads.threads_for(len(self.atoms)):
                self._step(count=True)
            self._refresh_properties()
            self.log()
            self.call_observers()
            yield self.nsteps == self.max_steps

    def _step(self, count=False):
        st = self._sync()
        before = self._written
        nsteps = self.nsteps
        want_energy = self._observer_due(self.nsteps + 1)
        iterations = geometries = 0
        try:
            last = len(self.gammas) - 1
            for stage, gamma in enumerate(self.gammas):
                it, ng = self._substep(gamma * self.dt, stage, want_energy and stage == last)
                iterations += it
                geometries += ng
            self._check_state_finite()
            if self.atoms.constraints:  # positions and momenta set by constraints: no carries
                st = self._state
                for carry in (st.carry_q, st.carry_p, st.carry_s):
                    carry[:] = 0.0
            self._commit()
            if count:
                self.nsteps = nsteps + 1
        except BaseException:
            # an error or an interrupt (Ctrl-C) anywhere in the step, the write-back
            # included: the Atoms go back to the state before it, whole
            self._state = None
            self.nsteps = nsteps
            self._restore(before)
            raise
        self.iterations = iterations
        self.geometry_evaluations = geometries
        self.total_iterations += iterations
        self.total_steps += 1

    def _check_state_finite(self):
        st = self._state
        for name, x in (("positions", st.q), ("momenta", st.p), ("spins", st.s)):
            bad = kernels.first_nonfinite_row(x)
            if bad >= 0:
                raise IntegrationError(
                    f"the step gave non-finite {name} ({_name_atoms([bad])}) at step "
                    f"{self.nsteps}: the forces or fields are not finite or the timestep "
                    f"({self.dt / units.fs:.4g} fs) is far too large. The atoms keep the "
                    f"state before this step.")

    def _commit(self):
        """Write the new state into the Atoms: in place (so references to
        ``atoms.positions`` stay live), float64 whatever dtype the user's arrays
        had (an integer or float32 array is replaced, not truncated)."""
        st = self._state
        arrays = self.atoms.arrays
        _write(arrays, "positions", st.q)
        _write(arrays, "momenta", st.p)
        if self.magnetic:
            _write(arrays, "initial_magmoms", st.mu[:, None] * st.s)
        st.observables = None
        self._remember_written()

    def _observer_due(self, n):
        for _, interval, _, _ in self.observers:
            if (interval > 0 and n % interval == 0) or (interval <= 0 and n == -interval):
                return True
        return False

    def _substep(self, h, stage, want_energy):
        """One second-order step of size h; returns (midpoint sweeps, geometries)."""
        st = self._state
        if not self.magnetic:
            self._lattice_step(h, want_energy)
            return 0, 0
        if self.frozen:
            W, st.s, its, _ = self._solve(st.s, st.Gq, self._predict(stage), h, stage,
                                          frozen=True)
            st.carry_s = self._carry_s_new
            self._remember_midpoint(stage, W)
            return its, 0
        return self._coupled_step(h, stage, want_energy)

    def _lattice_step(self, h, want_energy):
        """Velocity Verlet (no spins to move)."""
        st = self._state
        P = np.empty_like(st.p)
        kernels.kick(st.p, 0.5 * h, self._md_forces(st.FL, st.q), st.carry_p, P,
                     self._carry_mid)
        qt, P = self._drift(st.q, P, h)
        st.carry_q = self._carry_q_new
        self._check_displacement(st.q, qt, h)
        self._lattice_at(qt, want_energy)
        Ft = self._md_forces(st.FL, qt)
        kernels.kick(P, 0.5 * h, Ft, self._carry_mid, P, st.carry_p)
        st.q = qt
        st.p = self._adjust_momenta(P, qt)

    def _coupled_step(self, h, stage, want_energy):
        st = self._state
        ev = self.ev
        q, p, s = st.q, st.p, st.s
        W = self._predict(stage)
        qtol = 4.0 * _EPS * max(1.0, float(np.abs(q).max()))
        P = np.empty_like(p)
        qt_used = None
        iterations = geometries = 0
        for _ in range(_MAX_OUTER):
            F = self._exchange_forces(st.Gq, W, st.FL)
            kernels.kick(p, 0.5 * h, self._md_forces(F, q), st.carry_p, P, self._carry_mid)
            qt, P = self._drift(q, P, h)
            if qt_used is None:
                self._check_displacement(q, qt, h)
            elif kernels.max_abs_difference(qt, qt_used) <= qtol:
                break
            if ev.refresh(qt):  # a new pair list: G(q) must use it too
                st.Gq = ev.exchange_geometry(q, half=self.half_lists)
            self._Gqt = ev.exchange_geometry(qt, out=self._Gqt, mean_with=st.Gq,
                                             half=self.half_lists)
            geometries += 1
            W, s_new, its, moved = self._solve(s, self._Gqt, W, h, stage)
            iterations += its
            qt_used = qt
            if moved <= 8.0 * self.tol:
                # W moved by round-off only: P and q̃ computed from it stand
                break
        else:
            raise SpinConvergenceError(
                f"positions q̃ and midpoint spins did not settle in {_MAX_OUTER} "
                f"outer iterations at step {self.nsteps}; reduce the timestep")
        self._lattice_at(qt, want_energy)
        F = self._exchange_forces(self._Gqt, W, st.FL)
        kernels.kick(P, 0.5 * h, self._md_forces(F, qt), self._carry_mid, P, st.carry_p)
        st.carry_q, self._carry_q_new = self._carry_q_new, st.carry_q
        st.carry_s = self._carry_s_new
        self._remember_midpoint(stage, W)
        st.q, st.p, st.s = qt, self._adjust_momenta(P, qt), s_new
        st.Gq, self._Gqt = self._Gqt, st.Gq
        return iterations, geometries

    # -- pieces -------------------------------------------------------------------
    def _lattice_at(self, q, want_energy):
        """The one lattice evaluation of a step: F_L(q̃) (and E_L if logged)."""
        st = self._state
        res = self.ev.lattice(q, Want(forces=True, energy=want_energy))
        st.FL = res.forces
        st.EL = res.energy if want_energy else None
        st.EL_terms = res.energy_terms if want_energy else None

    def _exchange_forces(self, geoms, W, FL):
        """F_L + F_ex(q, W) from cached pair geometry (a new array)."""
        F = FL.copy()
        self.ev.spin(geoms, W, _FORCES, forces=F)
        return F

    def _check_displacement(self, q, qt, h):
        """One step may move an atom at most half the neighbour-list skin: that
        keeps one pair list valid at both q and q̃, and anything near it means the
        lattice integration has blown up (a Störmer–Verlet step moves atoms by
        ~1e-3 Å at ordinary temperatures and timesteps)."""
        limit = 0.5 * self.ev.neighbors.skin
        moved, atom = max_displacement(q, qt)
        if not moved <= limit:
            raise UnstableStepError(
                f"atom {atom} moved {moved:.3g} Å in one step (at most half the "
                f"neighbour-list skin, {limit:.3g} Å, is allowed) at step {self.nsteps}: "
                f"the lattice integration is unstable at this timestep "
                f"({h / units.fs:.4g} fs); reduce it. The atoms keep the state before "
                f"this step.")

    def _drift(self, q, P, h):
        """q̃ = q + h P/m, with constraints applied as VelocityVerlet does
        (RATTLE's first half: P is recomputed from the constrained q̃)."""
        qt = np.empty_like(q)
        st = self._state
        self._carry_q_new = np.empty_like(q)
        kernels.drift(q, P, self.masses[:, 0], h, st.carry_q, qt, self._carry_q_new)
        atoms = self.atoms
        if atoms.constraints:
            # positions set by constraints: nothing to compensate
            self._carry_q_new[:] = 0.0
            st.carry_p[:] = 0.0
            atoms.arrays["positions"][:] = q
            for c in atoms.constraints:
                c.adjust_positions(atoms, qt)
            P = (qt - q) * self.masses / h
        return qt, P

    def _md_forces(self, F, q):
        """Forces as ``atoms.get_forces(md=True)`` would give them."""
        atoms = self.atoms
        if not atoms.constraints:
            return F
        F = F.copy()
        atoms.arrays["positions"][:] = q
        for c in atoms.constraints:
            if hasattr(c, "redistribute_forces_md"):
                c.redistribute_forces_md(atoms, F)
            if hasattr(c, "adjust_potential_energy"):
                c.adjust_forces(atoms, F)
        return F

    def _adjust_momenta(self, p, q):
        atoms = self.atoms
        if not atoms.constraints:
            return p
        atoms.arrays["positions"][:] = q
        for c in atoms.constraints:
            if hasattr(c, "adjust_momenta"):
                c.adjust_momenta(atoms, p)
        return p

    def _predict(self, stage):
        """Starting midpoint spins: extrapolated from the last steps' midpoints at
        this stage (by the polynomial order that did best last time), else s."""
        st = self._state
        history = st.history[stage]
        if not history:
            return st.s.copy()
        return kernels.extrapolate(history, min(st.predictor_order[stage], len(history) - 1))

    def _remember_midpoint(self, stage, W):
        st = self._state
        history = st.history[stage]
        if history:
            st.predictor_order[stage] = kernels.best_extrapolation_order(history, W,
                                                                         self._probe)
        history.append(W)

    def _solve(self, s, geoms, W, h, stage, frozen=False):
        """Midpoint spins for the couplings J̄ = ½[J(q) + J(q̃)] held in ``geoms``
        (``Jbar``; ``J`` itself with a frozen lattice). Returns (W, s̃, sweeps,
        how far W moved from the starting guess)."""
        scale = h * self.sigma / self.hbar
        floor = 64.0 * self.tol
        couplings = [g.J if frozen else g.Jbar for g in geoms]
        if len(geoms) == 1:
            pairs = geoms[0].pairs
            stilde = np.zeros_like(s)
            self._carry_s_new = np.zeros_like(s)
            solve = kernels.midpoint_solve_half if pairs.half else kernels.midpoint_solve
            its, delta, status, which, theta, moved = solve(
                threads.count(), pairs.row, pairs.j, couplings[0], s, W, self._Wnext,
                stilde, scale, self.tol, floor, self.max_iter,
                min(1.0, 2.0 * self._state.theta[stage]), self._state.carry_s,
                self._carry_s_new)
            self._state.theta[stage] = theta if theta < 1.0 else self._state.theta[stage]
            if which == 1:
                W, self._Wnext = self._Wnext, W
        else:
            W0 = W
            W, stilde, its, delta, status = self._solve_terms(s, geoms, couplings, W, scale,
                                                              floor)
            moved = float(np.abs(W - W0).max()) if len(W) else 0.0
            self._carry_s_new = np.zeros_like(s)
        if status == kernels.NOT_CONVERGED:
            self._raise_not_converged(geoms, couplings, W, its, delta, scale)
        return W, stilde, its, moved

    def _solve_terms(self, s, geoms, couplings, W, scale, floor):
        """The same iteration for several spin terms (B̄ summed over terms)."""
        mean = [ExchangeGeometry(g.pairs, J, g.G, None) for g, J in zip(geoms, couplings)]
        want = Want(magnetic_forces=True)
        magnetic = self.ev.magnetic[:, None]
        previous = np.inf
        for it in range(1, self.max_iter + 1):
            B = self.ev.spin(mean, W, want).magnetic_forces
            stilde = s + scale * np.cross(W, B)
            v = s + stilde
            norm = np.linalg.norm(v, axis=1)
            norm[norm == 0.0] = 1.0
            Wn = np.where(magnetic, v / norm[:, None], 0.0)
            delta = float(np.abs(Wn - W).max()) if len(W) else 0.0
            W = Wn
            if not delta <= 2.0:
                return W, stilde, it, delta, kernels.NOT_CONVERGED
            if delta <= self.tol:
                return W, stilde, it, delta, kernels.CONVERGED
            if delta <= floor and delta >= previous:
                return W, stilde, it, delta, kernels.ROUNDOFF
            previous = delta
        return W, stilde, self.max_iter, delta, kernels.NOT_CONVERGED

    def _raise_not_converged(self, geoms, couplings, W, its, delta, scale):
        field = np.zeros(len(W))
        for g, J in zip(geoms, couplings):
            field += np.bincount(g.pairs.i, weights=np.abs(J), minlength=len(W))
            if g.pairs.half:
                field += np.bincount(g.pairs.j, weights=np.abs(J), minlength=len(W))
        x = abs(scale) * float(field.max()) if len(field) else 0.0
        raise SpinConvergenceError(
            f"the midpoint-spin iteration did not converge at step {self.nsteps}: "
            f"max |ΔW| = {delta:.3g} after {its} iterations (tol {self.tol:.1e}). "
            f"h·max|B|/ħ ≈ {x:.3g} rad; the iteration contracts only while this is "
            f"well below 2. Reduce the timestep (now {self.dt / units.fs:.4g} fs) "
            f"or raise max_iter. The atoms keep the state before this step.")

    # -- observables (computed only when read) ---------------------------------
    def _observables(self):
        st = self._sync()
        if st.observables is not None:
            return st.observables
        with threads.threads_for(len(self.atoms)):
            return self._compute_observables(st)

    def _compute_observables(self, st):
        ev = self.ev
        terms = {}
        if st.EL_terms is None:
            res = ev.lattice(st.q, Want(energy=True))
            st.EL, st.EL_terms = res.energy, res.energy_terms
        terms.update(st.EL_terms)
        B = np.zeros_like(st.s)
        if self.magnetic:
            res = ev.spin(st.Gq, st.s, Want(energy=True, magnetic_forces=True),
                          magnetic_forces=B)
            terms.update(res.energy_terms)
        for name in ev.hamiltonian.term_names:
            terms.setdefault(name, 0.0)
        extra = 0.0
        for c in self.atoms.constraints:
            if hasattr(c, "adjust_potential_energy"):
                extra += c.adjust_potential_energy(self.atoms)
        st.observables = {"terms": terms, "B": B, "extra": extra}
        return st.observables

    def get_energy_terms(self):
        """Potential energy by term (eV), at the current state."""
        return dict(self._observables()["terms"])

    def get_potential_energy(self):
        obs = self._observables()
        return float(sum(obs["terms"].values()) + obs["extra"])

    def get_kinetic_energy(self):
        st = self._sync()
        return float(0.5 * np.einsum("ij,ij->", st.p, st.p / self.masses))

    def get_total_energy(self):
        return self.get_potential_energy() + self.get_kinetic_energy()

    def get_magnetic_forces(self):
        """B_i = −∂E/∂s_i (eV) at the current state."""
        return self._observables()["B"].copy()

    def get_magnetization(self):
        """Mean unit spin over the magnetic atoms (LAMMPS ``compute spin``'s first
        three values; their norm is |M|)."""
        st = self._sync()
        n = int(self.ev.magnetic.sum())
        return st.s.sum(axis=0) / n if n else np.zeros(3)

    def get_spin_temperature(self):
        r"""The spin temperature of LAMMPS ``compute spin`` (Nurdin et al.):

        .. math:: T_s = \frac{\sum_i |\mathbf s_i \times \mathbf B_i|^2}
                             {2 k_B \sum_i \mathbf s_i\cdot\mathbf B_i}

        (LAMMPS writes it with ω = B/ħ and a factor ħ). NaN without magnetic atoms.
        """
        st = self._sync()
        B = self._observables()["B"]
        den = float(np.einsum("ij,ij->", st.s, B))
        if not self.magnetic or den == 0.0:
            return float("nan")
        num = float((np.cross(st.s, B) ** 2).sum())
        return num / (2.0 * units.kB * den)

    def get_temperature(self):
        dof = len(self.atoms) * 3
        for c in self.atoms.constraints:
            dof -= c.get_removed_dof(self.atoms)
        return 2.0 * self.get_kinetic_energy() / (max(dof, 1) * units.kB)

    @property
    def mean_iterations(self):
        """Midpoint sweeps per step, averaged over the steps taken so far."""
        return self.total_iterations / self.total_steps if self.total_steps else 0.0

    def _refresh_properties(self):
        # ASE asks the calculator for forces after every step so that loggers
        # find them cached; this integrator's logger reads its own state, so
        # that would be one wasted full evaluation per step.
        pass


def _copy(a):
    return None if a is None else a.copy()


def _write(arrays, name, values):
    """arrays[name] = values, in place if the array is float64 of that shape."""
    now = arrays.get(name)
    if now is not None and now.dtype == np.float64 and now.shape == values.shape:
        now[:] = values
    else:
        arrays[name] = np.array(values, dtype=np.float64)


def _checked_masses(atoms):
    masses = real_array(atoms.get_masses(), "masses")
    bad = np.flatnonzero(~(np.isfinite(masses) & (masses > 0.0)))
    if bad.size:
        raise ValueError(f"masses must be finite and positive; {_name_atoms(bad)} "
                         f"{'has' if bad.size == 1 else 'have'} mass {float(masses[bad[0]])}")
    return masses


def _checked_momenta(atoms):
    if "momenta" not in atoms.arrays:
        return np.zeros((len(atoms), 3))
    p = real_array(atoms.arrays["momenta"], "momenta", shape=(len(atoms), 3)).copy()
    bad = np.flatnonzero(~np.isfinite(p).all(axis=1))
    if bad.size:
        raise ValueError(f"momenta are not finite for {_name_atoms(bad)}")
    return p
