"""What every spin–lattice integrator here shares: the base of CollectivePRK,
SuzukiTrotter and any integrator to come (one new file, one step method).

:class:`SpinLatticeDynamics` owns the parameters of the dynamics, the set-up
(reading the state from the Atoms, the timestep check) and the run: steps one
at a time or in blocks, each written back whole or not at all (errors and
Ctrl-C alike). Its parts live beside it: the state and its bond with the Atoms
(:mod:`~ase_spin.md.state`), the lattice moves and constraints
(:mod:`~ase_spin.md.lattice`), the observables (:mod:`~ase_spin.md.observables`),
the errors (:mod:`~ase_spin.md.errors`). A subclass implements
``_substep(h, stage, want_energy)``: advance ``self._state`` by one
second-order step of size h, and optionally ``_prepare(state)`` to add its own
per-run buffers to the state.
"""

from __future__ import annotations

import functools
import inspect

import numpy as np
from ase import units
from ase.constraints import FixAtoms
from ase.md.md import MolecularDynamics

from .._jit.threads import AdaptiveThreads
from ..calculator import SpinLatticeCalculator
from ..constants import HBAR, HBAR_LAMMPS
from ..constraints import lattice_constraints, pinned_spins
from ..conventions import PHYSICAL
from ..io.progress import run_with_progress
from ..io.trajectories import check_trajectory_target
from ..spins import name_atoms, split_moments
from ..terms.base import Want
from ..validate import flag, positive_scalar, real_array, real_scalar, unknown_keywords, warn_user
from .compositions import composition_coefficients
from .errors import TimestepWarning
from .lattice import LatticeMotion
from .logger import SpinMDLogger
from .observables import Observables
from .state import AtomsBond, State

__all__ = ["SpinLatticeDynamics", "fastest_precession", "precession_phrase",
           "accepted_keywords", "KEYWORD_HINTS"]

_FORCES = Want(forces=True)


#: Largest phase (rad) the fastest precession or vibration may turn per step
#: without a warning (about 20 steps per period, the usual MD rule).
MAX_PHASE = 0.3
#: Smallest plausible timestep (fs) without a warning.
MIN_TIMESTEP_FS = 1e-3

_IN_KELVIN = "in kelvin, as ASE's Langevin takes it; its deprecated temperature is in eV"
_NO_BATH = "no heat bath here: ase_spin.Langevin takes {}"
#: Keywords written by mistake, from ASE's and LAMMPS's names (see
#: :func:`~ase_spin.validate.unknown_keywords`): slip -> (keyword meant, why,
#: what to say where the integrator does not take it).
KEYWORD_HINTS = {
    "temperature": ("temperature_K", _IN_KELVIN, _NO_BATH.format("temperature_K")),
    "temp": ("temperature_K", _IN_KELVIN, _NO_BATH.format("temperature_K")),
    "T": ("temperature_K", _IN_KELVIN, _NO_BATH.format("temperature_K")),
    "temperature_k": ("temperature_K", _IN_KELVIN, _NO_BATH.format("temperature_K")),
    "spin_temperature": ("spin_temperature_K", _IN_KELVIN,
                         _NO_BATH.format("spin_temperature_K")),
    "damping": ("spin_damping", "λ, the dimensionless Gilbert damping",
                _NO_BATH.format("spin_damping")),
    "alpha": ("spin_damping", "λ, the dimensionless Gilbert damping (LAMMPS's alpha_t)",
              _NO_BATH.format("spin_damping")),
    "gamma": ("friction", "γ in 1/(ASE time), e.g. 0.01 / ase.units.fs",
              _NO_BATH.format("friction")),
    "dt": ("timestep", "in ASE time units: e.g. 0.5 * ase.units.fs", ""),
    "seed": ("rng", "an integer seed or a numpy Generator", ""),
    "fix_com": ("fixcm", "", ""),
}


@functools.lru_cache(maxsize=None)
def accepted_keywords(cls):
    """The keywords ``cls(...)`` takes: the named parameters of every
    ``__init__`` up its MRO (each passes ``**kwargs`` on; ASE's
    MolecularDynamics and Dynamics included)."""
    keyword = (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)
    names = set()
    for c in cls.__mro__:
        init = vars(c).get("__init__")
        if c is object or init is None:
            continue
        try:
            parameters = inspect.signature(init).parameters.values()
        except (TypeError, ValueError):
            continue
        names.update(p.name for p in parameters if p.kind in keyword)
    names.discard("self")
    return frozenset(names)


