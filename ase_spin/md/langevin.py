"""Temperature control: spin and lattice Langevin dynamics around the collective step.

The deterministic (Hamiltonian) part of every step is :class:`CollectivePRK`'s
symplectic step, reused by inheritance; the baths act in two half steps around
it (an O–PRK–O splitting, docs/thermostats.md).
"""

from __future__ import annotations

from collections import deque

import numba as nb
import numpy as np
from ase import units

from ..hamiltonian import Want
from ..validate import flag, real_scalar
from .collective import CollectivePRK
from .logger import SpinMDLogger
from ..threads import threaded

__all__ = ["Langevin", "relax_spins", "LangevinLogger"]

_EB = Want(energy=True, magnetic_forces=True)
_E = Want(energy=True)


# -- compiled per-spin pieces of the spin bath ------------------------------------

@nb.njit(cache=True, inline="always")
def _normalise_row(s, i, x, y, z):
    n = np.sqrt(x * x + y * y + z * z)
    if n > 0.0:
        s[i, 0] = x / n
        s[i, 1] = y / n
        s[i, 2] = z / n


@threaded()
def damp(s, B, a_per_field, magnetic):
    r"""The exact solution of the damping flow about frozen fields, in place.

    ds_i/dt = κ_i [B_i − (s_i·B_i) s_i] (κ_i = λ r_i/ħ', ``a_per_field[i]`` =
    κ_i t) moves s_i along the great circle towards B̂_i with
    tan(θ/2) = tan(θ₀/2) e^{−a}, a = κ_i |B_i| t; in vector form

    .. math:: \mathbf s' \propto \mathbf s\,\mathrm{sech}\,a +
              [u_0 (1 - \mathrm{sech}\,a) + \tanh a]\,\hat{\mathbf b},
              \qquad u_0 = \mathbf s\cdot\hat{\mathbf b},

    normalised (the norm is 1 + u₀ tanh a; dividing by the computed norm keeps
    |s| at round-off).
    """
    for i in nb.prange(s.shape[0]):
        if not magnetic[i]:
            continue
        bx = B[i, 0]
        by = B[i, 1]
        bz = B[i, 2]
        b = np.sqrt(bx * bx + by * by + bz * bz)
        if b == 0.0:
            continue
        a = a_per_field[i] * b
        if a == 0.0:
            continue
        bx /= b
        by /= b
        bz /= b
        sx = s[i, 0]
        sy = s[i, 1]
        sz = s[i, 2]
        u0 = sx * bx + sy * by + sz * bz
        t = np.tanh(a)
        sech = 1.0 / np.cosh(a)
        # 1 − sech a = 2 sinh²(a/2) sech a, without cancellation for small a
        sh = np.sinh(0.5 * a)
        c = u0 * (2.0 * sh * sh * sech) + t
        _normalise_row(s, i, sx * sech + c * bx, sy * sech + c * by, sz * sech + c * bz)


@threaded()
def rotate(s, xi, amplitude, magnetic):
    """Rotate each s_i about the vector φ_i = ``amplitude[i]`` ξ_i by |φ_i|
    (Rodrigues), in place: s' = s cos φ + (n̂×s) sin φ + n̂ (n̂·s)(1 − cos φ)."""
    for i in nb.prange(s.shape[0]):
        if not magnetic[i]:
            continue
        c = amplitude[i]
        px = c * xi[i, 0]
        py = c * xi[i, 1]
        pz = c * xi[i, 2]
        phi = np.sqrt(px * px + py * py + pz * pz)
        if phi == 0.0:
            continue
        nx = px / phi
        ny = py / phi
        nz = pz / phi
        sx = s[i, 0]
        sy = s[i, 1]
        sz = s[i, 2]
        cp = np.cos(phi)
        sp = np.sin(phi)
        d = (nx * sx + ny * sy + nz * sz) * (1.0 - cp)
        _normalise_row(s, i,
                       sx * cp + (ny * sz - nz * sy) * sp + nx * d,
                       sy * cp + (nz * sx - nx * sz) * sp + ny * d,
                       sz * cp + (nx * sy - ny * sx) * sp + nz * d)


