"""The step policy of the collective method: what decides how a CollectivePRK
step iterates, in one place for both of its executors.

A CollectivePRK step is taken either in Python (:class:`~ase_spin.md.collective.CollectivePRK`)
or, for small systems, by one compiled call (:mod:`ase_spin.md.fused`). Both
read one :class:`StepPolicy` record, built by the integrator for the run, and
call the compiled functions of this module for every decision a step makes:
the first solve's tolerance, the solver's starting contraction, when q̃ and W
have settled, which sweeps and which solver a stage takes and when "auto"
switches to Anderson, the order of a frozen lattice's sweeps. Called from
Python or from compiled code they are the same machine code, so the two
executors take the same decisions to the bit.
"""

from __future__ import annotations

from typing import NamedTuple

import numba as nb
import numpy as np

from .kernels import MEMORY

__all__ = ["StepPolicy", "SOLVERS", "TOL_RANGE", "MAX_ROUNDS", "FIRST_SOLVE_FRACTION",
           "AUTO_SWITCH", "AUTO_FIRST_SWEEPS", "KEEP_GUESS", "first_tolerance",
           "start_contraction", "settled_qtol", "gives_up", "solver_settings",
           "auto_takes_local", "next_sweep_order", "INDEX_ORDER", "COLOUR_ORDER",
           "INDEX_ORDER_KEPT", "HELD_SWITCH", "HELD_MEMORY",
           "held_operators"]

EPS = float(np.finfo(float).eps)

#: Tightest and loosest stopping tolerances of the midpoint iteration (on unit vectors).
TOL_RANGE = (1e-16, 1e-3)
#: Outer rounds (q̃ and W settling together) a coupled step may take.
MAX_ROUNDS = 12
#: The solvers' floor: below this multiple of the tolerance a sweep that no
#: longer shrinks the change has reached round-off (kernels' ``after_sweep``).
FLOOR_FACTOR = 64.0
#: How far W may move in an outer round, in tolerances, for the kick and drift
#: computed from the W before it to stand: round-off, so that the step is the
#: implicit map to the last digit (time-reversible).
SETTLED_FACTOR = 8.0
#: The first midpoint solve of a (sub)step is converged to this fraction of how
#: far the update of q̃ moved W in the last step (see :func:`first_tolerance`).
FIRST_SOLVE_FRACTION = 0.1
#: ... and never looser than this.
FIRST_SOLVE_LOOSEST = 1e-6

#: The midpoint solvers: name -> (Anderson memory, locally exact sweeps).
SOLVERS = {"anderson": (MEMORY, True), "local": (0, True), "jacobi": (0, False)}
#: "auto" takes locally exact sweeps while they contract by less than this a
#: sweep, else the Anderson solver from then on at that stage and step size ...
AUTO_SWITCH = 0.4
#: ... and redoes with Anderson a solve of its first mode not done in this many sweeps.
AUTO_FIRST_SWEEPS = 40
#: Contraction per sweep above which "auto" keeps a copy of the starting guess
#: for that retry (below it, 40 sweeps gain over 27 decades: they do not fail).
KEEP_GUESS = 0.2


class StepPolicy(NamedTuple):
    """What a run's coupled steps iterate to, built by the integrator
    (:meth:`~ase_spin.md.collective.CollectivePRK.step_policy`) and read by
    both executors.

    ``tol``: the midpoint solves' tolerance; ``floor``: where a solve stops at
    round-off (:data:`FLOOR_FACTOR` tol); ``max_iter``: sweeps a solve may take;
    ``settled_tol``: how far W may move in an outer round for the step to stand;
    ``qtol_floor``: the least distance between the q̃ of two rounds that counts
    as settled (0: round-off of the coordinates, :func:`settled_qtol`);
    ``first_fraction``, ``first_loosest``: the first solve's tolerance
    (:func:`first_tolerance`); ``solver``: "auto", "anderson", "local" or
    "jacobi"."""

    tol: float
    floor: float
    max_iter: int
    settled_tol: float
    qtol_floor: float
    first_fraction: float
    first_loosest: float
    solver: str

    @classmethod
    def make(cls, tol, max_iter, solver, settled_tol=None, qtol_floor=0.0):
        """The record of the default policy for these settings; a thermostat
        that tolerates more (a bath's noise) passes its own ``settled_tol`` and
        ``qtol_floor``."""
        if settled_tol is None:
            settled_tol = SETTLED_FACTOR * tol
        return cls(float(tol), FLOOR_FACTOR * tol, int(max_iter), float(settled_tol),
                   float(qtol_floor), FIRST_SOLVE_FRACTION, FIRST_SOLVE_LOOSEST, solver)


@nb.njit(cache=True)
def first_tolerance(tol, settle, fraction, loosest):
    r"""Tolerance of the first midpoint solve of a coupled (sub)step:
    min(loosest, max(tol, fraction · δ)) (the policy's ``first_loosest``,
    ``first_fraction``: :data:`FIRST_SOLVE_LOOSEST`, :data:`FIRST_SOLVE_FRACTION`).

    The first solve uses the couplings at the q̃ drifted with the *predicted*
    W; the next outer round redrifts q̃ with the solved W and solves again,
    which moves W by some amount δ (``settle``: that of the same stage in the
    last step). Converging the first solve far below δ is wasted: its result
    is only the next solve's starting point. Every later solve, and so the W
    the step keeps, is converged to ``tol``: the fixed point is the same."""
    return min(loosest, max(tol, fraction * settle))


@nb.njit(cache=True)
def start_contraction(theta):
    """The contraction per sweep a solve starts from: min(1, 2θ) of the
    stage's last measured θ (a safe over-estimate for its stopping test)."""
    return min(1.0, 2.0 * theta)


