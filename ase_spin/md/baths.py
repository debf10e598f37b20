"""The heat baths' half steps around the collective step (an O–PRK–O
splitting, docs/thermostats.md): the spin bath's damped precession and
diffusion and the lattice's Ornstein–Uhlenbeck kick, with their energies.
:class:`BathHalfSteps` is the part of :class:`~ase_spin.md.langevin.Langevin`
that acts between the deterministic steps; its compiled pieces are in
:mod:`ase_spin.md.kernels.bath`."""

from __future__ import annotations

from typing import NamedTuple, Optional

import numpy as np

from .._jit import threads
from ..terms.base import Want
from . import kernels
from .gaussian import new_key
from .kernels.bath import bath_block, damp_from, noise_amplitude, ornstein_uhlenbeck

__all__ = ["BathHalfSteps"]

_EB = Want(energy=True, magnetic_forces=True)
_B = Want(magnetic_forces=True)
_NO_FORCES = np.zeros((0, 3))
_NO_ENERGIES = np.zeros(0)
_E = Want(energy=True)


class _SpinFields(NamedTuple):
    """The spin terms at one state of the spins (fixed positions)."""

    E_linear: float  # energy of the B = C s terms (−½ s·C s)
    E_other: float  # of the others
    B: np.ndarray  # every term's field
    B_linear: Optional[np.ndarray]  # the B = C s terms' (None: there are none)

    @property
    def energy(self):
        return self.E_linear + self.E_other