def fastest_precession(rates, B, hbar):
    """ω_s = max_i r_i |B_i|/ħ: the angular frequency of the fastest spin
    precession (rad per unit of time of ħ) for precession rate factors
    ``rates`` (r_i: 1, or g/μ_i; with the Gilbert factor 1/(1+λ²) of a bath)
    and fields ``B`` (eV). The timestep warning, :class:`SpinConvergenceError`
    and ``relax_spins``'s timestep all take it from here, so that they speak
    of one quantity."""
    if not len(B):
        return 0.0
    return float(np.max(rates * np.sqrt(np.einsum("ij,ij->i", B, B)))) / hbar


def precession_phrase(h, omega):
    """How the fastest spin turns in a step h at ω_s (:func:`fastest_precession`):
    the words of the timestep warning and of :class:`SpinConvergenceError`."""
    text = f"the fastest spin precesses by {abs(h) * omega:.2g} rad per step"
    if omega > 0.0:
        text += f" (period {2 * np.pi / omega / units.fs:.3g} fs)"
    return text

#: Most steps :meth:`SpinLatticeDynamics.run` takes in one block (small systems,
#: nothing observing the run in between): an interrupt waits for at most this many.
#: Blocks exist only for speed: in a small system the return to Python after each
#: step costs a share of the step that a block spreads over its steps
#: (``benchmarks/small_systems.py``; docs/benchmarks.md, "Why each fast path exists").
QUIET_BLOCK = 256
#: and when the adaptive thread count tries another count (a probe: it may be a
#: bad one on a busy machine)
PROBE_BLOCK = 16


