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
        """κ_i h, σ_i of N(h/2), c_i of the predictor's half step (cached per
        h, λ, T_s: the user may change them between runs)."""
        st = self._state
        key = (self.dt, self.spin_damping, self.spin_temp)
        coef = st.bath_coefficients.get(key)
        if coef is None:
            kappa_h = (self.spin_damping * self.dt / self.hbar) * st.rate
            d_h = self.spin_temp * kappa_h  # D_i h, D_i = κ_i k_B T_s
            c = (0.5 * self.gammas[0] * self.dt * self.sigma / self.hbar) * st.rate
            if len(st.bath_coefficients) > 8:
                st.bath_coefficients.clear()
            coef = st.bath_coefficients[key] = (kappa_h, noise_amplitude(0.5 * d_h), c)
        return coef

    # -- the step -------------------------------------------------------------------

    def _bath_begins_early(self, op):
        """Whether the closing bath half's spin move is made with the step's end
        forces (:meth:`_end_forces`; ``op`` the one spin operator at q̃, else None)."""
        st = self._state
        return (st.field_out is not None and st.field_filled and self._spin_bath_on()
                and op is not None and op.forces_with_field)

    def _spin_key(self):
        """(key, σ) of a noise move N(h/2): a fresh key with a bath at T_s > 0,
        else none drawn and σ = 0."""
        st = self._state
        if self.spin_temp > 0.0:
            return new_key(self.rng), self._coefficients()[1]
        return np.uint64(0), st.no_damping

    def _begin_bath(self, s_new):
        """The closing half's spin move m = N(h/2) D(h/2) s̃ about the field at
        the step's end from its midpoint fields (``field_out``, 2B̄ − B(y₀)),
        into a new array, its keys drawn as :meth:`_closing_bath` would
        (lattice, then spins): (lattice key, m, the rng state before the keys)."""
        st = self._state
        rng_state = self.rng.bit_generator.state
        lattice_key = new_key(self.rng) if self._lattice_bath_on() else None
        key, sigma = self._spin_key()
        m = np.empty_like(s_new)
        bath_block(s_new, m, st.s_before, st.field_out, st.B_y0, 1.0,
                   0.5 * self._coefficients()[0], sigma, key, st.no_damping, self.ev.magnetic)
        return lattice_key, m, rng_state

    def _noisy(self):
        """Does a bath with T > 0 act (the default ``tol`` is then NOISY_TOL)?"""
        return ((self.spin_damping > 0.0 and self.spin_temp > 0.0)
                or (self.fr > 0.0 and self.temp > 0.0))

    def _spin_bath_on(self):
        return self.magnetic and self.spin_damping > 0.0

    def _opening_bath(self):
        r"""The bath before the collective step: O_L(h/2) and, from the output
        point m, N(h/2) then D*(h/2) — the damping flow about the fields at its
        *end* y (implicit: y₀ = D_{B(m)} c, y = D_{B(y₀)} c, c = N(h/2) m). The
        same at every step: B(m) is known from the step before (its closing
        half, :meth:`_closing_bath`) or taken here, the same bits either way.

        The bath energy E(y) − E(x) and the predictor's field take one pass
        after the move, not a pass at y: for the terms B = C s (``linear_pairs``;
        C symmetric, fixed positions)

        .. math:: E(y) - E(x) = -x\cdot C\delta
                  - \tfrac12\,\delta\cdot C\delta, \qquad \delta = y - x,

        exactly, and the field the midpoint predictor takes is
        B(y₀) + C k, k = (y − y₀) + c y × B(y₀) (:func:`damp_from`): B(y)
        plus the first-order change over the explicit half step, the
        neighbours' motion that the random moves make unpredictable from the
        last steps (3 midpoint sweeps instead of 4). C k and both forms come
        from one pass over the pairs
        (:func:`~ase_spin.md.kernels.linear_field_and_form`); other terms give
        their energy at y from ``add``. x is m, or, when the last closing half
        left its energy uncounted (``bath_from``: exchange alone, see
        :meth:`_closing_bath`), the spins x before that half: the forms then
        count both halves. The forms never change C k: the trajectory is the
        same either way."""
        st = self._state
        st.B_y0_fresh = False
        if st.bath_from is not None and not self._spin_bath_on():  # (λ set to 0 since)
            self.bath_energy_spin += self._pending_bath_energy(st)
            st.bath_from = None
        ref = st.bath_from
        if ref is not None:  # (for a step that fails: see Langevin._step)
            # taken over before it is cleared: an interrupt in between must
            # find it in one place or the other
            self._consumed = (st.q, st.s, ref)
        st.bath_from = st.bath_pending = None
        self._lattice_bath(0.5 * self.dt)
        if not self._spin_bath_on():
            return
        kappa_h, _, c = self._coefficients()
        start = st.EB if st.EB is not None else self._spin_energy_fields()
        mag = self.ev.magnetic
        x, y0, y = st.s, st.s_spare, st.s_spare2
        key, sigma = self._spin_key()
        # c = N(h/2) x into st.s_before, y₀ = D_{B(x)}(h/2) c
        bath_block(x, y0, st.s_before, start.B, start.B, 0.0, st.no_damping, sigma, key,
                   0.5 * kappa_h, mag)
        # the fields at y₀ give the corrector
        st.s = y0
        B1 = self._spin_energy_fields(energy=False).B
        # x stays as it was until the forms below are taken
        st.s, st.s_spare, st.s_spare2 = y, x, y0
        st.carry_s[:] = 0.0  # the spins were replaced: no rounding error to carry
        if start.B_linear is None:  # no term of the form B = C s
            none = np.empty((0, 3))  # no predictor's kick wanted (damp_from)
            damp_from(st.s_before, B1, 0.5 * kappa_h, mag, y, none, np.empty(0), none, none)
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
        if ref is None:
            ref = x
        for op in st.ops:
            if op.linear:
                pairs, coupling = op.linear_pairs()
                f, g = kernels.linear_field_and_form(threads.count(), pairs.row, pairs.j,
                                                     coupling, pairs.half, st.kick, y, ref, B)
                form += f
                cross += g
            else:
                others += op.add(y, _E, _NO_FORCES, _NO_FORCES, _NO_ENERGIES)[0]
        self.bath_energy_spin += -cross - 0.5 * form + (others - start.E_other)
        st.B_next = B

    def _closing_bath(self, midpoint_field=None):
        r"""The bath after the collective step: O_L(h/2), D(h/2) about the fields
        at its start x = s̃, N(h/2); the spins m it leaves are the output point,
        and B(m) is kept for the next opening half.

        With ``midpoint_field`` B̄ (the solve's midpoint fields,
        B̄ = ½[C(q) + C(q̃)] W; one term B = C s, order 2) the field at x is
        taken without a pass over the pairs as

        .. math:: \hat{\mathbf B}(x) = 2\bar{\mathbf B} - \mathbf B(y_0)
                  = C(\tilde q)\,\tilde s + O(h^2)

        (W = (s + s̃)/|s + s̃| = (s + s̃)/2 + O(h²), and
        ½[C(q) − C(q̃)](s̃ − s) = O(h²); B(y₀) = C(q) s up to the corrector's
        move): the damping about it errs by O(λh³) per step, within the
        scheme's own local error. The move itself and B(m) are then made with
        the step's end forces where their pass allows (:meth:`_end_forces`),
        else here; and the spin energy this half puts in, E(m) − E(x), which
        would take a pass at x, is counted by the next opening half together
        with its own (``bath_from``), or when it is read
        (:meth:`_pending_bath_energy`)."""
        st = self._state
        early, st.early = st.early, None
        on = self._spin_bath_on()
        if early is not None:  # (begun with the end forces: _end_forces)
            self._lattice_bath(0.5 * self.dt, early[0])
            x, st.s = st.s, early[1]
            st.EB = _SpinFields(np.nan, 0.0, early[2], early[2])
            st.bath_from, st.bath_pending = x, None
            st.carry_s[:] = 0.0
            return
        if not on:
            self._lattice_bath(0.5 * self.dt)
            return
        kappa_h = self._coefficients()[0]
        x = st.s
        m = np.empty_like(x)  # (a new array: see Langevin._step)
        if midpoint_field is not None:
            self._lattice_bath(0.5 * self.dt)
            key, sigma = self._spin_key()
            # B̂ is formed row by row (bath_block's w = 1)
            bath_block(x, m, st.s_before, midpoint_field, st.B_y0, 1.0, 0.5 * kappa_h, sigma,
                       key, st.no_damping, self.ev.magnetic)
            st.s = m
            st.carry_s[:] = 0.0
            st.EB = self._spin_energy_fields(energy=False)
            st.bath_from, st.bath_pending = x, None
            return
        EB = self._spin_energy_fields()
        self._lattice_bath(0.5 * self.dt)
        key, sigma = self._spin_key()
        bath_block(x, m, st.s_before, EB.B, EB.B, 0.0, 0.5 * kappa_h, sigma, key,
                   st.no_damping, self.ev.magnetic)
        st.s = m
        st.carry_s[:] = 0.0
        st.EB = self._spin_energy_fields()
        self.bath_energy_spin += st.EB.energy - EB.energy

    def _pending_bath_energy(self, st):
        """The spin energy E(m) − E(x) the last closing half put in while it is
        not counted yet (``bath_from`` = x, m the spins now; one spin operator
        of the form B = C s): −½ m·B(m) + ½ x·C x, one pass over the pairs."""
        Bx = np.zeros_like(st.bath_from)
        for op in st.ops:
            op.field(st.bath_from, Bx)
        Bm = st.EB.B if st.EB is not None else None
        if Bm is None:
            Bm = np.zeros_like(st.s)
            for op in st.ops:
                op.field(st.s, Bm)
        return float(0.5 * np.einsum("ij,ij->", st.bath_from, Bx)
                     - 0.5 * np.einsum("ij,ij->", st.s, Bm))

    def _spin_energy_change(self, q, m, x):
        """E(m) − E(x) of the spin terms at positions q, from operators made
        afresh (after a failed step, whose own may have moved on)."""
        ops = self.ev.spin_operators(q, half=self.half_lists)
        Bm, Bx = np.zeros_like(m), np.zeros_like(x)
        for op in ops:
            op.field(m, Bm)
            op.field(x, Bx)
        return float(0.5 * np.einsum("ij,ij->", x, Bx) - 0.5 * np.einsum("ij,ij->", m, Bm))

    def _spin_energy_fields(self, energy=True):
        """:class:`_SpinFields` at the current spins: one pass (``energy``
        False: the fields only).

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
            if energy:
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