class BathHalfSteps:
    """The baths' half steps of :class:`~ase_spin.md.langevin.Langevin` (its
    state, coefficients and random numbers are the integrator's)."""

    def _coefficients(self):
        """κ_i h, σ_i of N(h) and of N(h/2), c_i of the predictor's half step
        (cached per h, λ, T_s: the user may change them between runs)."""
        st = self._state
        key = (self.dt, self.spin_damping, self.spin_temp)
        coef = st.bath_coefficients.get(key)
        if coef is None:
            kappa_h = (self.spin_damping * self.dt / self.hbar) * st.rate
            d_h = self.spin_temp * kappa_h  # D_i h, D_i = κ_i k_B T_s
            c = (0.5 * self.gammas[0] * self.dt * self.sigma / self.hbar) * st.rate
            if len(st.bath_coefficients) > 8:
                st.bath_coefficients.clear()
            coef = st.bath_coefficients[key] = (kappa_h, noise_amplitude(d_h),
                                                noise_amplitude(0.5 * d_h), c)
        return coef

    # -- the step -------------------------------------------------------------------

    def _bath_begins_early(self, op):
        """Whether the next bath's first part is made with the step's end forces
        (:meth:`_end_forces`; ``op`` the one spin operator at q̃, else None)."""
        st = self._state
        return (st.field_out is not None and st.field_filled and self._spin_bath_on()
                and op is not None and op.forces_with_field)

    def _begin_bath(self, s_new):
        """y₀ = D(h/2) N(h) D(h/2) s̃ into the spare spins, its keys drawn as
        :meth:`_opening_bath` would (lattice, then spins): (lattice key, y₀,
        the rng state before the keys)."""
        st = self._state
        rng_state = self.rng.bit_generator.state
        lattice_key = new_key(self.rng) if self._lattice_bath_on() else None
        kappa_h, sig_h, _, _ = self._coefficients()
        if self.spin_temp > 0.0:
            key, sigma = new_key(self.rng), sig_h
        else:
            key, sigma = np.uint64(0), st.no_damping
        y0 = st.s_spare
        bath_block(s_new, y0, st.s_before, st.field_out, st.B_y0, 1.0, 0.5 * kappa_h, sigma,
                   key, 0.5 * kappa_h, self.ev.magnetic)
        return lattice_key, y0, rng_state

    def _noisy(self):
        """Does a bath with T > 0 act (the default ``tol`` is then NOISY_TOL)?"""
        return ((self.spin_damping > 0.0 and self.spin_temp > 0.0)
                or (self.fr > 0.0 and self.temp > 0.0))

    def _spin_bath_on(self):
        return self.magnetic and self.spin_damping > 0.0

    def _opening_bath(self):
        r"""The bath before the collective step: O_L(h/2) and, from the output
        point m, N(h/2) then D*(h/2) — the damping flow about the fields at its
        *end* y (implicit: y₀ = D_{B(m)} c, y = D_{B(y₀)} c, c = N(h/2) m).
        After a step whose closing half was put off (``pending``), the whole
        bath between the two collective steps: O_L(h) and, in time order,
        D(h/2) N(h) D*(h/2) (D: see :meth:`_closing_bath`), y₀ from the
        fields at the bath's start — made already, with B(y₀), when the last
        step's end forces were (:meth:`_end_forces`).

        The bath energy E(y) − E(x) (x the spins at the bath's start) and the
        predictor's field take one pass after the move, not a pass at y: for
        the terms B = C s (``linear_pairs``; C symmetric, fixed positions)

        .. math:: E(y) - E(x) = -x\cdot C\delta
                  - \tfrac12\,\delta\cdot C\delta, \qquad \delta = y - x,

        exactly, and the field the midpoint predictor takes is
        B(y₀) + C k, k = (y − y₀) + c y × B(y₀) (:func:`damp_from`): B(y)
        plus the first-order change over the explicit half step, the
        neighbours' motion that the random moves make unpredictable from the
        last steps (3 midpoint sweeps instead of 4). C k and both forms come
        from one pass over the pairs
        (:func:`~ase_spin.md.kernels.linear_field_and_form`); other terms give
        their energy at y from ``add``. The energy takes no field at x: that
        field need only steer the damping (see :meth:`_closing_bath`)."""
        st = self._state
        pending, B0 = st.pending, st.pending_B0
        st.pending, st.pending_B0 = False, None
        early, st.early = getattr(st, "early", None), None
        st.B_y0_fresh = False
        self._lattice_bath(self.dt if pending is not False else 0.5 * self.dt,
                           None if early is None else early[0])
        if not self._spin_bath_on():
            return
        kappa_h, sig_h, sig_half, c = self._coefficients()
        noisy = self.spin_temp > 0.0
        if pending is not False:
            start = pending
            k1, sigma = 0.5 * kappa_h, sig_h
        else:
            start = st.EB if st.EB is not None else self._spin_energy_fields()
            k1, sigma = st.no_damping, sig_half
        mag = self.ev.magnetic
        x, y0, y = st.s, st.s_spare, st.s_spare2
        if early is not None:  # y₀ and B(y₀) are here already (_end_forces)
            B1 = early[2]
        else:
            key = new_key(self.rng) if noisy else np.uint64(0)
            if not noisy:
                sigma = st.no_damping
            w = 0.0 if B0 is None else 1.0  # the field at the start, or 2B̄ − B(y₀)
            bath_block(x, y0, st.s_before, start.B, start.B if B0 is None else B0, w, k1,
                       sigma, key, 0.5 * kappa_h, mag)
            # y₀ = D_{B0}(h/2) c; the fields at y₀ give the corrector
            st.s = y0
            B1 = self._spin_energy_fields(energy=False).B
        # x stays as it was until the forms below are taken
        st.s, st.s_spare, st.s_spare2 = y, x, y0
        st.carry_s[:] = 0.0  # the spins were replaced: no rounding error to carry
        if start.B_linear is None:  # no term of the form B = C s
            damp_from(st.s_before, B1, 0.5 * kappa_h, mag, y)
            end = self._spin_energy_fields()
            self.bath_energy_spin += end.energy - start.energy
            st.B_next = end.B
            return
        # B(y₀) kept for the field at this step's end (_closing_bath)
        if st.B_y0 is None or st.B_y0.shape != B1.shape:
            st.B_y0 = np.empty_like(B1)
        damp_from(st.s_before, B1, 0.5 * kappa_h, mag, y, y0, c, st.kick, st.B_y0)
        st.B_y0_fresh = len(st.ops) == 1
        B = B1  # B(y₀) + C k, below
        form = cross = 0.0
        others = 0.0
        for op in st.ops:
            if op.linear:
                pairs, coupling = op.linear_pairs()
                f, g = kernels.linear_field_and_form(threads.count(), pairs.row, pairs.j,
                                                     coupling, pairs.half, st.kick, y, x, B)
                form += f
                cross += g
            else:
                others += op.add(y, _E, _NO_FORCES, _NO_FORCES, _NO_ENERGIES)[0]
        self.bath_energy_spin += -cross - 0.5 * form + (others - start.E_other)
        st.B_next = B

    def _closing_bath(self, midpoint_field=None):
        r"""The bath after the collective step: O_L(h/2), D(h/2) about the fields
        at its start, N(h/2) — or nothing yet if the next step's opening half
        takes over (see :meth:`_step`).

        Put off, the bath's first move D(h/2) needs the field at the step's
        end x = s̃ only to steer the damping (the energy is taken from forms,
        :meth:`_opening_bath`). With ``midpoint_field`` B̄ (the solve's
        midpoint fields, B̄ = ½[C(q) + C(q̃)] W; one term B = C s, order 2) it
        is

        .. math:: \hat{\mathbf B}(x) = 2\bar{\mathbf B} - \mathbf B(y_0)
                  = C(\tilde q)\,\tilde s + O(h^2)

        (W = (s + s̃)/|s + s̃| = (s + s̃)/2 + O(h²), and
        ½[C(q) − C(q̃)](s̃ − s) = O(h²); B(y₀) = C(q) s up to the corrector's
        move): the damping about it errs by O(λh³) per step, within the
        scheme's own local error, and saves a pass over the pairs."""
        st = self._state
        on = self._spin_bath_on()
        if midpoint_field is not None:  # (put off: see _substep)
            # B̂ is formed row by row in the next bath (bath_block's w = 1)
            st.pending = st.EB = _SpinFields(np.nan, 0.0, midpoint_field, midpoint_field)
            st.pending_B0 = st.B_y0
            return
        # put off: the next opening half takes the exchange energy from the
        # forms (see _opening_bath), not from E here
        EB = self._spin_energy_fields(linear_energy=not self._defer) if on else None
        if self._defer:
            st.pending = EB
            st.EB = EB
            return
        self._lattice_bath(0.5 * self.dt)
        if not on:
            return
        kappa_h, _, sig_half, _ = self._coefficients()
        sigma, key = sig_half, np.uint64(0)
        if self.spin_temp > 0.0:
            key = new_key(self.rng)
        else:
            sigma = st.no_damping
        bath_block(st.s, st.s_spare, st.s_before, EB.B, EB.B, 0.0, 0.5 * kappa_h, sigma, key,
                   st.no_damping, self.ev.magnetic)
        st.s, st.s_spare = st.s_spare, st.s
        st.carry_s[:] = 0.0
        st.EB = self._spin_energy_fields()
        self.bath_energy_spin += st.EB.energy - EB.energy

    def _spin_energy_fields(self, energy=True, linear_energy=True):
        """:class:`_SpinFields` at the current spins: one pass (``linear_energy``
        False: E_linear left NaN, for a caller that does not use it).

        Operators of the form B_i = Σ_j c_ij s_j (``linear_pairs``: exchange)
        give their fields alone, and their energy as −½ Σ_i s_i·B_i: the
        energy of a quadratic form up to a constant (Exchange's offset), which
        cancels in the differences at fixed positions that the bath energy
        is made of. Other operators give both from ``add``."""
        st = self._state
        s = st.s
        B = np.zeros_like(s)
        others = []
        for op in st.ops:
            if op.linear:
                op.field(s, B)
            else:
                others.append(op)
        linear = None
        E_linear = E_other = 0.0
        if len(others) < len(st.ops):
            linear = B.copy() if others else B
            if not linear_energy:
                E_linear = np.nan
            elif energy:
                E_linear = -0.5 * float(np.einsum("ij,ij->", s, B))
        want = _EB if energy else _B
        for op in others:
            E_other += op.add(s, want, B, _NO_FORCES, _NO_ENERGIES)[0]
        return _SpinFields(float(E_linear), float(E_other), B, linear)

    def _lattice_bath_on(self):
        return self.fr != 0.0 and not self.frozen

    def _lattice_bath(self, tau, key=None):
        """O_L(τ): the exact Ornstein–Uhlenbeck step of the momenta; adds the
        kinetic-energy change to ``bath_energy_lattice``. ``key``: its random
        numbers' key if drawn already (:meth:`_end_forces`)."""
        st = self._state
        if not self._lattice_bath_on():
            return
        c1 = np.exp(-self.fr * tau)
        c2 = np.sqrt(-np.expm1(-2.0 * self.fr * tau) * self.temp)
        # the momenta before the last bath: nothing refers to them any more
        p = st.p_spare if st.p_spare is not None and st.p_spare.shape == st.p.shape else None
        if p is None or p is st.p:
            p = np.empty_like(st.p)
        m = self.masses[:, 0]
        dK = ornstein_uhlenbeck(st.p, new_key(self.rng) if key is None else key, m, c1, c2,
                                self.fix_com, p)
        if st.constraints:
            K0 = 0.5 * float(np.einsum("ij,ij->", st.p, st.p / self.masses))
            p = self._adjust_momenta(p, st.q)
            dK = 0.5 * float(np.einsum("ij,ij->", p, p / self.masses)) - K0
        self.bath_energy_lattice += dK
        st.p_spare, st.p = st.p, p
        st.carry_p[:] = 0.0

    # -- observables -----------------------------------------------------------------