class SpinLatticeDynamics(AtomsBond, LatticeMotion, Observables, MolecularDynamics):
    """Base of the spin–lattice integrators (see the module docstring).

    Parameters common to all: ``timestep`` (ASE time units), ``hbar`` (eV·(ASE
    time)), ``precession`` ("moment": σ = −1, physical and LAMMPS; "spin": σ = +1,
    the paper's), ``gyromagnetic`` ("moment": ds_i/dt = (σ g/(μ_i ħ)) s_i × B_i,
    the Landau–Lifshitz precession of a moment μ_i μB; "lammps": ds_i/dt =
    (σ/ħ) s_i × B_i whatever the moment, LAMMPS SPIN's equation) and ``g``:
    by default those of the calculator's conventions (physical: CODATA ħ,
    "moment", the electron's g; "lammps": LAMMPS's ħ, "lammps"; "paper": ħ = 1,
    "spin"; see
    :mod:`ase_spin.conventions`), ``order``/``composition`` (symmetric compositions of the step),
    ``lattice`` ("moving" or "frozen"), ``threads`` ("auto": all configured
    threads or one, whichever runs the steps faster right now, see
    :class:`~ase_spin._jit.threads.AdaptiveThreads`; or a fixed count; default from
    the environment variable ``ASE_SPIN_THREADS``), and ASE's ``trajectory``,
    ``logfile``, ``loginterval``, ``append_trajectory``.
    """

    half_lists = True

    def __init__(self, atoms, timestep, *, hbar=None, precession=None,
                 gyromagnetic=None, g=None, order=2, composition=None, lattice="moving",
                 threads=None, trajectory=None, logfile=None, loginterval=1, **kwargs):
        self._refuse_unknown(kwargs)
        calc = getattr(atoms, "calc", None)
        #: the calculator's conventions, the defaults of ħ, precession, gyromagnetic, g
        self.conventions = (calc.hamiltonian.conventions
                            if isinstance(calc, SpinLatticeCalculator) else PHYSICAL)
        if precession is None:
            precession = self.conventions.precession
        if not isinstance(precession, str) or precession not in ("moment", "spin"):
            raise ValueError(f'precession must be "moment" or "spin", got {precession!r}')
        if gyromagnetic is None:
            gyromagnetic = self.conventions.gyromagnetic
        if not isinstance(gyromagnetic, str) or gyromagnetic not in ("lammps", "moment"):
            raise ValueError(f'gyromagnetic must be "lammps" or "moment", got {gyromagnetic!r}')
        self.gyromagnetic = gyromagnetic
        self.g = self.conventions.g if g is None else positive_scalar(g, "g")
        if not isinstance(lattice, str) or lattice not in ("moving", "frozen"):
            raise ValueError(f'lattice must be "moving" or "frozen", got {lattice!r}')
        timestep = real_scalar(timestep, "timestep")
        if timestep == 0.0:
            raise ValueError("timestep must be non-zero")
        self.precession = precession
        self.sigma = -1.0 if precession == "moment" else 1.0
        self.hbar = self.conventions.hbar if hbar is None else checked_hbar(hbar)
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

    @classmethod
    def _refuse_unknown(cls, kwargs):
        """TypeError for keywords no ``__init__`` of the class takes, naming the
        one most likely meant (:data:`KEYWORD_HINTS`, else the closest name):
        before anything else is checked, so that ``temperature=300`` is
        reported as such, not as a missing ``temperature_K``."""
        error = unknown_keywords(cls.__name__, kwargs, accepted_keywords(cls), KEYWORD_HINTS)
        if error is not None:
            raise error

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

    # -- set-up ------------------------------------------------------------------
    def _initialize(self):
        atoms = self.atoms
        calc = atoms.calc
        if not isinstance(calc, SpinLatticeCalculator):
            raise TypeError(f"{type(self).__name__} needs atoms.calc to be an ase_spin "
                            f"SpinLatticeCalculator, got {type(calc).__name__}")
        if calc.hamiltonian.conventions != self.conventions:
            raise ValueError(
                f"the calculator follows the {calc.hamiltonian.conventions.name!r} conventions "
                f"but {type(self).__name__} was made under {self.conventions.name!r} ones "
                "(atoms.calc was set or replaced after it): make the integrator after "
                "setting atoms.calc")
        if calc.hamiltonian.cutoff > 0.0 and not calc.hamiltonian.skin > 0.0:
            raise ValueError(f"{type(self).__name__} needs a neighbour-list skin > 0 (the "
                             "calculator's skin=...): one pair list serves q and q̃")
        masses = _checked_masses(atoms)
        momenta = _checked_momenta(atoms)
        ev, moments = calc.bound_evaluator(atoms)
        self._calc = calc
        self.ev = ev
        spins, mu = split_moments(moments)
        pinned = pinned_spins(atoms)
        self.masses = masses[:, None]
        self.magnetic = ev.any_magnetic and bool(ev.hamiltonian.spin_terms)
        self.frozen = self.frozen_lattice or self._all_fixed()
        q = real_array(atoms.positions, "positions").copy()
        # the constraints on positions, forces and momenta (all but FixSpins),
        # and the pinned spins (FixSpins: precession rate 0), as they are now
        # (a change of the constraints brings a new state: _in_sync)
        st = State(q=q, p=momenta, s=np.ascontiguousarray(spins), mu=mu,
                   rate=self._precession_rates(mu), scales={}, EL=None,
                   constraints=lattice_constraints(atoms), pinned=pinned,
                   pinned_rows=None if pinned is None else np.flatnonzero(pinned & ev.magnetic),
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
        directions); or |h| below :data:`MIN_TIMESTEP_FS` fs (a unit slip).
        The warning (:class:`TimestepWarning`) states figures valid whatever
        the caller's units; the hint about ASE time units only where the
        number looks like a value meant in fs (:meth:`_unit_hint`)."""
        self._checked_dt = self.dt
        h = abs(self.dt)
        ev = self.ev
        problems = []
        fastest = 0.0
        if h < MIN_TIMESTEP_FS * units.fs:
            problems.append(f"it is below {MIN_TIMESTEP_FS} fs")
        if self.magnetic:
            omega = self._fastest_precession(q, spins, mu)
            fastest = max(fastest, omega)
            if h * omega > MAX_PHASE:
                problems.append(precession_phrase(h, omega))
        if not self.frozen and len(q) > 1:
            rng = np.random.default_rng(0)
            d = rng.normal(size=q.shape)
            d *= 1e-3 / np.linalg.norm(d, axis=1)[:, None]
            dF = ev.lattice(q + d, _FORCES).forces - forces
            k = np.linalg.norm(dF, axis=1) / 1e-3
            omega = float(np.sqrt(np.max(k / masses)))
            fastest = max(fastest, omega)
            if h * omega > MAX_PHASE:
                problems.append(f"the fastest vibration turns by {h * omega:.2g} rad per step "
                                f"(period ≈ {2 * np.pi / omega / units.fs:.3g} fs)")
        if problems:
            too_small = h < MIN_TIMESTEP_FS * units.fs
            advice = ("so small a timestep is most likely a unit slip" if too_small else
                      f"keep h·ω below {MAX_PHASE} rad per step (about 20 steps per period) "
                      "for accurate dynamics")
            warn_user(TimestepWarning(self.dt / units.fs, problems, advice,
                                          self._unit_hint(fastest, too_small)))

    def _fastest_precession(self, q, spins, mu):
        """ω_s (:func:`fastest_precession`) at positions q and unit spins, from
        one direct pass over the half list (no pair geometry kept for it)."""
        B = self.ev.evaluate(q, spins, Want(magnetic_forces=True)).magnetic_forces
        return fastest_precession(self._precession_rates(mu), B, self.hbar)

    def _unit_hint(self, fastest, too_small):
        """For a Python caller, where the numbers show a likely slip of units: a
        timestep far too small (seconds or ps for ASE time units), or one written
        as a number of fs (``timestep=0.1``: 1.018 fs) that, read as fs, would
        pass the check. '' otherwise (the figures of the warning say it all)."""
        ase_time = f"Timesteps are in ASE time units (1 fs = ase.units.fs = {units.fs:.4g})"
        if too_small:
            return f"{ase_time}."
        x = self.dt
        typed = x == float(f"{x:.3g}")  # a number typed by hand, not a product with units.fs
        meant = abs(x) * units.fs
        if not typed or meant < MIN_TIMESTEP_FS * units.fs or meant * fastest > MAX_PHASE:
            return ""
        return f"{ase_time}: for {x:g} fs write timestep={x:g} * ase.units.fs."

    def _precession_rates(self, mu):
        """Per-spin factor r_i of the precession, ds_i/dt = r_i (σ/ħ) s_i × B_i:
        1 (LAMMPS) or g/μ_i (a moment μ_i μB: the Landau–Lifshitz precession);
        0 for a spin pinned by :class:`~ase_spin.constraints.FixSpins` (every
        spin update then leaves it as it is, to the bit: docs/dynamics.md,
        "Pinned spins")."""
        if self.gyromagnetic == "lammps":
            rate = np.ones_like(mu)
        else:
            rate = np.zeros_like(mu)
            np.divide(self.g, mu, out=rate, where=mu > 0.0)
        pinned = pinned_spins(self.atoms)
        if pinned is not None:
            rate[pinned] = 0.0
        return rate


    def _all_fixed(self):
        fixed = np.zeros(len(self.atoms), dtype=bool)
        for c in self.atoms.constraints:
            if isinstance(c, FixAtoms):
                fixed[c.index] = True
        return bool(fixed.all()) and len(self.atoms) > 0

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
        # arrays per step, a share of every step that blocks do not pay)
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
            st = self._state
            if st.constraints:  # positions and momenta set by constraints: no carries
                for carry in (st.carry_q, st.carry_p, st.carry_s):
                    carry[:] = 0.0
            self._commit()  # checks that the state is finite first
            if count:
                self.nsteps = nsteps + 1
            # the statistics in one statement, inside the try: nothing of the
            # step runs after it, so an interrupt is either in the step (all
            # undone below) or after it (all done)
            (self.iterations, self.geometry_evaluations, self.total_iterations,
             self.total_steps) = (iterations, geometries, self.total_iterations + iterations,
                                  self.total_steps + 1)
        except BaseException:
            # an error or an interrupt (Ctrl-C) anywhere in the step, the write-back
            # included: the Atoms go back to the state before it, whole
            self._state = None
            self.nsteps = nsteps
            self._restore(before)
            raise

    def _substep(self, h, stage, want_energy):
        """One second-order step of size h on ``self._state``; returns (midpoint
        sweeps, geometry evaluations) for the statistics."""
        raise NotImplementedError

    @property
    def mean_iterations(self):
        """Midpoint sweeps per step, averaged over the steps taken so far."""
        return self.total_iterations / self.total_steps if self.total_steps else 0.0


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


#: ħ in units users write by mistake (their size in eV·(ASE time) per unit)
_OTHER_HBAR_UNITS = {"eV·ps": 1000.0 * units.fs, "eV·fs (or meV·ps)": units.fs,
                     "eV·s": units.s, "J·s": units.J * units.s}


def checked_hbar(hbar):
    """``hbar`` (eV·(ASE time)), refused where it is the value of ħ in another
    unit (eV·ps, eV·fs, meV·ps, eV·s, J·s): a wrong trajectory otherwise."""
    hbar = positive_scalar(hbar, "hbar")
    for name, unit in _OTHER_HBAR_UNITS.items():
        if abs(hbar * unit / HBAR - 1.0) < 1e-5:
            raise ValueError(
                f"hbar={hbar:.10g} is ħ in {name}; integrators take ħ in eV·(ASE time unit): "
                f"ase_spin.constants.HBAR = {HBAR:.10g} (CODATA) or HBAR_LAMMPS = "
                f"{HBAR_LAMMPS:.10g} (LAMMPS's), or leave hbar out (the conventions' ħ)")
    return hbar
