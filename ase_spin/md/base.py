"""What every spin–lattice integrator here shares: the base of CollectivePRK,
SuzukiTrotter and any integrator to come (one new file, one step method).

:class:`SpinLatticeDynamics` owns the bond with the Atoms — reading the state,
noticing any change to it (or to the calculator and its terms) between steps,
writing a step back whole or not at all (errors and Ctrl-C alike), the
constraints, the compensated (Kahan) kick and drift, velocity Verlet when there
are no spins to move, and the observables. A subclass implements
``_substep(h, stage, want_energy)``: advance ``self._state`` by one
second-order step of size h, and optionally ``_prepare(state)`` to add its own
per-run buffers to the state.
"""

from __future__ import annotations

import copy
import warnings

import numpy as np
from ase import units
from ase.constraints import FixAtoms
from ase.md.md import MolecularDynamics

from .._jit import threads
from .._jit.threads import AdaptiveThreads
from ..calculator import SpinLatticeCalculator
from ..constants import HBAR
from ..io.progress import run_with_progress
from ..io.trajectories import check_trajectory_target
from ..neighbors import max_displacement
from ..spins import name_atoms, split_moments
from ..terms.base import Want
from ..validate import flag, positive_scalar, real_array, real_scalar
from . import kernels
from .compositions import composition_coefficients
from .logger import SpinMDLogger

__all__ = ["SpinLatticeDynamics", "TimestepWarning", "IntegrationError", "SpinConvergenceError",
           "UnstableStepError", "HBAR"]

_FORCES = Want(forces=True)
_NO_FIELD = np.zeros((0, 3))
_NO_ENERGIES = np.zeros(0)
#: Want of the step's lattice evaluation, by (energy, virial)
_LATTICE = {(e, v): Want(forces=True, energy=e, virial=v)
            for e in (False, True) for v in (False, True)}


#: Largest phase (rad) the fastest precession or vibration may turn per step
#: without a warning (about 20 steps per period, the usual MD rule).
MAX_PHASE = 0.3
#: Smallest plausible timestep (fs) without a warning.
MIN_TIMESTEP_FS = 1e-3


class TimestepWarning(UserWarning):
    """The timestep is implausible for the system (too large for its fastest
    precession or vibration, or absurdly small)."""


class IntegrationError(RuntimeError):
    """A step could not be taken; the Atoms keep the state before it."""


class SpinConvergenceError(IntegrationError):
    """The implicit equation for the midpoint spins was not solved."""


class UnstableStepError(IntegrationError):
    """The step is implausibly large: an atom moved too far, or a spin was to
    rotate too far, in one step."""


class State:
    """What an integrator holds between steps (design.md, "one step as data").

    q, p, s, mu: positions, momenta, unit spins, moment magnitudes. FL: lattice
    forces at q. ops: the spin terms prepared at q (SpinOperators). EL, EL_terms: lattice
    energy when it was asked for. carry_*: rounding errors of the compensated
    updates. Subclasses add their own fields in ``_prepare``.
    """

    def __init__(self, **fields):
        self.__dict__.update(fields)

    def __getstate__(self):
        # the fused step's compiled pieces are a cache, rebuilt on use: not data
        state = dict(self.__dict__)
        state.pop("fused", None)
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)


def _same(a, b):
    if a is None or b is None:
        return a is b
    if a.shape != b.shape or a.dtype != b.dtype:
        return False
    if a.nbytes <= 8192 and a.flags.c_contiguous and b.flags.c_contiguous:
        # small arrays: the bytes, cheaper than a compiled call (stricter too:
        # -0.0 and 0.0 differ, so at worst a needless resync)
        return a.tobytes() == b.tobytes()
    return kernels.same(a, b)


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



#: Most steps :meth:`SpinLatticeDynamics.run` takes in one block (small systems,
#: nothing observing the run in between): an interrupt waits for at most this many.
QUIET_BLOCK = 256
#: and when the adaptive thread count tries another count (a probe: it may be a
#: bad one on a busy machine)
PROBE_BLOCK = 16


