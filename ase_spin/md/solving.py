"""The midpoint solves of :class:`~ase_spin.md.collective.CollectivePRK`: a
stage's solve with its solver chosen and switched by the policy
(:mod:`~ase_spin.md.policy`), the kernels it calls, the colour order of a
frozen lattice's sweeps, the fields of expensive operators held fixed while
the rest converge, and the error when a solve does not converge.

:class:`MidpointSolves` is a part of CollectivePRK (its methods read
``self._state``, ``self.ev``, ``self.tol``, ``self._solver``).
"""

from __future__ import annotations

import numpy as np
from ase import units

from .._jit import threads
from ..neighbors import rows_in_order
from . import kernels, policy
from .base import MAX_PHASE, precession_phrase
from .errors import SpinConvergenceError

__all__ = ["MidpointSolves", "THREADED_COLOURS"]

#: Colours a lattice of threaded size may have for its frozen stages to take
#: colour order (MidpointSolves._colour_pairs): two, a two-colourable lattice
#: (simple cubic, bcc with its nearest neighbours), where a colour-ordered
#: sweep squares the error.
THREADED_COLOURS = 2


class MidpointSolves:
    """The midpoint solves of a collective step (see the module docstring)."""

    def _solve(self, s, operators, W, h, stage, mean=True, tol=None, first=True):
        """Midpoint spins for the midpoint fields of ``operators`` (B̄ =
        ½[B(q, W) + B(q̃, W)]; B(q, W) itself when ``mean`` is False: a frozen
        lattice), to tolerance ``tol`` (default the policy's). Returns (W, s̃,
        sweeps, how far W moved from the starting guess, the rounding error of s̃).
        ``first``: the step's first solve (from the predictor), whose sweeps
        "auto" chooses by policy.auto_takes_local when it is to the policy's
        tolerance. The solver's settings and its switch: policy.solver_settings."""
        st = self._state
        rules = st.policy
        tol = rules.tol if tol is None else tol
        chooses = first and tol <= rules.tol  # (not a loose first solve, not a later one)
        scale = self._scale(h)
        carry = np.zeros_like(s)
        stilde = np.zeros_like(s)
        memory, local, sweeps, switch, adaptive = policy.solver_settings(
            rules.solver, (stage, h) in st.modes, rules.max_iter)
        if adaptive:
            if chooses:
                local = policy.auto_takes_local(st.one_sweep[stage], st.theta[stage])
            # cheap sweeps while they contract fast; the stiff case is retried below,
            # from the starting guess if they contracted slowly last time (a copy:
            # 24 bytes per atom at the step's peak memory), else from their last iterate
            guess = W.copy() if st.theta[stage] > policy.KEEP_GUESS else None
            its, delta, status, which, theta, moved = self._run_solver(
                s, operators, W, stage, mean, scale, stilde, carry, tol, memory, local, sweeps)
            if (status != kernels.NOT_CONVERGED
                    and not policy.gives_up(its, theta, switch)):
                st.theta[stage] = theta if 0.0 <= theta < 1.0 else st.theta[stage]
                if chooses:
                    st.one_sweep[stage] = its == 1
                self._choose_order(stage, local, its, theta)
                if which == 1:
                    W, st.Wnext = st.Wnext, W
                return W, stilde, its, moved, carry
            st.one_sweep[stage] = False
            st.modes[(stage, h)] = "anderson"
            st.theta[stage] = 1.0
            memory, local, sweeps, _, _ = policy.solver_settings(rules.solver, True,
                                                                  rules.max_iter)
            if status == kernels.NOT_CONVERGED:
                if guess is not None:
                    W = guess
                elif which == 1:
                    W, st.Wnext = st.Wnext, W
                spent = its
                its, delta, status, which, theta, moved = self._run_solver(
                    s, operators, W, stage, mean, scale, stilde, carry, tol, memory, local,
                    sweeps)
                its += spent
        else:
            its, delta, status, which, theta, moved = self._run_solver(
                s, operators, W, stage, mean, scale, stilde, carry, tol, memory, local, sweeps)
        self._choose_order(stage, local, its, theta)
        st.theta[stage] = theta if 0.0 <= theta < 1.0 else st.theta[stage]
        if which == 1:
            W, st.Wnext = st.Wnext, W
        if status == kernels.NOT_CONVERGED:
            self._raise_not_converged(operators, s, W, its, delta, mean)
        return W, stilde, its, moved, carry

    def _choose_order(self, stage, local, sweeps, measured):
        """After a solve at ``stage`` (locally exact sweeps or not: ``local``; ``sweeps`` sweeps, contraction
        ``measured`` or −1): the order of that stage's next locally exact
        sweeps (policy.next_sweep_order; a frozen lattice, used with one spin
        operator of linear pairs; in a system of threaded size only on a
        lattice of :data:`THREADED_COLOURS` colours at most, see
        :meth:`_colour_pairs`)."""
        if self.frozen:
            st = self._state
            st.sweep_order[stage], st.theta_index[stage] = policy.next_sweep_order(
                st.sweep_order[stage], local, sweeps, measured,
                st.theta_index[stage])

    def _colour_pairs(self, operators, mean):
        """(row, nbr, c, order, starts) for a colour-ordered solve: the full
        list's rows copied in colour order (neighbors.rows_in_order, made once:
        a frozen lattice's pairs and couplings do not change) and its
        colouring; or None where colour order does not pay: in a system of
        threaded size (threads.SERIAL_BELOW atoms or more) whose colouring
        takes more than :data:`THREADED_COLOURS` colours. There every colour is
        a parallel region of its own, and more of them cost about what their
        fewer sweeps save (docs/benchmarks.md, "Why each fast path exists"). The
        stages then keep index order for good and the full list is let go.
        Decided from the size and the lattice alone, never the threads: the
        same bits whatever their count."""
        st = self._state
        pairs, c = self._full_pairs(operators, mean)
        order, starts = pairs.colours()
        colours = len(starts) - 1
        n = len(st.s)
        if n >= threads.SERIAL_BELOW and colours > THREADED_COLOURS:
            st.sweep_order[:] = policy.INDEX_ORDER_KEPT
            st.full_ops = None
            st.colour_rows = None
            return None
        kept = st.colour_rows
        if kept is None or kept[0] is not c:
            kept = st.colour_rows = (c, rows_in_order(pairs.row, pairs.j, c, order))
        return (*kept[1], order, starts)

    def _full_pairs(self, operators, mean):
        """(pairs, c) of ``operators``' one linear-pairs operator on the full
        pair list, with its colouring: the operator itself if it is on one,
        else its twin made once (a frozen lattice: the pairs do not change)."""
        pairs, c = operators[0].linear_pairs(mean)
        if not pairs.half:
            return pairs, c
        st = self._state
        if st.full_ops is None:
            st.full_ops = self.ev.spin_operators(st.q, half=False)
        return st.full_ops[0].linear_pairs(mean)

    def _midpoint_field_buffer(self):
        """An (n, 3) buffer for a solve's midpoint fields (made once, zero: the
        rows without spin, which no solve writes, stay 0)."""
        st = self._state
        if st.field_buffer is None or st.field_buffer.shape != st.s.shape:
            st.field_buffer = np.zeros_like(st.s)
        return st.field_buffer

    def _scale(self, h):
        """c_i = hσ r_i/ħ of a stage of size h (one array per step size, kept)."""
        st = self._state
        scale = st.scales.get(h)
        if scale is None:
            scale = st.scales[h] = (h * self.sigma / self.hbar) * st.rate
        return scale

    def _run_solver(self, s, operators, W, stage, mean, scale, stilde, carry, tol, memory,
                    local, max_iter):
        """One midpoint solve by the kernels: Anderson ``memory``, locally exact
        sweeps or not (``local``), at most ``max_iter`` sweeps (see :meth:`_solve`).
        Where some of ``operators`` declare ``expensive_field`` and others do
        not (policy.held_operators), their fields are held fixed while the
        others converge, then updated (kernels.midpoint_solve_held: the same
        fixed point to ``tol``); a stage whose outer iteration contracts by
        more than policy.HELD_SWITCH solves plainly from then on."""
        st = self._state
        split = None if st.unheld[stage] else policy.held_operators(operators)
        if split is None:
            return self._sweeps(s, operators, W, st.Wnext, stage, mean, scale, stilde, carry,
                                tol, memory, local, max_iter, kernels.NO_FIELD)
        held, rest = split
        guess = W.copy()  # for the plain solve, should the held fields' iteration give up

        def inner(cur, nxt, external):
            return self._sweeps(s, rest, cur, nxt, stage, mean, scale, stilde, carry, tol,
                                memory, local, max_iter, external)

        *result, outer_theta, gave_up = kernels.midpoint_solve_held(
            inner, held, W, st.Wnext, tol, st.policy.floor, max_iter,
            policy.start_contraction(st.held_theta[stage]), mean, policy.HELD_SWITCH,
            policy.HELD_MEMORY)
        if 0.0 <= outer_theta < 1.0:
            st.held_theta[stage] = outer_theta
        if not gave_up:
            return tuple(result)
        st.unheld[stage] = True
        W[:] = guess
        return self._sweeps(s, operators, W, st.Wnext, stage, mean, scale, stilde, carry, tol,
                            memory, local, max_iter, kernels.NO_FIELD)

    def _sweeps(self, s, operators, W, Wnext, stage, mean, scale, stilde, carry, tol, memory,
                local, max_iter, external):
        """One call of the midpoint solvers over ``operators`` (buffers ``W``,
        ``Wnext``), with the fixed field ``external`` added (kernels.NO_FIELD:
        none; then a solve with one linear operator may take colour order and
        fill the midpoint fields a subclass asks for)."""
        st = self._state
        args = (s, W, Wnext, stilde, scale, tol, st.policy.floor, max_iter,
                policy.start_contraction(st.theta[stage]), st.carry_s, carry)
        plain = external is kernels.NO_FIELD
        if len(operators) == 1 and operators[0].linear:
            # B̄_i = Σ_j c_ij W_j (+ E_i): the whole iteration in one compiled loop
            coloured = None
            if plain and local and st.sweep_order[stage] == policy.COLOUR_ORDER:  # (frozen)
                coloured = self._colour_pairs(operators, mean)
            # the midpoint fields where asked for, else an empty array (not
            # None: one compiled specialisation for both kinds of caller)
            field = kernels.NO_FIELD
            if plain and st.field_out is not None:
                field = st.field_out
                st.field_filled = True
            if coloured is not None:
                row, nbr, c, order, starts = coloured
                return kernels.midpoint_solve(threads.count(), row, nbr, c, *args, memory, local,
                                              field, order, starts, external)
            pairs, c = operators[0].linear_pairs(mean)
            solve = kernels.midpoint_solve_half if pairs.half else kernels.midpoint_solve
            return solve(threads.count(), pairs.row, pairs.j, c, *args, memory, local, field,
                         kernels.NO_ORDER, kernels.NO_ORDER, external)
        return kernels.midpoint_solve_operators(operators, *args, mean, memory, local, external)

    def _raise_not_converged(self, operators, s, W, its, delta, mean):
        B = np.zeros_like(W)
        for op in operators:
            op.field(W, B, mean)
        if delta != delta:  # NaN: a field that is not finite, not a step too large
            row = kernels.first_nonfinite_row(W)  # the spin the NaN spread from, else
            row = row if row >= 0 else kernels.first_nonfinite_row(B)  # the field's
            if row >= 0:
                self._raise_nonfinite(2, row)
        # the phase of the timestep warning (one function: they cannot disagree),
        # from the fields at the step's start (at W, a midpoint of spins far
        # apart, they may all but vanish)
        try:
            omega = self._fastest_precession(self._state.q, s, self._state.mu)
        except (ValueError, FloatingPointError):  # (a failure of its own: not this one's)
            omega = float("nan")
        phase = abs(self.dt) * omega
        if self._solver == "jacobi":
            why = ("the Jacobi iteration (solver=\"jacobi\") contracts only while this is "
                   "well below 2 rad; solver=\"auto\" converges further. ")
        elif phase > kernels.MAX_TURN:
            why = (f"above {kernels.MAX_TURN:g} rad the midpoint rotation of a spin "
                   "saturates at a half turn: no step of the dynamics exists. ")
        else:
            why = "at this step size the midpoint spins may not exist or not be unique. "
        raise SpinConvergenceError(
            f"the midpoint-spin iteration ({self._solver}) did not converge at step "
            f"{self.nsteps}: max |ΔW| = {delta:.3g} after {its} iterations (tol "
            f"{self.tol:.1e}). At the step's start {precession_phrase(self.dt, omega)}: "
            f"{why}Reduce the timestep (now {self.dt / units.fs:.4g} fs; keep h·ω below "
            f"{MAX_PHASE} rad per step) or raise max_iter. The atoms keep the state "
            f"before this step.")
