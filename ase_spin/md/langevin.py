"""Temperature control: spin and lattice Langevin dynamics around the collective step.

The deterministic (Hamiltonian) part of every step is :class:`CollectivePRK`'s
symplectic step, reused by inheritance; the baths act in two half steps around
it (an O–PRK–O splitting, docs/thermostats.md).
"""

from __future__ import annotations

from collections import deque

import numpy as np
from ase import units

from .._jit import threads
from ..validate import REQUIRED, flag, real_scalar
from . import bath_parameters as parameters
from . import kernels
from .baths import BathHalfSteps
from .collective import CollectivePRK
from .kernels.bath import midpoint_remainder, predict_midpoint
from .logger import LangevinLogger

__all__ = ["Langevin", "LangevinLogger"]


#: Default midpoint tolerance with a bath at T > 0 acting: the noise moves each
#: spin by ~√(2Dh) per step and the predictor cannot foresee it, so round-off
#: (CollectivePRK's 1e-15) costs more sweeps a step for no difference that the
#: run can show (E_tot − E_bath and the sampling: docs/thermostats.md;
#: ``benchmarks/bench_langevin.py``).
NOISY_TOL = 1e-10
#: The remainder predictor with a noisy spin bath, row m (newest first): the
#: last remainder plus the mean of the last m increments (see Langevin._predict).
_MEAN_SLOPE = np.array([[1.0, 0.0, 0.0, 0.0],
                        [2.0, -1.0, 0.0, 0.0],
                        [1.5, 0.0, -0.5, 0.0],
                        [4.0 / 3.0, 0.0, 0.0, -1.0 / 3.0]])
#: Outer-iteration settling tolerance with a bath on (see Langevin.step_policy).
_SETTLED = 1e-12
#: and of q̃ (Å), see Langevin.step_policy
_SETTLED_Q = 1e-10


