"""What every spin minimiser shares: ASE's optimizer interface on the spins of
Atoms at fixed positions (``run(fmax, steps)``, ``irun``, ``attach``, a log,
a trajectory), convergence on the largest torque, the write-back of the spins
after every step, and a fresh start when the Atoms were changed between
steps."""

from __future__ import annotations

import time

import numpy as np
from ase.io.trajectory import Trajectory
from ase.optimize.optimize import DEFAULT_MAX_STEPS, Optimizer

from ..io.trajectories import check_trajectory_target
from ..validate import flag, integer, real_scalar
from . import sphere
from .objective import FrozenLattice

__all__ = ["SpinOptimizer", "largest_torque", "checked_fmax"]


def largest_torque(s, B, free):
    """max_i |s_i × B_i| (eV) over the spins that may turn (mask ``free``)."""
    if not free.any():
        return 0.0
    return float(sphere.norms(sphere.torque(s[free], B[free])).max())


def checked_fmax(fmax):
    fmax = real_scalar(fmax, "fmax")
    if not fmax >= 0.0:
        raise ValueError(f"fmax (the largest torque |s × B| to stop at, eV) must be >= 0, "
                         f"got {fmax}")
    return fmax


class SpinOptimizer(Optimizer):
    """Base of the spin minimisers: an :class:`ase.optimize.optimize.Optimizer`
    whose degrees of freedom are the directions of the spins, the positions
    fixed.

    ``opt.run(fmax=1e-6, steps=...)`` turns the spins until the largest torque
    max_i |s_i × B_i| (eV; B_i = −∂E/∂s_i) over the spins that may turn is
    ≤ ``fmax``, or ``steps`` steps are done; it returns whether it converged
    (as ASE's optimizers, no exception). Spins pinned by
    :class:`~ase_spin.constraints.FixSpins` and non-magnetic atoms stay as they
    are. After every step the spins are in ``atoms`` (``initial_magmoms``) and
    their energy and magnetic forces in the calculator's results, so an
    attached observer or the trajectory reads them without an evaluation.
    ``opt.evaluations`` counts the evaluations of E and B (each one pass over
    the spin terms). A change of the Atoms between steps (positions, spins,
    a term's parameter) is noticed: the minimiser starts afresh from them.

    Parameters
    ----------
    atoms : ase.Atoms with a :class:`~ase_spin.SpinLatticeCalculator`
    logfile : file, str or None
        As ASE's: ``"-"`` for standard output. One line per step: step, time,
        energy (eV), largest torque (eV), evaluations so far.
    trajectory : str, path, open ase.io.Trajectory or None
        Frames of the Atoms with their spins (and energy) every ``loginterval``
        steps; an existing file is not overwritten unless
        ``append_trajectory=True`` (it is then continued).
    maxmove : float
        The largest rotation of any spin in one step (rad).
    """

    #: default of ``maxmove`` (rad)
    default_maxmove = 0.2

    def __init__(self, atoms, logfile=None, trajectory=None, *, maxmove=None,
                 append_trajectory=False, loginterval=1):
        append = flag(append_trajectory, "append_trajectory")
        loginterval = integer(loginterval, "loginterval", minimum=1)
        maxmove = self.default_maxmove if maxmove is None else real_scalar(maxmove, "maxmove")
        if not 0.0 < maxmove <= np.pi:
            raise ValueError(f"maxmove (the largest rotation of a spin per step, rad) must "
                             f"be in (0, π], got {maxmove}")
        self.maxmove = maxmove
        check_trajectory_target(trajectory, append)
        self.landscape = FrozenLattice(atoms, type(self).__name__)
        self._evaluations_before = 0
        super().__init__(atoms, logfile=logfile, trajectory=None)
        if trajectory is not None:
            if not hasattr(trajectory, "write"):
                trajectory = self.closelater(
                    Trajectory(trajectory, mode="a" if append else "w", atoms=atoms))
            self.attach(trajectory.write, interval=loginterval, atoms=atoms)
        self._start()

    # -- the state ----------------------------------------------------------
    def _start(self):
        """(Re)start from the Atoms as they are: the landscape at their
        positions, the spins, their energy and fields, no memory."""
        if self.landscape.atoms is not self.atoms or not self.landscape.current():
            self._evaluations_before += self.landscape.evaluations
            self.landscape = FrozenLattice(self.atoms, type(self).__name__)
        land = self.landscape
        self.s = land.s.copy()
        self.free = land.free
        self.energy, self.B = land(self.s)
        self.reset()

    def _sync(self):
        if not self.landscape.current():
            self._start()

    @property
    def evaluations(self):
        """Evaluations of E and B so far (one pass over the spin terms each)."""
        return self._evaluations_before + self.landscape.evaluations

    def torque(self):
        """The largest torque max_i |s_i × B_i| (eV) over the spins that turn."""
        return largest_torque(self.s, self.B, self.free)

    def forces(self):
        """The torques s_i × B_i of the spins that turn, (N, 3) (eV), zero
        rows for the others: minus the gradient of E in the rotation vectors."""
        t = sphere.torque(self.s, self.B)
        t[~self.free] = 0.0
        return t

    def _accept(self, s, energy, B):
        """Take spins s with their energy and fields, write them back."""
        self.s, self.energy, self.B = s, energy, B
        self.landscape.write(s, energy, B)

    def reset(self):
        """Forget what the minimiser learnt (a subclass's memory)."""

    def step(self):
        raise NotImplementedError

    # -- ASE's optimizer interface ------------------------------------------
    def irun(self, fmax=1e-6, steps=DEFAULT_MAX_STEPS):
        """As ASE's: a generator yielding after each step whether the largest
        torque is ≤ ``fmax`` (eV)."""
        self.fmax = checked_fmax(fmax)
        steps = integer(steps, "steps", minimum=0)
        self._sync()
        self.max_steps = self.nsteps + steps
        if self.nsteps == 0:
            self.log()
            self.call_observers()
        converged = self.torque() <= self.fmax
        yield converged
        while not converged and self.nsteps < self.max_steps:
            self._sync()
            self.step()
            self.nsteps += 1
            self.log()
            self.call_observers()
            converged = self.torque() <= self.fmax
            yield converged

    def run(self, fmax=1e-6, steps=DEFAULT_MAX_STEPS):
        """Minimise until the largest torque is ≤ ``fmax`` (eV) or ``steps``
        steps are done; True if converged."""
        converged = False
        for converged in self.irun(fmax, steps):
            pass
        return converged

    def converged(self, forces=None):
        """Whether the largest torque is ≤ ``fmax``."""
        return self.fmax is not None and self.torque() <= self.fmax

    def log(self, *args):
        if self.logfile is None:
            return
        name = type(self).__name__
        if self.nsteps == 0:
            self.logfile.write(f"{' ' * len(name)}  {'Step':>4} {'Time':>8} {'Energy':>18} "
                               f"{'torque':>12} {'evals':>7}\n")
        t = time.localtime()
        self.logfile.write(f"{name}:  {self.nsteps:4d} {t[3]:02d}:{t[4]:02d}:{t[5]:02d} "
                           f"{self.energy:18.10f} {self.torque():12.4e} "
                           f"{self.evaluations:7d}\n")

    def todict(self):
        return {"type": "optimization", "optimizer": type(self).__name__,
                "maxmove": self.maxmove, "fmax": self.fmax}

    def get_number_of_evaluations(self):
        return self.evaluations