@nb.njit(cache=True)
def settled_qtol(largest, qtol_floor):
    """How close q̃ of an outer round must come to the last round's for the
    step to stand on the pair geometry prepared there:
    max(4ε·max(1, largest coordinate), ``qtol_floor``) — round-off by default,
    so that the step is the implicit map."""
    return max(4.0 * EPS * max(1.0, largest), qtol_floor)


@nb.njit(cache=True)
def gives_up(sweeps, measured, switch):
    """Whether a solve of "auto"'s first mode contracted too slowly (more than
    ``switch`` a sweep, measured over more than two sweeps) for that mode to
    go on at its stage and step size."""
    return sweeps > 2 and measured > switch


def solver_settings(solver, switched, max_iter):
    """(Anderson memory, locally exact sweeps, sweeps allowed, contraction per
    sweep above which "auto" switches, whether the step's first solve chooses
    its sweeps by :func:`auto_takes_local`) for a stage's solves with
    ``solver``; ``switched``: "auto" has switched to Anderson at that stage
    and step size."""
    if solver == "auto":
        if switched:
            return (*SOLVERS["anderson"], max_iter, np.inf, False)
        return (*SOLVERS["local"], min(max_iter, AUTO_FIRST_SWEEPS), AUTO_SWITCH, True)
    return (*SOLVERS[solver], max_iter, np.inf, False)


#: "auto" takes a Jacobi sweep rather than a locally exact one for a solve that
#: follows a one-sweep solve at its stage, while the stage's sweeps contract by
#: less than this a sweep (see :func:`auto_takes_local`).
JACOBI_AFTER_ONE_SWEEP_BELOW = 0.1


@nb.njit(cache=True, inline="always")
def auto_takes_local(one_sweep, theta):
    """Whether ``solver="auto"`` (in its first mode, before any switch to
    Anderson) makes a step's first solve (from the predictor, to the full
    tolerance) with locally exact sweeps, else with Jacobi's (every other
    solve takes locally exact ones): not when the stage's last such solve took
    a single sweep (``one_sweep``) and its sweeps contract by less than
    :data:`JACOBI_AFTER_ONE_SWEEP_BELOW` (``theta``): there the predictor
    leaves nothing to contract, and a one-sweep Jacobi solve costs less than a
    locally exact one (which needs its end points made in a pass of their own)."""
    return not (one_sweep and theta < JACOBI_AFTER_ONE_SWEEP_BELOW)


#: The order of a frozen lattice's locally exact sweeps, per stage
#: (:func:`next_sweep_order`): the index order; the colour order; the index
#: order for good (the colour order tried and found not to pay).
INDEX_ORDER, COLOUR_ORDER, INDEX_ORDER_KEPT = 0, 1, 2
#: A stage whose locally exact solve in index order took at least this many
#: sweeps tries the colour order ...
COLOUR_FROM_SWEEPS = 5
#: ... and goes back to index order after a colour-ordered solve of at most
#: this many ...
INDEX_ORDER_UP_TO_SWEEPS = 3
#: ... or for good once a colour-ordered sweep contracts by less than the
#: index order's contraction to this power: what a colour-ordered sweep costs
#: in index-order sweeps, with a margin (a full list, and a pass per colour).
COLOUR_PAYS_POWER = 1.3


@nb.njit(cache=True, inline="always")
def next_sweep_order(order, local, sweeps, measured, theta_index):
    """After a solve at a frozen lattice's stage: (the order of its next
    locally exact sweeps, the contraction of its index-order sweeps), from the
    order the solve took (``order``: :data:`INDEX_ORDER`, :data:`COLOUR_ORDER`
    or :data:`INDEX_ORDER_KEPT`), whether its sweeps were locally exact
    (``local``; Jacobi sweeps say nothing), their number, the contraction
    they showed (``measured``, −1 if none) and the index order's last
    (``theta_index``, −1 if none yet). Colour order takes the earlier
    colours' new W (kernels' ``midpoint_solve``), about two index-order
    sweeps' contraction on a two-colourable lattice, far less on others; it
    is tried after a long index-order solve and kept while it contracts by
    more than the index order to the power :data:`COLOUR_PAYS_POWER`."""
    if not local:
        return order, theta_index
    if order == COLOUR_ORDER:
        if sweeps <= INDEX_ORDER_UP_TO_SWEEPS:
            return INDEX_ORDER, theta_index
        if (0.0 < measured < 1.0 and 0.0 < theta_index < 1.0
                and not measured < theta_index ** COLOUR_PAYS_POWER):
            return INDEX_ORDER_KEPT, theta_index
        return COLOUR_ORDER, theta_index
    if 0.0 <= measured < 1.0:
        theta_index = measured
    if order == INDEX_ORDER and sweeps >= COLOUR_FROM_SWEEPS:
        return COLOUR_ORDER, theta_index
    return order, theta_index


#: A solve's outer iteration over the held fields (:func:`held_operators`)
#: that contracts by more than this (measured from its second round) gives
#: up: that stage then solves plainly, every field in every sweep. Dipolar
#: fields contract it by far less at any step the spins allow.
HELD_SWITCH = 0.5
#: The Anderson memory of that outer iteration (kernels.midpoint_solve_held).
HELD_MEMORY = MEMORY


def held_operators(operators):
    """(held, rest): the spin operators whose fields a midpoint solve holds
    fixed while the others converge (those that declare ``expensive_field``:
    one evaluation costs as much as hundreds of sweeps of the rest), and the
    others; or None, where there are not both kinds (then holding a field
    saves nothing: the plain solve). The split solve reaches the same
    midpoint to the tolerance (kernels.midpoint_solve_held)."""
    held = [op for op in operators if op.expensive_field]
    if not held or len(held) == len(operators):
        return None
    return held, [op for op in operators if not op.expensive_field]