@nb.njit(cache=True)
def ornstein_uhlenbeck(p, xi, m, c1, c2, fix_com, out):
    """out = c1 p + c2 √m ξ (c2 = √((1 − c1²) k_B T)); with ``fix_com`` the
    change of the total momentum is taken off, mass-weighted. Returns the
    change of the kinetic energy."""
    n = p.shape[0]
    dP = np.zeros(3)
    M = 0.0
    for i in range(n):
        r = c2 * np.sqrt(m[i])
        M += m[i]
        for a in range(3):
            out[i, a] = c1 * p[i, a] + r * xi[i, a]
            dP[a] += out[i, a] - p[i, a]
    dK = 0.0
    for i in range(n):
        for a in range(3):
            if fix_com:
                out[i, a] -= m[i] * dP[a] / M
            dK += 0.5 * (out[i, a] * out[i, a] - p[i, a] * p[i, a]) / m[i]
    return dK


#: polynomial extrapolation to the next value from the last 1–4 (newest first)
_EXTRAPOLATION = ((1.0,), (2.0, -1.0), (3.0, -3.0, 1.0), (4.0, -6.0, 4.0, -1.0))


def _extrapolate_increment(history, order, rows=slice(None)):
    c = _EXTRAPOLATION[order]
    out = c[0] * history[-1][rows]
    for k in range(1, len(c)):
        out += c[k] * history[-1 - k][rows]
    return out


def _rng(rng):
    if rng is None or isinstance(rng, (int, np.integer)) and not isinstance(rng, bool):
        if rng is not None and rng < 0:
            raise ValueError(f"rng seed must be a non-negative integer, got {rng}")
        return np.random.default_rng(rng)
    if isinstance(rng, np.random.Generator):
        return rng
    raise TypeError("rng must be a numpy Generator (np.random.default_rng(seed)), an "
                    f"integer seed or None, got {type(rng).__name__}")


def _temperature(value, what):
    t = real_scalar(value, what)
    if t < 0.0:
        raise ValueError(f"{what} must be >= 0 K, got {t}")
    return t


def _non_negative(value, what, unit):
    x = real_scalar(value, what)
    if x < 0.0:
        raise ValueError(f"{what} must be >= 0 ({unit}), got {x}")
    return x