class SpinLatticeDynamics(MolecularDynamics):
    """Base of the spin–lattice integrators (see the module docstring).

    Parameters common to all: ``timestep`` (ASE time units), ``hbar`` (default
    :data:`HBAR`), ``precession`` ("moment": σ = −1, LAMMPS; "spin": σ = +1, the
    paper), ``gyromagnetic`` ("lammps": ds_i/dt = (σ/ħ) s_i × B_i whatever the
    moment, LAMMPS SPIN's equation; "moment": ds_i/dt = (σ g/(μ_i ħ)) s_i × B_i,
    the Landau–Lifshitz precession of a moment μ_i μB, with ``g`` = 2 by
    default), ``order``/``composition`` (symmetric compositions of the step),
    ``lattice`` ("moving" or "frozen"), ``threads`` ("auto": all configured
    threads or one, whichever runs the steps faster right now, see
    :class:`~ase_spin._jit.threads.AdaptiveThreads`; or a fixed count; default from
    the environment variable ``ASE_SPIN_THREADS``), and ASE's ``trajectory``,
    ``logfile``, ``loginterval``, ``append_trajectory``.
    """

    half_lists = True

    def __init__(self, atoms, timestep, *, hbar=None, precession="moment",
                 gyromagnetic="lammps", g=2.0, order=2, composition=None, lattice="moving",
                 threads=None, trajectory=None, logfile=None, loginterval=1, **kwargs):
        if not isinstance(precession, str) or precession not in ("moment", "spin"):
            raise ValueError(f'precession must be "moment" or "spin", got {precession!r}')
        if not isinstance(gyromagnetic, str) or gyromagnetic not in ("lammps", "moment"):
            raise ValueError(f'gyromagnetic must be "lammps" or "moment", got {gyromagnetic!r}')
        self.gyromagnetic = gyromagnetic
        self.g = positive_scalar(g, "g")
        if not isinstance(lattice, str) or lattice not in ("moving", "frozen"):
            raise ValueError(f'lattice must be "moving" or "frozen", got {lattice!r}')
        timestep = real_scalar(timestep, "timestep")
        if timestep == 0.0:
            raise ValueError("timestep must be non-zero")
        self.precession = precession
        self.sigma = -1.0 if precession == "moment" else 1.0
        self.hbar = HBAR if hbar is None else positive_scalar(hbar, "hbar")
        self.order, self.gammas = composition_coefficients(order, composition)
        self.frozen_lattice = lattice == "frozen"
        self.threads = AdaptiveThreads(threads)
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
        # time = t0 + (nsteps - n0)·dt0: exact nsteps·dt until dt is changed
        self._clock = (0.0, 0, self.dt)
        self._checked_dt = None

    def get_time(self):
        """Simulated time (ASE units), accumulated step by step: changing
        ``dyn.dt`` between runs keeps the time of the steps already taken."""
        t0, n0, dt0 = self._clock
        return t0 + (self.nsteps - n0) * dt0

    def _rebase_clock(self):
        t0, n0, dt0 = self._clock
        if self.dt != dt0:
            dt = real_scalar(self.dt, "timestep (dyn.dt)")
            if dt == 0.0:
                raise ValueError("timestep (dyn.dt) must be non-zero")
            self._clock = (self.get_time(), self.nsteps, dt)

    def __getstate__(self):
        """Pickle and deepcopy: everything but the closing of files (the log
        line reopens its file, appending; see SpinMDLogger)."""
        state = dict(self.__dict__)
        state.pop("_exitstack", None)
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        for function, *_ in self.observers:
            if isinstance(function, SpinMDLogger):
                self.closelater(function)

    def todict(self):
        return {**super().todict(), "order": self.order, "precession": self.precession,
                "gyromagnetic": self.gyromagnetic, "g": self.g, "hbar": self.hbar,
                "threads": self.threads.setting}

    # -- set-up and staleness --------------------------------------------------
    def _initialize(self):
        atoms = self.atoms
        calc = atoms.calc
        if not isinstance(calc, SpinLatticeCalculator):
            raise TypeError(f"{type(self).__name__} needs atoms.calc to be an ase_spin "
                            f"SpinLatticeCalculator, got {type(calc).__name__}")
        if calc.hamiltonian.cutoff > 0.0 and not calc.hamiltonian.skin > 0.0:
            raise ValueError(f"{type(self).__name__} needs a neighbour-list skin > 0 (the "
                             "calculator's skin=...): one pair list serves q and q̃")
        masses = _checked_masses(atoms)
        momenta = _checked_momenta(atoms)
        ev, moments = calc.bound_evaluator(atoms)
        self._calc = calc
        self.ev = ev
        spins, mu = split_moments(moments)
        self.masses = masses[:, None]
        self.magnetic = ev.any_magnetic and bool(ev.hamiltonian.spin_terms)
        self.frozen = self.frozen_lattice or self._all_fixed()
        q = real_array(atoms.positions, "positions").copy()
        st = State(q=q, p=momenta, s=np.ascontiguousarray(spins), mu=mu,
                   rate=self._precession_rates(mu), scales={}, EL=None,
                   EL_terms=None, VL=None, observables=None,
                   # rounding errors of the last updates (compensated summation)
                   carry_q=np.zeros_like(q), carry_p=np.zeros_like(q),
                   carry_s=np.zeros_like(q), carry_mid=np.zeros_like(q))
        if self.frozen:
            st.FL = np.zeros_like(q)
        else:  # with energy (and virial) if a log line (a frame) is written now
            frame = self._frame_due(self.nsteps)
            res = ev.lattice(q, Want(forces=True, energy=self._observer_due(self.nsteps),
                                     virial=frame and self._stress_available()))
            st.FL, st.EL, st.EL_terms, st.VL = (res.forces, res.energy,
                                                res.energy_terms, res.virial)
        if self._checked_dt != self.dt:
            self._check_timestep(q, spins, mu, masses, st.FL)
        st.ops = ev.spin_operators(q, half=self.half_lists) if self.magnetic else None
        self._prepare(st)
        self._state = st
        self._remember_written()

    def _prepare(self, state):
        """Add an integrator's own per-run fields to a fresh state."""

    def _check_timestep(self, q, spins, mu, masses, forces):
        r"""Warn when the timestep h is implausible for this system, with its value
        in fs: h·ω > :data:`MAX_PHASE` for the fastest spin precession,
        ω_s = max_i r_i |B_i|/ħ (r_i the precession rate factor), or for the
        fastest vibration, ω_v² ≈ max_i |ΔF_i|/(m_i |δ_i|) from one lattice
        evaluation at positions displaced by δ (|δ_i| = 10⁻³ Å, random
        directions); or |h| below :data:`MIN_TIMESTEP_FS` fs (a unit slip)."""
        self._checked_dt = self.dt
        h = abs(self.dt)
        ev = self.ev
        problems = []
        if h < MIN_TIMESTEP_FS * units.fs:
            problems.append(f"it is below {MIN_TIMESTEP_FS} fs")
        if self.magnetic:
            # one direct pass over the half list: no pair geometry kept for this
            B = ev.evaluate(q, spins, Want(magnetic_forces=True)).magnetic_forces
            omega = float(np.max(self._precession_rates(mu) * np.linalg.norm(B, axis=1)))
            omega /= self.hbar
            if h * omega > MAX_PHASE:
                problems.append(f"the fastest spin precesses by {h * omega:.2g} rad per step "
                                f"(period {2 * np.pi / omega / units.fs:.3g} fs)")
        if not self.frozen and len(q) > 1:
            rng = np.random.default_rng(0)
            d = rng.normal(size=q.shape)
            d *= 1e-3 / np.linalg.norm(d, axis=1)[:, None]
            dF = ev.lattice(q + d, _FORCES).forces - forces
            k = np.linalg.norm(dF, axis=1) / 1e-3
            omega = float(np.sqrt(np.max(k / masses)))
            if h * omega > MAX_PHASE:
                problems.append(f"the fastest vibration turns by {h * omega:.2g} rad per step "
                                f"(period ≈ {2 * np.pi / omega / units.fs:.3g} fs)")
        if problems:
            warnings.warn(
                f"timestep {self.dt / units.fs:.4g} fs ({self.dt:.4g} ASE time units; "
                f"1 fs = ase.units.fs = {units.fs:.4g}): {'; '.join(problems)}. Timesteps "
                f"are in ASE units: write e.g. timestep=0.1 * ase.units.fs. Keep h·ω below "
                f"{MAX_PHASE} rad for accurate dynamics.", TimestepWarning, stacklevel=4)

    def _precession_rates(self, mu):
        """Per-spin factor r_i of the precession, ds_i/dt = r_i (σ/ħ) s_i × B_i:
        1 (LAMMPS) or g/μ_i (a moment μ_i μB: the Landau–Lifshitz precession)."""
        if self.gyromagnetic == "lammps":
            return np.ones_like(mu)
        rate = np.zeros_like(mu)
        np.divide(self.g, mu, out=rate, where=mu > 0.0)
        return rate


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
        # the buffers the next step's snapshot of positions, momenta and moments
        # goes to (_commit: the ones held now stay intact for _restore); kept
        # while the size holds (this also runs after every step that cannot
        # take the compiled commit, e.g. without moments)
        shape = self._written[0].shape
        spare = getattr(self, "_spare", None)
        if spare is None or spare[0].shape != shape:
            self._spare = tuple(np.empty(shape) for _ in range(3))
        # whether the snapshot's positions, momenta and moments are all (n, 3)
        # float64 (only _commit's compiled pass sets it)
        self._snapshot_rows = False

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
        if not (a.calc is calc and calc.evaluator is self.ev
                and self.ev.state_token == token and not self.ev.stale()
                and len(a) == len(numbers) and a.pbc.tolist() == pbc
                and _same(a.cell.array, cell)):
            return False
        now = (arrays["positions"], arrays.get("momenta"), arrays.get("initial_magmoms"))
        shape = pos.shape
        if (self._snapshot_rows and _rows3(now[0], shape) and _rows3(now[1], shape)
                and _rows3(now[2], shape)):
            # the three arrays a step writes, in one compiled call
            same = kernels.same_rows(now[0], pos, now[1], mom, now[2], mag)
        else:
            same = _same(now[0], pos) and _same(now[1], mom) and _same(now[2], mag)
        return (same
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
        with self.threads.step(len(self.atoms)):
            self._step()

    def irun(self, steps=50):
        """ASE's ``MolecularDynamics.irun``, with the step counter advanced
        together with the Atoms: an interrupt (Ctrl-C) leaves both at the state
        before a step or both after it."""
        return self._irun(steps, blocks=False)

    def _irun(self, steps, blocks):
        """:meth:`irun`; with ``blocks``, the steps after which nothing observes
        the run (no log line, frame or observer due) may be taken several at a
        time (:meth:`_quiet_steps`), the Atoms written and the counter advanced
        after each block: the same states, fewer returns to Python."""
        self.max_steps = self.nsteps + steps
        if self.nsteps == 0:
            self._refresh_properties()
            self.log()
            self.call_observers()
        yield self.nsteps == self.max_steps
        blocked = False  # a block was taken: time blocks only (see below)
        stopped = False  # the last block stopped before a step it could not take
        # the state is as the last step left it: nothing but this loop has run
        # since (no observer due, no caller between the steps of run()), so the
        # next step need not compare the Atoms with it (two reads of (N, 3)
        # arrays per step, ~4 % of a step at 32 000 atoms)
        synced = False
        while self.nsteps < self.max_steps:
            # after a block that stopped early, that step the usual way first
            quiet = self._steps_unobserved() if blocks and not stopped else 0
            with self.threads.step(len(self.atoms)) as context:
                done = 0
                tried = quiet >= 2 and self._blocks_possible()
                if tried:
                    if getattr(context, "probing", False):
                        quiet = min(quiet, PROBE_BLOCK)
                    done = self._quiet_steps(quiet)
                stopped = 0 < done < quiet
                timed = hasattr(context, "steps")
                if done:
                    blocked = True
                    if timed:
                        context.steps = done
                else:
                    self._step(count=True, synced=tried or synced)
                    if blocked and timed:
                        # a step alone pays Python's share that a block spreads
                        # over its steps: the thread counts are judged on blocks
                        context.steps = 0
            self._refresh_properties()
            self.log()
            synced = (blocks and self._state is not None
                      and not self._observer_due(self.nsteps))
            self.call_observers()
            yield self.nsteps == self.max_steps

    def run(self, steps=50, progress=False):
        """ASE's ``run``; ``progress=True`` (or a dict of tqdm options) shows a
        progress bar with steps/s and the time left (:mod:`ase_spin.io.progress`)."""
        if progress:
            return run_with_progress(self, steps, progress)
        converged = False
        for converged in self._irun(steps, blocks=True):
            pass
        return converged

    def _steps_unobserved(self):
        """How many of the next steps end with no observer due (so that no
        energy, frame or Python call is needed between them), at most
        :data:`QUIET_BLOCK` and the steps left in the run."""
        n0 = self.nsteps
        ahead = min(self.max_steps - n0, QUIET_BLOCK)
        for _, interval, _, _ in self.observers:
            if interval > 0:
                due = (n0 // interval + 1) * interval
            elif -interval > n0:
                due = -interval
            else:
                continue
            ahead = min(ahead, due - n0 - 1)
        return ahead

    def _quiet_steps(self, steps):
        """Take up to ``steps`` steps at once, nothing observing the run between
        them, and write the Atoms after the last (an integrator that can:
        :meth:`_steps_at_once`). Returns the steps taken (0: none, take one
        the usual way). An error or interrupt leaves the Atoms and the counter
        as they were before the block."""
        self._rebase_clock()
        self._sync()
        before = self._written
        nsteps = self.nsteps
        try:
            done, sweeps, last_sweeps, last_geometries = self._steps_at_once(steps)
            if done:
                self._commit()
                self.nsteps = nsteps + done
        except BaseException:
            self._state = None
            self.nsteps = nsteps
            self._restore(before)
            raise
        if done:
            self.iterations = last_sweeps
            self.geometry_evaluations = last_geometries
            self.total_iterations += sweeps
            self.total_steps += done
        return done

    def _blocks_possible(self):
        """Whether :meth:`_steps_at_once` may take steps (a quick test before the
        state is synchronised)."""
        return False

    def _steps_at_once(self, steps):
        """Up to ``steps`` whole steps in one call, the Atoms not written: (steps
        done, sweeps in all, sweeps and geometries of the last step). None here."""
        return 0, 0, 0, 0

    def _step(self, count=False, synced=False):
        """One step (all stages); ``synced``: the clock and the state have just
        been brought up to date (:meth:`_quiet_steps`, which took no step)."""
        if synced:
            st = self._state
        else:
            self._rebase_clock()
            st = self._sync()
        before = self._written
        nsteps = self.nsteps
        want_energy = self._observer_due(self.nsteps + 1)
        # a frame to write after this step: the lattice call gives the virial too
        self._frame_virial = self._frame_due(self.nsteps + 1) and self._stress_available()
        iterations = geometries = 0
        try:
            last = len(self.gammas) - 1
            for stage, gamma in enumerate(self.gammas):
                it, ng = self._substep(gamma * self.dt, stage, want_energy and stage == last)
                iterations += it
                geometries += ng
            if self.atoms.constraints:  # positions and momenta set by constraints: no carries
                st = self._state
                for carry in (st.carry_q, st.carry_p, st.carry_s):
                    carry[:] = 0.0
            self._commit()  # checks that the state is finite first
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
        for which, x in enumerate((st.q, st.p, st.s)):
            bad = kernels.first_nonfinite_row(x)
            if bad >= 0:
                self._raise_nonfinite(which, bad)

    def _raise_nonfinite(self, which, row):
        name = ("positions", "momenta", "spins")[which]
        raise IntegrationError(
            f"the step gave non-finite {name} ({name_atoms([row])}) at step "
            f"{self.nsteps}: the forces or fields are not finite or the timestep "
            f"({self.dt / units.fs:.4g} fs) is far too large. The atoms keep the "
            f"state before this step.")

    def _commit(self):
        """Write the new state into the Atoms, if it is finite (else
        :class:`IntegrationError`, nothing written): in place (so references to
        ``atoms.positions`` stay live), float64 whatever dtype the user's arrays
        had (an integer or float32 array is replaced, not truncated)."""
        st = self._state
        arrays = self.atoms.arrays
        written, spare = self._written, self._spare
        shape = st.q.shape
        pos, mom, mag = (arrays["positions"], arrays.get("momenta"),
                         arrays.get("initial_magmoms"))
        if (_rows3(pos, shape) and _rows3(mom, shape) and _rows3(written[1], shape)
                and _rows3(mag, shape) and _rows3(written[2], shape)
                and st.q.flags.c_contiguous and st.p.flags.c_contiguous
                and st.s.flags.c_contiguous):
            # the usual case, one compiled pass: the check, the writes and the
            # snapshot _in_sync compares with next time, into the spare buffers
            # (``written``'s stay as they are: the step's _restore may need them)
            which, row = kernels.commit_state(st.q, st.p, st.s, st.mu, self.magnetic, pos, mom,
                                              mag if self.magnetic else pos, *spare)
            if which >= 0:
                self._raise_nonfinite(which, row)
            moments = spare[2] if self.magnetic else written[2]
            self._spare = (written[0], written[1], written[2] if self.magnetic else spare[2])
            # masses, cell, numbers, constraints: as at the last sync (a step
            # does not change them)
            self._written = (spare[0], spare[1], moments, *written[3:8], self.ev.state_token)
            self._snapshot_rows = True
            st.observables = None
            return
        self._check_state_finite()
        _write(arrays, "positions", st.q)
        _write(arrays, "momenta", st.p)
        if self.magnetic:
            now = arrays.get("initial_magmoms")
            if now is not None and now.dtype == np.float64 and now.shape == st.s.shape:
                np.multiply(st.mu[:, None], st.s, out=now)  # in place, no temporary
            else:
                _write(arrays, "initial_magmoms", st.mu[:, None] * st.s)
        st.observables = None
        self._remember_written()

    def _observer_due(self, n, frames_only=False):
        for function, interval, _, _ in self.observers:
            if frames_only and isinstance(function, SpinMDLogger):
                continue  # the log line reads the state, not the calculator
            if (interval > 0 and n % interval == 0) or (interval <= 0 and n == -interval):
                return True
        return False

    def _frame_due(self, n):
        """An observer other than the log line (a trajectory, a user's function
        that may write the Atoms) runs after step n."""
        return self._observer_due(n, frames_only=True)

    def _stress_available(self):
        return self.atoms.cell.rank == 3

    def _substep(self, h, stage, want_energy):
        """One second-order step of size h on ``self._state``; returns (midpoint
        sweeps, geometry evaluations) for the statistics."""
        raise NotImplementedError

    # -- pieces every step uses ---------------------------------------------------

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
        if self.atoms.constraints:
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
        if atoms.constraints:
            # positions set by constraints: nothing to compensate
            carry[:] = 0.0
            st.carry_p[:] = 0.0
            atoms.arrays["positions"][:] = q
            for c in atoms.constraints:
                c.adjust_positions(atoms, qt)
            P = (qt - q) * self.masses / h
        return qt, P, carry

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
            res = ev.spin(st.ops, st.s, Want(energy=True, magnetic_forces=True),
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

    def get_magnetic_energy(self):
        """Energy of the spin-dependent terms (eV), at the current state."""
        terms = self._observables()["terms"]
        return float(sum(terms[k] for k in self.ev.hamiltonian.spin_term_names))

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

    # -- the calculator's results for observers (trajectory frames) -------------

    def call_observers(self):
        """ASE's, with the calculator's results for the current state published
        first (:meth:`publish_results`) when an observer other than the log line
        is due: trajectory frames (and a user's ``ase.io.write`` in an observer)
        then hold energy, forces, stress, magnetic forces; on the other steps
        nothing is computed."""
        if self._frame_due(self.nsteps):
            self.publish_results()
        super().call_observers()

    def publish_results(self):
        """Put the results of the current state into ``atoms.calc`` as if it had
        computed them: ``energy``, ``free_energy``, ``forces`` (the Hamiltonian's,
        before constraints, as any calculator gives them), ``stress`` (a cell
        with three vectors), ``magmoms`` (N, 3), ``magmom`` (|Σ μ_i s_i|),
        ``magnetic_forces`` B = −∂E/∂s (eV), ``magnetic_energy`` and
        ``energy_terms``. From what the step already computed (the lattice part
        once per step) plus one pass over the spin terms; ``atoms.get_forces()``
        etc. then cost nothing until the Atoms change."""
        st = self._sync()
        with threads.threads_for(len(self.atoms)):
            results = self._frame_results(st)
        self._calc.publish(self.atoms, results)

    def _frame_results(self, st):
        ev = self.ev
        obs = self._observables()
        stress = self._stress_available()
        F = (ev.lattice(st.q, _FORCES).forces if self.frozen else st.FL).copy()
        V = np.zeros(6)
        if self.magnetic:
            # operators able to give the virial when it is wanted (those of
            # the step need not be)
            ops = ev.spin_operators(st.q, virial=True, half=True) if stress else st.ops
            res = ev.spin(ops, st.s, Want(forces=True, virial=stress), forces=F)
            if stress:
                V += res.virial
        if stress:
            VL = st.VL
            if VL is None:
                VL = ev.lattice(st.q, Want(virial=True)).virial
            V += VL
        terms = dict(obs["terms"])
        energy = float(sum(terms.values()))
        moments = st.mu[:, None] * st.s
        results = {"energy": energy, "free_energy": energy, "forces": F,
                   "magnetic_forces": obs["B"].copy(), "energy_terms": terms,
                   "magnetic_energy": float(sum(terms[k] for k in
                                                ev.hamiltonian.spin_term_names)),
                   "magmoms": moments}
        results.update(_total_moment(moments))
        if stress:
            results["stress"] = V / abs(np.linalg.det(self.atoms.cell.array))
        return results

    def _traj_write_image(self, description):
        """ASE's trajectory writer, with what a .traj frame has no field for in
        the frame's ``info``: ``magnetic_forces`` (N, 3), ``magnetic_energy``,
        ``energy_terms`` (the user's Atoms keep their own info)."""
        calc = self._calc
        current = not calc.check_state(self.atoms)
        info = self.atoms.info
        saved = dict(info)
        for key in ("magnetic_forces", "magnetic_energy", "energy_terms"):
            if current and key in calc.results:
                info[key] = calc.results[key]
        try:
            super()._traj_write_image(description)
        finally:
            info.clear()
            info.update(saved)

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


_F64 = np.dtype(np.float64)


def _rows3(a, shape):
    """``a`` is a C-contiguous, writeable float64 array of ``shape`` ((n, 3)):
    what the compiled commit and check take (the cheap tests first: this runs
    at every step)."""
    return (a is not None and a.dtype is _F64 and a.shape == shape
            and a.flags.c_contiguous and a.flags.writeable)


def _total_moment(moments):
    """ASE's scalar ``magmom`` for vector moments: |Σ_i μ_i s_i| (μB), and the
    vector itself as ``magmom_vector``."""
    total = moments.sum(axis=0)
    return {"magmom": float(np.sqrt(total @ total)), "magmom_vector": total}


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
        raise ValueError(f"masses must be finite and positive; {name_atoms(bad)} "
                         f"{'has' if bad.size == 1 else 'have'} mass {float(masses[bad[0]])}")
    return masses


def _checked_momenta(atoms):
    if "momenta" not in atoms.arrays:
        return np.zeros((len(atoms), 3))
    p = real_array(atoms.arrays["momenta"], "momenta", shape=(len(atoms), 3)).copy()
    bad = np.flatnonzero(~np.isfinite(p).all(axis=1))
    if bad.size:
        raise ValueError(f"momenta are not finite for {name_atoms(bad)}")
    return p