class Langevin(BathHalfSteps, CollectivePRK):
    r"""Spin–lattice dynamics in contact with heat baths (spins and lattice).

    Equations of motion (Stratonovich; B_i = −∂E/∂s_i, eV; r_i the precession
    rate factor of ``gyromagnetic``: 1, or g/μ_i; σ of ``precession``;
    λ = ``spin_damping``; γ = ``friction``):

    .. math::

        \dot{\mathbf r}_i &= \mathbf p_i/m_i, \qquad
        \dot{\mathbf p}_i = \mathbf F_i - \gamma\,\mathbf p_i
            + \sqrt{2\gamma m_i k_B T}\,\boldsymbol\eta_i(t), \\
        \dot{\mathbf s}_i &= \frac{r_i}{\hbar(1+\lambda^2)}
            \left[\sigma\,\mathbf s_i\times\mathbf B_i
                  - \lambda\,\mathbf s_i\times(\mathbf s_i\times\mathbf B_i)\right]
            + \sqrt{2D_i}\;\mathbf s_i\times\boldsymbol\zeta_i(t),
        \qquad D_i = \frac{\lambda\, r_i\, k_B T_s}{\hbar(1+\lambda^2)},

    η, ζ unit white noises (⟨ζ_a(t)ζ_b(t')⟩ = δ_ab δ(t−t')). The spin line is
    the Landau–Lifshitz form of the Gilbert equation with damping λ (LAMMPS
    ``fix langevin/spin``'s α_t, 1/(1+λ²) its "Gilbert factor"). Fluctuation–
    dissipation, per spin: with κ_i = λ r_i/(ħ(1+λ²)) the damping drift is
    −κ_i ∇_s E and the noise a rotational diffusion D_i Δ_s, so the
    Fokker–Planck current is J = −κ_i P ∇_s E − D_i ∇_s P; for
    P ∝ exp(−E/k_B T_s) it is P ∇_s E (D_i/k_B T_s − κ_i), zero iff
    D_i = κ_i k_B T_s, whatever the moment μ_i and rate r_i (the precession
    current is divergence-free for any P = f(E)). Written as a thermal field ξ_i added
    to B_i in both terms, the same variance is
    ⟨ξ_ia(t) ξ_jb(t')⟩ = 2 λ ħ k_B T_s / r_i δ_ij δ_ab δ(t−t'):
    proportional to μ_i/g under ``gyromagnetic="moment"`` (LAMMPS issue 5097:
    one μ-independent variance leaves mixed-moment sublattices off the bath
    temperature), independent of μ_i under ``"lammps"`` (r_i = 1).

    One step of size h (docs/thermostats.md, docs/dynamics.md), in time order:

    .. math:: O_L(h/2)\,N(h/2)\,D^*(h/2)\;\Phi^{\rm PRK}_h\;O_L(h/2)\,D(h/2)\,N(h/2)

    Φ^PRK is :class:`CollectivePRK`'s step with the precession rates
    r_i/(1+λ²) (any ``order``: its composition stages all sit inside);
    O_L(τ): p ← e^{−γτ} p + √(1−e^{−2γτ}) √(m k_B T) ξ (exact
    Ornstein–Uhlenbeck, as ASE's Langevin); D(τ): the exact damping flow about
    the fields frozen at its start, D*(τ) about those at its end (implicit,
    one correction: :func:`_damped`), so that the step is symmetric; N(τ):
    s_i ← (s_i + ζ_i)/|s_i + ζ_i| with ζ_i ⟂ s_i Gaussian of variance
    σ_i² = 2D_iτ(1 + 5D_iτ) per direction (:func:`noise_amplitude`: weak
    second order). Sampling is weak second order (measured, docs/thermostats.md).
    Every step is this whole step, whatever observes the run and however it
    is cut into runs: its output point lies on the trajectory, and a seed
    fixes the trajectory (docs/dynamics.md, "Reproducibility"). Four passes
    over the spin terms per step; with exchange alone at order 2 two (the
    field at the step's end from its midpoint fields, :meth:`_closing_bath`,
    and the fields B(m) after the closing half in the pass of the step's end
    forces, :meth:`_end_forces`; three where that pass is not the Python
    step's: a frozen lattice, the compiled small-system step). Every spin
    update is a rotation or a normalised move: |s_i| stays 1 to round-off.

    Parameters
    ----------
    atoms, timestep
        As for :class:`CollectivePRK`; the timestep must be positive.
    temperature_K : float, required
        Lattice bath temperature (K). (``temperature``, ASE's older name, in
        eV there, is refused as an unknown keyword naming this one.)
    spin_damping : float, required
        λ ≥ 0, dimensionless; typically 0.01 to 0.1 (LAMMPS's ``fix
        langevin/spin`` example: 0.01); 0: spins without bath (their NVE
        precession).
    friction : float, required
        γ ≥ 0 in 1/(ASE time), as ``ase.md.langevin.Langevin``: typically
        ``0.001 / units.fs`` to ``0.01 / units.fs`` (ASE's suggestion);
        0: lattice without bath.

        The three have no defaults, as ASE's Langevin (friction) and LAMMPS's
        ``fix langevin`` and ``fix langevin/spin``: how strongly a bath
        couples is part of the physics a run shows (how fast it equilibrates,
        how much the bath disturbs time correlations, switching rates and
        magnon lifetimes), not a numerical setting, so it is the user's
        choice. Leaving one out is a TypeError that names each with its
        typical values; an unknown keyword is reported first, with the one
        most likely meant.
    spin_temperature_K : float, optional
        Spin bath temperature (K); default ``temperature_K``.
    fixcm : bool
        Keep the total momentum as it is (the random and friction forces'
        sum is taken off, mass-weighted), as ASE's ``fixcm``.
    rng : numpy Generator, int seed or None
        The random numbers: each bath move takes one 64-bit key from it and
        draws its Gaussian numbers inside the compiled kernels
        (:mod:`ase_spin.md.gaussian`: the same for any thread count), up
        to four a step, in a fixed order. The same seed and start give the same
        trajectory, to the bit, whatever observes the run or how it is cut
        into runs; a run is continued by restoring
        ``dyn.rng.bit_generator.state`` (see docs/thermostats.md).
    tol : float, optional
        The midpoint iteration's tolerance, as for :class:`CollectivePRK`;
        default :data:`NOISY_TOL` (1e-10) when a bath at T > 0 acts at
        construction, else round-off (1e-15): the noise the predictor cannot
        foresee would make round-off cost more sweeps a step, with no
        difference in E_tot − E_bath or the sampling (docs/thermostats.md).
    hbar, precession, gyromagnetic, g, order, max_iter, lattice, trajectory,
    logfile, loginterval, **kwargs
        As for :class:`CollectivePRK`. The log adds the energy the baths put
        in (Ebath) and the conserved Etot − Ebath: :class:`LangevinLogger`.
    """

    # its own midpoint predictor (_predict, _remember_midpoint) and its baths
    # between steps: the compiled executor takes its coupled step alone
    compiled_predictor = False
    compiled_blocks = False
    #: the field at a step's end for the closing bath half from the solve's
    #: midpoint fields where it can (see _closing_bath); False: a pass over the
    #: spin terms (tests/test_langevin.py compares the two)
    _end_field_from_midpoint = True

    def __init__(self, atoms, timestep, temperature_K=REQUIRED, *, spin_damping=REQUIRED,
                 friction=REQUIRED, spin_temperature_K=None, hbar=None, precession=None,
                 gyromagnetic=None, order=2, fixcm=True, rng=None, trajectory=None,
                 logfile=None, loginterval=1, **kwargs):
        # unknown keywords first: temperature=300 (ASE's old name) is a slip to
        # name as such, not a missing temperature_K
        self._refuse_unknown(kwargs)
        parameters.require(temperature_K=temperature_K, spin_damping=spin_damping,
                           friction=friction)
        self.set_temperature(temperature_K, spin_temperature_K)
        self.spin_damping = spin_damping
        self.fr = friction
        self.fix_com = flag(fixcm, "fixcm")
        self.rng = parameters.generator(rng)
        if not real_scalar(timestep, "timestep") > 0.0:
            raise ValueError(f"Langevin needs a positive timestep, got {timestep}")
        if kwargs.get("tol") is None and self._noisy():
            kwargs["tol"] = NOISY_TOL
        super().__init__(atoms, timestep, hbar=hbar, precession=precession,
                         gyromagnetic=gyromagnetic, order=order, trajectory=trajectory,
                         logfile=None, loginterval=loginterval, **kwargs)
        #: energy the lattice and spin baths put into the system so far (eV)
        self.bath_energy_lattice = 0.0
        self.bath_energy_spin = 0.0
        if logfile:
            logger = self.closelater(LangevinLogger(self, logfile))
            self.attach(logger, loginterval)

    # the bath parameters, checked whenever they are set (between runs too:
    # NaN or a negative value would switch a bath off without a word)

    @property
    def spin_damping(self):
        """λ ≥ 0, dimensionless. May be changed between runs: the precession
        rates r_i/(1+λ²) of the steps to come follow."""
        return self._spin_damping

    @spin_damping.setter
    def spin_damping(self, value):
        self._spin_damping = parameters.spin_damping(value)

    @property
    def fr(self):
        """γ ≥ 0, the lattice bath's friction in 1/(ASE time) (ASE's name)."""
        return self._friction

    @fr.setter
    def fr(self, value):
        self._friction = parameters.non_negative(value, "friction", "1/ASE time")

    def set_friction(self, friction):
        """New friction γ (1/(ASE time)) for the steps to come, as
        ``ase.md.langevin.Langevin.set_friction``."""
        self.fr = friction

    @property
    def temp(self):
        """k_B T of the lattice bath (eV), as ASE's Langevin."""
        return self._temp

    @temp.setter
    def temp(self, value):
        self._temp = parameters.kT(value, "temp (k_B T of the lattice bath)")

    @property
    def spin_temp(self):
        """k_B T_s of the spin bath (eV)."""
        return self._spin_temp

    @spin_temp.setter
    def spin_temp(self, value):
        self._spin_temp = parameters.kT(value, "spin_temp (k_B T of the spin bath)")

    def set_temperature(self, temperature_K, spin_temperature_K=None):
        """New bath temperatures (K) for the steps to come (spin bath: default
        the lattice's), as ``ase.md.langevin.Langevin.set_temperature``."""
        temp = parameters.temperature_K(temperature_K, "temperature_K") * units.kB
        spin = (temp if spin_temperature_K is None else units.kB
                * parameters.temperature_K(spin_temperature_K, "spin_temperature_K"))
        self.temp, self.spin_temp = temp, spin

    def todict(self):
        return {**super().todict(), "temperature_K": self.temp / units.kB,
                "spin_temperature_K": self.spin_temp / units.kB,
                "spin_damping": self.spin_damping, "friction": self.fr,
                "fixcm": self.fix_com}

    # -- set-up -------------------------------------------------------------------

    def _precession_rates(self, mu):
        """The collective step precesses at r_i/(1+λ²) (the Gilbert factor)."""
        return super()._precession_rates(mu) / (1.0 + self.spin_damping ** 2)

    def _prepare(self, st):
        super()._prepare(st)
        n = len(st.s)
        # the λ of st.rate's Gilbert factor: another λ set since lets the state go
        st.rate_damping = self.spin_damping
        st.EB = None  # _SpinFields at the current spins and q, if known
        # the spins x at the start of the last closing bath half, while the
        # spin energy it put in is not counted yet (see _closing_bath): the
        # next opening half counts it with its own, from E(y) − E(x); else None
        st.bath_from = None
        st.bath_pending = None  # that energy, once computed for a reader
        # the predictor's history of midpoint remainders W − W₀ (see _predict)
        st.increments = deque(maxlen=4)
        st.increment_order = 0
        st.remainder_spare = None  # a buffer for the next remainder
        st.s_start = st.s
        st.B_start = None  # the predictor's field at s_start (_opening_bath), if known
        st.B_next = None  # that field, from the bath before the collective step
        # the known part W₀ of the midpoint predicted from s_start (see _predict):
        # W − it is the remainder kept, without a second pass
        st.known = st.known_for = None
        st.bath_coefficients = {}
        st.s_before = np.zeros((n, 3))
        # the predictor's kick (see damp_from); the spins' next two buffers (a
        # bath keeps its start x for the energy, and writes y₀ and y apart)
        st.kick = np.zeros((n, 3))
        st.s_spare, st.s_spare2 = np.zeros((n, 3)), np.zeros((n, 3))
        st.p_spare = None
        st.no_damping = np.zeros(n)
        # B(y₀) of the last opening bath, kept for the field at the step's end
        # (see _closing_bath), and whether it is this step's with exchange the
        # only spin term
        st.B_y0 = None
        st.B_y0_fresh = False
        # this step's closing bath half begun with its end forces (see
        # _end_forces): (lattice key or None, the spins m after it, B(m), the
        # rng's state before their keys), or None
        st.early = None

    def _sync(self):
        """The base's, except that a state let go (the Atoms were changed)
        first counts the spin energy its last closing bath half put in."""
        st = self._state
        if self._in_sync() and st.rate_damping == self.spin_damping:
            return st
        if st is not None and st.bath_from is not None:
            self.bath_energy_spin += self._pending_bath_energy(st)
            st.bath_from = None
        self._state = None
        self._initialize()
        return self._state

    def _step(self, count=False, synced=False):
        # Every step is the same whatever observes the run or how it is cut
        # into runs: opening bath half, collective step, closing bath half, the
        # keys drawn in that order (lattice, spins; opening, closing). What
        # carries over to the next step (B at the output point, the energy the
        # closing half put in, the predictor's history) changes no bit of it.
        if not synced:  # (a state let go counts its bath energy here, see _sync)
            self._rebase_clock()
            self._sync()
        st = self._state
        self._consumed = None  # (q, m, x) of a pending bath energy the step took over
        saved = (self.bath_energy_lattice, self.bath_energy_spin,
                 self.rng.bit_generator.state)
        try:
            super()._step(count, synced=True)
        except BaseException:
            # the Atoms went back to the state before the step: so do the
            # bath energies and the random numbers; the energy of the closing
            # half before (not counted yet) is counted now
            self.bath_energy_lattice, self.bath_energy_spin = saved[:2]
            self.rng.bit_generator.state = saved[2]
            pending = self._consumed
            if pending is None and st is not None and st.bath_from is not None:
                pending = (st.q, st.s, st.bath_from)
                # counted here: the state may live on (an interrupt before the
                # step began), and must not count it again
                st.bath_from = st.bath_pending = None
            if pending is not None:
                try:
                    self.bath_energy_spin += self._spin_energy_change(*pending)
                except Exception:  # noqa: BLE001 - the step's own error is the one to see
                    pass
            raise
        finally:
            self._consumed = None

    def _substep(self, h, stage, want_energy):
        st = self._state
        if stage == 0:
            self._opening_bath()
        st.s_start = st.s
        st.B_start = st.B_next if stage == 0 else None
        st.B_next = None
        # the solve's midpoint fields give the field at the step's end when
        # exchange is the only spin term and the step has one stage (see
        # _closing_bath)
        field = None
        if self._end_field_from_midpoint and st.B_y0_fresh and len(self.gammas) == 1:
            field = self._midpoint_field_buffer()
        st.field_out = field
        st.field_filled = False
        st.early = None
        try:
            result = super()._substep(h, stage, want_energy)
        finally:
            st.field_out = None
        st.EB = None
        if stage == len(self.gammas) - 1:
            self._closing_bath(field if st.field_filled else None)
        return result

    def _end_forces(self, operators, W, s_new):
        r"""The step's end forces; with the field at the step's end from the
        midpoint (:meth:`_closing_bath`: ``field_out`` filled, exchange alone),
        also the closing bath half's spin move, which needs nothing the rest
        of the step computes: m = N(h/2) D(h/2) s̃ (:func:`bath_block`) and
        the fields B(m) at q̃, the positions the bath acts at, in the same
        pass over the pairs as the forces at (q̃, W)
        (:meth:`~ase_spin.terms.exchange.ExchangeOperator.forces_and_field`):
        one pass fewer. The keys are drawn as :meth:`_closing_bath` would
        (lattice, then spins): the same numbers, the same bits."""
        st = self._state
        op = operators[0] if len(operators) == 1 else None
        if not self._bath_begins_early(op):
            return super()._end_forces(operators, W, s_new)
        lattice_key, m, rng_state = self._begin_bath(s_new)
        F = st.FL.copy()
        Bm = np.zeros_like(s_new)
        op.forces_and_field(W, F, m, Bm)
        st.early = (lattice_key, m, Bm, rng_state)
        return F

    def _round_forces(self, W, s_new):
        """CollectivePRK's, with the closing bath's spin move (:meth:`_end_forces`)
        begun in the same pass too: the forces at (q, W) and at (q̃, W) and the
        fields B(m) at q̃, one pass over the pairs."""
        st = self._state
        ops, there = st.ops, st.ops_next
        here = ops[0] if len(ops) == 1 else None
        op = there[0] if len(there) == 1 else None
        if not (self._bath_begins_early(op) and here is not None and here.merges_forces
                and here.pairs_with(op)):
            return super()._round_forces(W, s_new)
        lattice_key, m, rng_state = self._begin_bath(s_new)
        F = st.FL.copy()
        Bm = np.zeros_like(s_new)
        keep = here.forces_here_and_there(W, F, op, u=m, field=Bm)
        return F, (keep, (lattice_key, m, Bm, rng_state))

    def _finish_round(self, pending):
        if len(pending) > 1:
            self._state.early = pending[1]
        return super()._finish_round(pending)

    def _drop_round(self, pending):
        if len(pending) > 1:  # the keys drawn for a bath begun too early: not drawn
            self.rng.bit_generator.state = pending[1][3]

    def step_policy(self):
        """CollectivePRK's, except with a bath on: then the step is not
        reversible and moves each spin by random angles of order √(2Dh) (≥ 1e-6
        in any run worth a bath), so a kick computed from a midpoint off by
        1e-12 stands (W settled to :data:`_SETTLED` instead of round-off, which
        cost a third outer iteration in most steps: the noise leaves the
        predictor far off), and q̃ within :data:`_SETTLED_Q` Å of the round
        before stands on the geometry prepared there (couplings off by
        ~J'·1e-10 eV, far below the noise: one geometry per step, where
        round-off took two)."""
        rules = super().step_policy()
        if self._spin_bath_on() or self.fr > 0.0:
            return rules._replace(settled_tol=max(rules.settled_tol, _SETTLED),
                                  qtol_floor=_SETTLED_Q)
        return rules

    def _predict(self, stage):
        """The midpoint spins predicted as W = W₀ + R, normalised: W₀ the midpoint
        of each spin alone in the field the bath left (:func:`_frozen_field_midpoint`
        with c = (h/2)σ r/(ħ(1+λ²)) and B(y₀) + C k, see :meth:`_opening_bath`),
        R extrapolated from the last steps' remainders W − W₀. The baths move
        the spins between steps by random amounts, which extrapolating W itself
        (as CollectivePRK does) would carry into the prediction.

        With noise, R moves like a random walk with a drift (each step's random
        moves shift it): R is predicted as the last remainder plus the mean of
        the last m ≤ 3 increments, R₀ + (R₀ − R_m)/m. A polynomial of order 0
        (the last R, the best guess for the random part) lags behind the
        drift, and a midpoint solve stopped at ``tol`` keeps part of that
        systematic miss: E_tot − E_bath then drifts (docs/thermostats.md);
        the mean slope has no lag, for √(1 + 1/m) times the random miss.
        Without noise (a smooth R), the polynomial order that predicted the
        last remainder best (as CollectivePRK's predictor)."""
        st = self._state
        history = st.increments
        if stage != 0 or not history or st.B_start is None:
            return super()._predict(stage)
        if self.spin_temp > 0.0:
            order = min(3, len(history) - 1)
            coef = _MEAN_SLOPE[order]
        else:
            order = min(st.increment_order, len(history) - 1)
            coef = kernels.LOW_ORDER_COEFFICIENTS[order]
        R = kernels.newest_first(history, order)[:4]  # beyond the order: the newest again
        # the mean slope uses R₀ and R_m only: the newest in the slots of zero
        # weight (its rows are in cache: two (n, 3) arrays fewer to read)
        R = tuple(r if w != 0.0 else R[0] for r, w in zip(R, coef))
        W = np.empty_like(st.s)
        if st.known is None or st.known.shape != W.shape:
            st.known = np.empty_like(W)
        predict_midpoint(st.s, st.B_start, self._coefficients()[2], *R, coef, W, st.known)
        st.known_for = st.s_start  # the explicit part of this start's midpoint is known
        return W

    def _remember_midpoint(self, stage, W):
        st = self._state
        if stage == 0 and st.B_start is not None and self._spin_bath_on():
            # stage 0 is predicted from the remainders below: CollectivePRK's
            # history of increments would cost a pass and 288 bytes per atom
            st.history[0].clear()
        else:
            super()._remember_midpoint(stage, W)
        if stage != 0:
            return
        history = st.increments
        if st.B_start is None or not self._spin_bath_on():
            history.clear()
            return
        R = st.remainder_spare
        if R is None or R.shape != W.shape:
            R = np.empty_like(W)
        st.remainder_spare = None
        if st.known_for is st.s_start:
            np.subtract(W, st.known, out=R)
        else:
            midpoint_remainder(W, st.s_start, st.B_start, self._coefficients()[2], R)
        st.known_for = None
        if history and not self.spin_temp > 0.0:  # (a noisy bath: see _predict)
            st.increment_order = kernels.best_extrapolation_order(history, R, st.probe)
        if len(history) == history.maxlen:  # the one that drops out: the next R's buffer
            st.remainder_spare = history.popleft()
        history.append(R)

    def get_bath_energy(self):
        """Energy the baths have put into the system since the start (eV):
        the sum of the energy changes of every bath half step."""
        pending = 0.0
        if self._state is not None:
            st = self._sync()
            if st.bath_from is not None:
                if st.bath_pending is None:
                    with threads.threads_for(len(self.atoms)):
                        st.bath_pending = self._pending_bath_energy(st)
                pending = st.bath_pending
        return self.bath_energy_lattice + self.bath_energy_spin + pending

    def get_conserved_energy(self):
        """E_tot − E_bath: constant but for the collective step's own (bounded)
        energy error."""
        return self.get_total_energy() - self.get_bath_energy()