class Langevin(CollectivePRK):
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

    One step of size h (docs/thermostats.md):

    .. math:: O_s(h/2)\,O_L(h/2)\;\Phi^{\rm PRK}_h\;O_L(h/2)\,O_s(h/2)

    in time order O_s = D then N before, N then D after (a symmetric step,
    whose end point — after D — samples the Boltzmann distribution far better
    than a point after N);
    Φ^PRK is :class:`CollectivePRK`'s step with the precession rates
    r_i/(1+λ²) (any ``order``: its composition stages all sit inside);
    O_L(τ): p ← e^{−γτ} p + √(1−e^{−2γτ}) √(m k_B T) ξ (exact
    Ornstein–Uhlenbeck, as ASE's Langevin); D(τ): the exact damping flow about
    the fields B(s) frozen at its start (:func:`damp`); N(τ): each spin rotated
    by the Gaussian rotation vector √(2 D_i τ) ξ_i (:func:`rotate`). Every
    spin update is a rotation: |s_i| stays 1 to round-off.

    Parameters
    ----------
    atoms, timestep
        As for :class:`CollectivePRK`; the timestep must be positive.
    temperature_K : float
        Lattice bath temperature (K).
    spin_damping : float
        λ ≥ 0, dimensionless; 0: spins without bath (their NVE precession).
    friction : float
        γ ≥ 0 in 1/(ASE time), as ``ase.md.langevin.Langevin`` (e.g.
        ``0.01 / units.fs``); 0: lattice without bath.
    spin_temperature_K : float, optional
        Spin bath temperature (K); default ``temperature_K``.
    fixcm : bool
        Keep the total momentum as it is (the random and friction forces'
        sum is taken off, mass-weighted), as ASE's ``fixcm``.
    rng : numpy Generator, int seed or None
        The random numbers; a run is reproduced by restoring
        ``dyn.rng.bit_generator.state`` (see docs/thermostats.md).
    hbar, precession, gyromagnetic, g, order, tol, max_iter, lattice, trajectory,
    logfile, loginterval, **kwargs
        As for :class:`CollectivePRK`. The log adds the energy the baths put
        in (Ebath) and the conserved Etot − Ebath: :class:`LangevinLogger`.
    """

    def __init__(self, atoms, timestep, temperature_K, *, spin_damping, friction,
                 spin_temperature_K=None, hbar=None, precession="moment",
                 gyromagnetic="lammps", order=2, fixcm=True, rng=None, trajectory=None,
                 logfile=None, loginterval=1, **kwargs):
        self.temp = _temperature(temperature_K, "temperature_K") * units.kB
        self.spin_temp = (self.temp if spin_temperature_K is None else
                          _temperature(spin_temperature_K, "spin_temperature_K") * units.kB)
        self.spin_damping = _non_negative(spin_damping, "spin_damping", "dimensionless")
        self.fr = _non_negative(friction, "friction", "1/ASE time")
        self.fix_com = flag(fixcm, "fixcm")
        self.rng = _rng(rng)
        if not real_scalar(timestep, "timestep") > 0.0:
            raise ValueError(f"Langevin needs a positive timestep, got {timestep}")
        super().__init__(atoms, timestep, hbar=hbar, precession=precession,
                         gyromagnetic=gyromagnetic, order=order, trajectory=trajectory,
                         logfile=None, loginterval=loginterval, **kwargs)
        #: energy the lattice and spin baths put into the system so far (eV)
        self.bath_energy_lattice = 0.0
        self.bath_energy_spin = 0.0
        if logfile:
            logger = self.closelater(LangevinLogger(self, logfile))
            self.attach(logger, loginterval)

    def set_temperature(self, temperature_K, spin_temperature_K=None):
        """New bath temperatures (K) for the steps to come (spin bath: default
        the lattice's), as ``ase.md.langevin.Langevin.set_temperature``."""
        temp = _temperature(temperature_K, "temperature_K") * units.kB
        spin = (temp if spin_temperature_K is None else
                _temperature(spin_temperature_K, "spin_temperature_K") * units.kB)
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
        st.EB = None  # (spin energy, fields) at the current spins and q, if known
        # the predictor's history of midpoint increments W − s, per stage
        st.increments = [deque(maxlen=4) for _ in self.gammas]
        st.increment_order = [0 for _ in self.gammas]
        st.s_start = st.s
        st.B_start = None  # fields at s_start (from the bath's last pass), if known
        st.bath_coefficients = {}  # per half-step size: κ_i τ, √(2 D_i τ)

    # -- the step -------------------------------------------------------------------

    def _step(self, count=False):
        saved = (self.bath_energy_lattice, self.bath_energy_spin,
                 self.rng.bit_generator.state)
        try:
            super()._step(count)
        except BaseException:
            # the Atoms went back to the state before the step: so do the
            # bath energies and the random numbers
            self.bath_energy_lattice, self.bath_energy_spin = saved[:2]
            self.rng.bit_generator.state = saved[2]
            raise

    def _substep(self, h, stage, want_energy):
        half = 0.5 * self.dt
        st = self._state
        if stage == 0:
            self._spin_bath(half, first=True)
            self._lattice_bath(half)
        st.s_start = st.s
        st.B_start = st.EB[1] if stage == 0 and st.EB is not None else None
        result = super()._substep(h, stage, want_energy)
        st.EB = None
        if stage == len(self.gammas) - 1:
            self._lattice_bath(half)
            self._spin_bath(half, first=False)
        return result

    def _predict(self, stage):
        """The midpoint spins predicted as W = s + (h/2) c s × B(s) + R, R
        extrapolated from the last steps' remainders: the baths move the spins
        between steps by random amounts, which extrapolating W itself (as
        CollectivePRK does) would carry into the prediction."""
        st = self._state
        history = st.increments[stage]
        if stage != 0 or not history or st.B_start is None:
            return super()._predict(stage)
        W = st.s + self._explicit_half_step(st.s, st.B_start)
        W += _extrapolate_increment(history, st.increment_order[stage])
        norm = np.sqrt(np.einsum("ij,ij->i", W, W))
        np.divide(W, norm[:, None], out=W, where=norm[:, None] > 0.0)
        return W

    def _explicit_half_step(self, s, B):
        c = (0.5 * self.gammas[0] * self.dt * self.sigma / self.hbar) * self._state.rate
        return c[:, None] * np.cross(s, B)

    def _remember_midpoint(self, stage, W):
        super()._remember_midpoint(stage, W)
        st = self._state
        if stage != 0:
            return
        history = st.increments[stage]
        if st.B_start is None:
            history.clear()
            return
        R = W - st.s_start - self._explicit_half_step(st.s_start, st.B_start)
        if history:
            rows = st.probe
            errors = [np.abs(_extrapolate_increment(history, k, rows) - R[rows]).max()
                      for k in range(min(len(history), 4))]
            st.increment_order[stage] = int(np.argmin(errors))
        history.append(R)

    def _spin_bath(self, tau, first):
        """O_s(τ): D(τ) then N(τ) (``first``), or N(τ) then D(τ); adds its energy
        change to ``bath_energy_spin``."""
        st = self._state
        if not self.magnetic or self.spin_damping == 0.0:
            return
        noisy = self.spin_temp > 0.0
        if st.EB is None:  # the fields are needed now if D comes first (or N is idle)
            st.EB = self._spin_energy_fields(fields=first or not noisy)
        E0, B = st.EB
        key = (tau, self.spin_damping, self.spin_temp)  # the user may change them
        coef = st.bath_coefficients.get(key)
        if coef is None:  # κ_i τ and the noise amplitude √(2 D_i τ), D_i = κ_i k_B T_s
            kappa_tau = (self.spin_damping * tau / self.hbar) * st.rate
            if len(st.bath_coefficients) > 8:
                st.bath_coefficients.clear()
            coef = st.bath_coefficients[key] = (kappa_tau,
                                                np.sqrt(2.0 * self.spin_temp * kappa_tau))
        mag = self.ev.magnetic
        if first:
            damp(st.s, B, coef[0], mag)
        if noisy:
            rotate(st.s, self.rng.standard_normal(st.s.shape), coef[1], mag)
        if not first:
            damp(st.s, self._spin_energy_fields()[1] if noisy else B, coef[0], mag)
        st.carry_s[:] = 0.0  # the spins were replaced: no rounding error to carry
        # energy and fields: the fields serve the next D, or the predictor
        st.EB = self._spin_energy_fields()
        self.bath_energy_spin += st.EB[0] - E0

    def _spin_energy_fields(self, fields=True):
        """(spin energy, fields or None) at the current spins: one pass."""
        st = self._state
        if not fields:
            res = self.ev.spin(st.ops, st.s, _E)
            return float(sum(res.energy_terms.values())), None
        B = np.zeros_like(st.s)
        res = self.ev.spin(st.ops, st.s, _EB, magnetic_forces=B)
        return float(sum(res.energy_terms.values())), B

    def _lattice_bath(self, tau):
        """O_L(τ): the exact Ornstein–Uhlenbeck step of the momenta; adds the
        kinetic-energy change to ``bath_energy_lattice``."""
        st = self._state
        if self.fr == 0.0 or self.frozen:
            return
        c1 = np.exp(-self.fr * tau)
        c2 = np.sqrt(-np.expm1(-2.0 * self.fr * tau) * self.temp)
        xi = self.rng.standard_normal(st.p.shape)
        p = np.empty_like(st.p)
        m = self.masses[:, 0]
        dK = ornstein_uhlenbeck(st.p, xi, m, c1, c2, self.fix_com, p)
        if self.atoms.constraints:
            K0 = 0.5 * float(np.einsum("ij,ij->", st.p, st.p / self.masses))
            p = self._adjust_momenta(p, st.q)
            dK = 0.5 * float(np.einsum("ij,ij->", p, p / self.masses)) - K0
        self.bath_energy_lattice += dK
        st.p = p
        st.carry_p[:] = 0.0

    # -- observables -----------------------------------------------------------------

    def get_bath_energy(self):
        """Energy the baths have put into the system since the start (eV):
        the sum of the energy changes of every bath half step."""
        return self.bath_energy_lattice + self.bath_energy_spin

    def get_conserved_energy(self):
        """E_tot − E_bath: constant but for the collective step's own (bounded)
        energy error."""
        return self.get_total_energy() - self.get_bath_energy()


class LangevinLogger(SpinMDLogger):
    """:class:`SpinMDLogger`'s line (time, energies, T, |M|, Ts — LAMMPS
    ``compute spin``'s estimator, meaningful only near equilibrium — and
    sweeps) followed by Ebath, the energy the baths put in since the start, and
    Econs = Etot − Ebath (eV)."""

    def __init__(self, dyn, logfile, header=True, mode="a", **kwargs):
        super().__init__(dyn, logfile, header=False, mode=mode, **kwargs)
        n = len(dyn.atoms)
        digits = 4 if n <= 100 else 3 if n <= 1000 else 2 if n <= 10000 else 1
        self.hdr += " %13s %13s" % ("Ebath[eV]", "Econs[eV]")
        self.fmt = self.fmt[:-1] + f" %13.{digits}f %13.{digits}f\n"
        if header:
            self.logfile.write(self.hdr + "\n")

    def __call__(self):
        dyn = self.dyn
        epot = dyn.get_potential_energy()
        ekin = dyn.get_kinetic_energy()
        m = dyn.get_magnetization()
        bath = dyn.get_bath_energy()
        self.logfile.write(self.fmt % (
            dyn.get_time() / (1000 * units.fs), epot + ekin, epot, ekin,
            dyn.get_magnetic_energy(), dyn.get_temperature(), float((m @ m) ** 0.5),
            dyn.get_spin_temperature(), dyn.iterations, bath, epot + ekin - bath))
        self.logfile.flush()


def relax_spins(atoms, *, fmax=1e-6, damping=1.0, timestep=None, steps=100_000,
                hbar=None, gyromagnetic="lammps", **kwargs):
    r"""Relax the spins to a (local) minimum of the energy at fixed positions:
    zero-temperature damped Landau–Lifshitz–Gilbert dynamics (:class:`Langevin`
    with T_s = 0, frozen lattice), the damped-precession path of each spin
    towards its field, until every torque |s_i × B_i| ≤ ``fmax`` (eV).

    ``damping``: λ (1 is the fastest relaxation of a spin in a fixed field);
    ``timestep``: default 0.2 ħ(1+λ²)/(r_max |B|_max) from the initial fields.
    The spins are written back to ``atoms``; positions and momenta are not
    touched. Returns the number of steps taken; raises RuntimeError (the
    Atoms keep their spins from before the call) if ``fmax`` is not reached
    in ``steps`` steps.
    """
    fmax = _non_negative(fmax, "fmax", "eV")
    damping = real_scalar(damping, "damping")
    if not damping > 0.0:
        raise ValueError(f"damping must be > 0 to relax spins, got {damping}")
    before = atoms.arrays.get("initial_magmoms")
    before = None if before is None else before.copy()
    dyn = None
    try:
        if timestep is None:
            probe = Langevin(atoms, 1.0, 0.0, spin_damping=damping, friction=0.0,
                             hbar=hbar, gyromagnetic=gyromagnetic, lattice="frozen",
                             **kwargs)
            B = probe.get_magnetic_forces()
            probe._sync()
            field = float((np.linalg.norm(B, axis=1) * probe._state.rate).max(initial=0.0))
            if field == 0.0:
                return 0
            timestep = 0.2 * probe.hbar / field
        dyn = Langevin(atoms, timestep, 0.0, spin_damping=damping, friction=0.0,
                       hbar=hbar, gyromagnetic=gyromagnetic, lattice="frozen", **kwargs)
        for n in range(steps + 1):
            B = dyn.get_magnetic_forces()
            s = dyn._state.s
            torque = np.linalg.norm(np.cross(s, B), axis=1)
            if float(torque.max(initial=0.0)) <= fmax:
                return n
            if n < steps:
                dyn.step()
        raise RuntimeError(f"relax_spins: largest torque {float(torque.max()):.3g} eV "
                           f"> fmax = {fmax:g} eV after {steps} steps; raise steps or "
                           "damping. The spins are as they were before the call.")
    except BaseException:
        if before is None:
            atoms.arrays.pop("initial_magmoms", None)
        else:
            atoms.arrays["initial_magmoms"] = before
        raise
