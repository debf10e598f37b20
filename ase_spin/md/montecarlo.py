r"""Monte Carlo for the spins on a frozen lattice: Metropolis moves in an
adaptive cone, optionally with over-relaxation, for any of the package's spin
terms through the term contract.

**The exact energy change of a move, whatever the terms.** Anisotropies and
the biquadratic exchange are not linear in s_i, so −B_i·Δs_i is not the
energy change of a move. What the contract does give for any spins is each
operator's energy per atom (``SpinOperator.add`` with
``Want(energies=True)``): a pair term puts half of every pair's energy on
each of its two atoms (LAMMPS's per-atom energy), a term without pairs
(``Term.neighbor_list`` None: fields, anisotropies) its whole site energy on
the atom. The spins are split into colours, no two atoms of one colour within
the reach of any spin term (the greedy colouring of the full pair list,
:meth:`~ase_spin.neighbors.pairs.PairList.colours`). With every spin of one
colour moved at once to a trial direction, the energy is a sum of one
function per moved spin (they do not interact), and the change that moving
spin i *alone* would make is

.. math:: \Delta E_i = 2\,\Delta\varepsilon_i^{\rm pair} + \Delta\varepsilon_i^{\rm site},

ε_i the energies per atom of the pair terms and of the site terms, before
and after: each pair (i, j) changes only through s_i, and its change is
shared equally between ε_i and ε_j. Each ΔE_i is then accepted or rejected on
its own (Metropolis, probability min(1, e^{−ΔE_i/k_BT})), exactly as moves one
spin at a time in colour order would be. Two passes of the operators per
colour, no knowledge of any term's internals, nothing approximate. Each
colour also checks Σ_i ΔE_i = Σ_k Δε_k over all atoms (both sides the exact
total change if the terms are local on the pair list): a term coupling spins
of one colour (the long-range ``Dipolar`` methods "direct" and "ewald", a
pair with an atom's own periodic image that depends on its direction) breaks
it, and is refused with an error rather than sampled wrongly.

**Moves.** A trial direction is drawn uniformly in the cone of half-angle θ
about s_i (a symmetric proposal; θ = π: uniform on the sphere). θ adapts
during the first ``adapt_sweeps`` sweeps after the start or a change of
temperature, towards the acceptance rate ``acceptance`` (0.5), and is then
held fixed, so that the chain measured is a time-homogeneous Metropolis chain
(detailed balance holds exactly). ``overrelaxation=k`` adds k sweeps of
reflections s_i → 2(s_i·B̂_i)B̂_i − s_i about the local field B_i per
Metropolis sweep: energy-conserving and always accepted when the energy is
linear in each spin (exchange, DMI, Zeeman: the field on s_i does not depend
on s_i), which decorrelates the Heisenberg model near T_C far faster than
Metropolis alone; refused for terms for which it does not conserve the
energy (anisotropies, biquadratic exchange; checked on its first sweep).

**Cost.** A sweep is two passes of every spin operator (its energies per
atom) per colour (2 colours for simple cubic, 4 for fcc with nearest
neighbours), plus one field pass per colour and reflection sweep; the trial
moves and the accept/reject of a colour are one compiled call each. Random
numbers come from a numpy ``Generator`` (``seed``): a run is reproducible.
"""

from __future__ import annotations

import numba as nb
import numpy as np
from ase import units
from ase.optimize.optimize import Dynamics
from ase.utils import IOContext

from .._jit import threads
from .._jit.threads import AdaptiveThreads
from ..calculator import SpinLatticeCalculator
from ..constraints import pinned_spins
from ..spins import split_moments
from ..terms.base import Want
from ..validate import flag, integer, positive_scalar, real_scalar

__all__ = ["MonteCarlo", "MonteCarloLogger"]

_ENERGIES = Want(energies=True)
_ENERGY = Want(energy=True)
_NONE3 = np.zeros((0, 3))
#: relative round-off allowed in Σ_i ΔE_i = Σ_k Δε_k (sums of per-atom energies)
_LOCALITY_TOL = 1e-9
#: smallest cone half-angle the adaptation goes to (rad)
_MIN_CONE = 1e-3


@nb.njit(cache=True)
def cone_trials(s, atoms, cos_max, u, trial):
    """``trial[a]`` = a unit vector drawn uniformly in the cone of half-angle
    θ (cos θ = ``cos_max``) about ``s[atoms[a]]``, from the uniform numbers
    ``u[a, 0]`` (cos of the angle: 1 − u(1 − cos θ), uniform in solid angle)
    and ``u[a, 1]`` (azimuth)."""
    for a in range(atoms.shape[0]):
        i = atoms[a]
        x, y, z = s[i, 0], s[i, 1], s[i, 2]
        # a unit vector t1 ⊥ s from the coordinate axis least aligned with s
        ax, ay, az = abs(x), abs(y), abs(z)
        if ax <= ay and ax <= az:
            t1x, t1y, t1z = 0.0, -z, y
        elif ay <= az:
            t1x, t1y, t1z = z, 0.0, -x
        else:
            t1x, t1y, t1z = -y, x, 0.0
        norm = np.sqrt(t1x * t1x + t1y * t1y + t1z * t1z)
        t1x, t1y, t1z = t1x / norm, t1y / norm, t1z / norm
        t2x, t2y, t2z = y * t1z - z * t1y, z * t1x - x * t1z, x * t1y - y * t1x
        c = 1.0 - u[a, 0] * (1.0 - cos_max)
        sn = np.sqrt(max(0.0, 1.0 - c * c))
        phi = 2.0 * np.pi * u[a, 1]
        cp, sp = np.cos(phi), np.sin(phi)
        vx = c * x + sn * (cp * t1x + sp * t2x)
        vy = c * y + sn * (cp * t1y + sp * t2y)
        vz = c * z + sn * (cp * t1z + sp * t2z)
        r = np.sqrt(vx * vx + vy * vy + vz * vz)
        trial[i, 0] = vx / r
        trial[i, 1] = vy / r
        trial[i, 2] = vz / r


@nb.njit(cache=True)
def metropolis_accept(s, trial, atoms, dE, beta, u):
    """Metropolis: ``s[i] = trial[i]`` for the atoms of ``atoms`` with
    u < exp(−β ΔE_i) (ΔE_i = ``dE[a]``); ``trial[i] = s[i]`` for the others,
    so that ``trial`` equals ``s`` afterwards. Returns (accepted, their ΔE)."""
    accepted = 0
    change = 0.0
    for a in range(atoms.shape[0]):
        i = atoms[a]
        if dE[a] <= 0.0 or u[a] < np.exp(-beta * dE[a]):
            s[i, 0] = trial[i, 0]
            s[i, 1] = trial[i, 1]
            s[i, 2] = trial[i, 2]
            accepted += 1
            change += dE[a]
        else:
            trial[i, 0] = s[i, 0]
            trial[i, 1] = s[i, 1]
            trial[i, 2] = s[i, 2]
    return accepted, change


@nb.njit(cache=True)
def reflect(s, B, atoms):
    """Over-relaxation: s_i → 2(s_i·B̂_i)B̂_i − s_i for the atoms of
    ``atoms`` with B_i ≠ 0, renormalised (round-off)."""
    for a in range(atoms.shape[0]):
        i = atoms[a]
        b2 = B[i, 0] * B[i, 0] + B[i, 1] * B[i, 1] + B[i, 2] * B[i, 2]
        if b2 == 0.0:
            continue
        c = 2.0 * (s[i, 0] * B[i, 0] + s[i, 1] * B[i, 1] + s[i, 2] * B[i, 2]) / b2
        x = c * B[i, 0] - s[i, 0]
        y = c * B[i, 1] - s[i, 1]
        z = c * B[i, 2] - s[i, 2]
        r = np.sqrt(x * x + y * y + z * z)
        s[i, 0] = x / r
        s[i, 1] = y / r
        s[i, 2] = z / r


class MonteCarlo(Dynamics):
    """Metropolis Monte Carlo of the spins at ``temperature_K`` on the frozen
    lattice of ``atoms`` (``atoms.calc`` an ase_spin
    :class:`~ase_spin.SpinLatticeCalculator`; the module docstring says how
    the energy change of a move is computed exactly for any terms).

    ``mc.run(sweeps)``: one step is one sweep (every free spin offered one
    move, colour by colour); observers attached with ``mc.attach(f,
    interval=k)`` run every k sweeps and find the spins written into
    ``atoms``; ``logfile``/``loginterval`` write a line (sweep, magnetic
    energy, |M|, acceptance, cone angle) and ``trajectory`` frames, as ASE's
    dynamics do.

    Parameters: ``seed`` (an int, None or a numpy ``Generator``: the
    stream of every random number), ``cone_angle`` (rad, the starting
    half-angle, default 1), ``acceptance`` (the rate the cone adapts to,
    0.5), ``adapt_sweeps`` (sweeps of adaptation after the start and after
    :meth:`set_temperature`, 100; 0: θ fixed), ``overrelaxation`` (reflection
    sweeps per Metropolis sweep, 0), ``threads`` (as the integrators': "auto",
    or a whole number). Spins pinned by
    :class:`~ase_spin.FixSpins` are not moved; non-magnetic atoms have none.
    """

    def __init__(self, atoms, temperature_K, *, seed=None, cone_angle=1.0, acceptance=0.5,
                 adapt_sweeps=100, overrelaxation=0, threads=None, logfile=None,
                 loginterval=1, trajectory=None, append_trajectory=False):
        if not isinstance(getattr(atoms, "calc", None), SpinLatticeCalculator):
            raise TypeError("MonteCarlo needs atoms.calc to be an ase_spin "
                            f"SpinLatticeCalculator, got {type(atoms.calc).__name__}")
        cone = real_scalar(cone_angle, "cone_angle")
        if not 0.0 < cone <= np.pi:
            raise ValueError(f"cone_angle must be in (0, π] rad, got {cone}")
        target = real_scalar(acceptance, "acceptance")
        if not 0.0 < target < 1.0:
            raise ValueError(f"acceptance must be between 0 and 1, got {target}")
        self.cone_angle = cone
        self.target_acceptance = target
        self.adapt_sweeps = integer(adapt_sweeps, "adapt_sweeps", 0)
        self.overrelaxation = integer(overrelaxation, "overrelaxation", 0)
        #: threads of the sweeps: all or one, whichever is faster now ("auto"), as
        #: the integrators choose them (:class:`~ase_spin._jit.threads.AdaptiveThreads`)
        self.threads = AdaptiveThreads(threads)
        flag(append_trajectory, "append_trajectory")
        if isinstance(seed, np.random.Generator):
            self.rng = seed
        elif seed is None or (isinstance(seed, (int, np.integer)) and not isinstance(seed, bool)):
            self.rng = np.random.default_rng(seed)
        else:
            raise TypeError(f"seed must be an integer, None or a numpy Generator, got "
                            f"{type(seed).__name__} {seed!r:.40}")
        super().__init__(atoms, logfile=None, trajectory=trajectory,
                         append_trajectory=append_trajectory, loginterval=loginterval)
        self.set_temperature(temperature_K)
        #: acceptance rate of the last sweep, and accepted/offered moves so far
        self.acceptance = float("nan")
        self.accepted = 0
        self.offered = 0
        self._state = None
        self._written = None
        if logfile:
            self.attach(self.closelater(MonteCarloLogger(self, logfile)), loginterval)

    # -- parameters -----------------------------------------------------------
    def set_temperature(self, temperature_K):
        """A new temperature (K) for the sweeps to come; the cone adapts again
        for ``adapt_sweeps`` sweeps."""
        t = positive_scalar(temperature_K, "temperature_K")
        if not np.isfinite(t):
            raise ValueError(f"temperature_K must be finite, got {t}")
        #: k_B T (eV); ``spin_temp`` as ase_spin.Langevin names its spin bath's
        self.temp = self.spin_temp = t * units.kB
        self._adapt_until = getattr(self, "nsteps", 0) + self.adapt_sweeps

    @property
    def temperature_K(self):
        return self.temp / units.kB

    def todict(self):
        return {"type": "monte-carlo", "temperature_K": self.temperature_K,
                "cone_angle": self.cone_angle, "acceptance": self.target_acceptance,
                "overrelaxation": self.overrelaxation}

    # -- state ------------------------------------------------------------------
    def _initialize(self):
        """Read the spins and the frozen lattice from the Atoms; prepare every
        spin operator once (full pair lists) and the colours."""
        atoms = self.atoms
        calc = atoms.calc
        if not isinstance(calc, SpinLatticeCalculator):
            raise TypeError("MonteCarlo needs atoms.calc to be an ase_spin "
                            f"SpinLatticeCalculator, got {type(calc).__name__}")
        ev, moments = calc.bound_evaluator(atoms)
        spins, mu = split_moments(moments)
        hamiltonian = ev.hamiltonian
        q = np.ascontiguousarray(atoms.positions, dtype=float)
        magnetic = ev.magnetic.copy()
        movable = magnetic.copy()
        pinned = pinned_spins(atoms)
        if pinned is not None:
            movable &= ~pinned
        spin_terms = hamiltonian.spin_terms if ev.any_magnetic else []
        with threads.threads_for(len(atoms)):
            ops = ev.spin_operators(q) if spin_terms else []
        pair_term = np.array([bool(t.neighbor_list) for t in spin_terms], dtype=bool)
        reach = max((t.cutoff for t in spin_terms if t.neighbor_list), default=0.0)
        if reach > 0.0 and ev.neighbors is not None:
            order, starts = ev.neighbors.sublist(reach, magnetic, half=False).colours()
            colours = [order[starts[c]:starts[c + 1]] for c in range(len(starts) - 1)]
        else:
            colours = [np.arange(len(atoms))]
        colours = [np.ascontiguousarray(c[movable[c]], dtype=np.int64) for c in colours]
        colours = [c for c in colours if len(c)]
        self.ev = ev
        self._state = {"s": np.ascontiguousarray(spins), "mu": mu, "q": q, "ops": ops,
                       "pair_term": pair_term, "colours": colours, "magnetic": magnetic,
                       "EL": None, "energy": None, "checked_reflection": False,
                       "moved": False}
        self._remember()

    def _remember(self):
        a = self.atoms
        self._written = (a.positions.copy(), a.arrays["initial_magmoms"].copy()
                         if "initial_magmoms" in a.arrays else None,
                         a.cell.array.copy(), a.pbc.copy(), a.numbers.copy(), len(a.constraints),
                         a.calc)

    def _in_sync(self):
        if self._state is None or self._written is None:
            return False
        a = self.atoms
        pos, mag, cell, pbc, numbers, nconstraints, calc = self._written
        m = a.arrays.get("initial_magmoms")
        return (a.calc is calc and len(a) == len(pos) and np.array_equal(a.positions, pos)
                and mag is not None and m is not None and np.array_equal(m, mag)
                and np.array_equal(a.cell.array, cell) and np.array_equal(a.pbc, pbc)
                and np.array_equal(a.numbers, numbers) and len(a.constraints) == nconstraints
                and not self.ev.stale())

    def _sync(self):
        if not self._in_sync():
            self._initialize()
        return self._state

    def _write_back(self):
        st = self._state
        if st is None or not st["moved"]:
            return  # the Atoms hold this state already (as the user gave it)
        self.atoms.arrays["initial_magmoms"] = st["mu"][:, None] * st["s"]
        st["moved"] = False
        self._remember()

    # -- energies ---------------------------------------------------------------
    def _site_energies(self, W):
        """(ε^pair, ε^site): the energies per atom (eV) of the pair terms and of
        the terms without pairs at unit spins W."""
        st = self._state
        n = len(W)
        pair, site = np.zeros(n), np.zeros(n)
        for op, is_pair in zip(st["ops"], st["pair_term"]):
            op.add(W, _ENERGIES, _NONE3, _NONE3, pair if is_pair else site)
        return pair, site

    def energy_changes(self, trial, colour):
        """ΔE_i (eV) of moving each spin i of colour ``colour`` (index into
        the colours) alone from its current direction to ``trial[i]``, all
        computed from one pair of passes (module docstring); ``trial`` equals
        the current spins elsewhere. ValueError if the terms are not local on
        the colouring (the check Σ_i ΔE_i = Σ_k Δε_k)."""
        st = self._sync()
        atoms = st["colours"][colour]
        with threads.threads_for(len(trial)):
            return self._energy_changes(st["s"], np.ascontiguousarray(trial, dtype=float),
                                        atoms)

    def _energy_changes(self, s, trial, atoms):
        p0, s0 = self._site_energies(s)
        p1, s1 = self._site_energies(trial)
        dp = p1 - p0
        ds = s1 - s0
        dE = 2.0 * dp[atoms] + ds[atoms]
        total = dp.sum() + ds.sum()
        scale = np.abs(p0).sum() + np.abs(p1).sum() + np.abs(s0).sum() + np.abs(s1).sum()
        if abs(dE.sum() - total) > _LOCALITY_TOL * scale + 1e-300:
            names = [type(t).__name__ for t in self.ev.hamiltonian.spin_terms]
            raise ValueError(
                "Monte Carlo needs spin terms whose energy is local on their pair list "
                f"(spins of one colour must not interact); the terms {names} couple "
                "them: a long-range Dipolar (method 'direct' or 'ewald'), or a cell so "
                "small that an atom is its own neighbour (repeat the cell)")
        return dE

    # -- the sweep --------------------------------------------------------------
    def step(self):
        """One sweep (Metropolis over every colour, then the reflection sweeps)."""
        st = self._sync()
        try:
            with self.threads.step(len(self.atoms)):
                self._sweep(st)
        except BaseException:
            # a sweep is whole or not at all: the spins are read again from
            # the Atoms, which hold the state before it
            self._state = None
            raise
        st["moved"] = True

    def _sweep(self, st):
        s = st["s"]
        trial = s.copy()
        beta = 1.0 / self.temp
        cos_max = np.cos(self.cone_angle)
        accepted = offered = 0
        for atoms in st["colours"]:
            u = self.rng.random((len(atoms), 3))
            cone_trials(s, atoms, cos_max, u, trial)
            dE = self._energy_changes(s, trial, atoms)
            acc, _ = metropolis_accept(s, trial, atoms, dE, beta, u[:, 2])
            accepted += acc
            offered += len(atoms)
        for _ in range(self.overrelaxation):
            self._reflection_sweep(st)
        st["energy"] = None
        self.accepted += accepted
        self.offered += offered
        self.acceptance = accepted / offered if offered else float("nan")
        if self.nsteps < self._adapt_until and offered:
            # multiplicative steps towards the target rate while adapting
            self.cone_angle = float(np.clip(
                self.cone_angle * np.exp(self.acceptance - self.target_acceptance),
                _MIN_CONE, np.pi))

    def _reflection_sweep(self, st):
        s = st["s"]
        check = not st["checked_reflection"]
        e0 = self._magnetic_energy(s) if check else 0.0
        B = np.zeros_like(s)
        for atoms in st["colours"]:
            B[:] = 0.0
            for op in st["ops"]:
                op.field(s, B)
            reflect(s, B, atoms)
        if check:
            e1 = self._magnetic_energy(s)
            scale = max(abs(e0), abs(e1), 1e-300)
            if abs(e1 - e0) > 1e-9 * scale * max(1, len(s)) ** 0.5:
                names = [type(t).__name__ for t in self.ev.hamiltonian.spin_terms]
                raise ValueError(
                    f"overrelaxation changed the energy by {e1 - e0:.3g} eV: reflections "
                    "about the local field conserve it only for terms linear in each spin "
                    f"(exchange, DMI, Zeeman); the terms here are {names}: use "
                    "overrelaxation=0")
            st["checked_reflection"] = True

    def _magnetic_energy(self, s):
        return float(sum(op.add(s, _ENERGY, _NONE3, _NONE3, np.zeros(0))[0]
                         for op in self._state["ops"]))

    # -- the run ----------------------------------------------------------------
    def irun(self, steps=100):
        """ASE's ``irun``: ``steps`` sweeps, observers called after the sweeps
        they are due at (with the spins written into the Atoms first), the
        Atoms written after the last."""
        steps = integer(steps, "sweeps", 0)
        self._sync()
        self.max_steps = self.nsteps + steps
        if self.nsteps == 0:
            self.call_observers()
        yield self.nsteps >= self.max_steps
        while self.nsteps < self.max_steps:
            self.step()
            self.nsteps += 1
            if self._observer_due() or self.nsteps == self.max_steps:
                self._write_back()
                self.call_observers()
            yield self.nsteps >= self.max_steps

    def run(self, steps=100):
        """``steps`` sweeps (see :meth:`irun`)."""
        for _ in self.irun(steps):
            pass
        return True

    def call_observers(self):
        self._write_back()
        super().call_observers()

    def _observer_due(self):
        n = self.nsteps
        return any((interval > 0 and n % interval == 0) or (interval <= 0 and n == -interval)
                   for _, interval, _, _ in self.observers)

    def log(self, *args, **kwargs):
        return True

    # -- observables, as the integrators name them --------------------------------
    def get_spins(self):
        """The unit spins now (N, 3), zero rows for non-magnetic atoms."""
        return self._sync()["s"].copy()

    def get_magnetization(self):
        """Mean unit spin over the magnetic atoms."""
        st = self._sync()
        n = int(st["magnetic"].sum())
        return st["s"].sum(axis=0) / n if n else np.zeros(3)

    def get_magnetic_energy(self):
        """Energy of the spin-dependent terms (eV) now."""
        st = self._sync()
        if st["energy"] is None:
            with threads.threads_for(len(self.atoms)):
                st["energy"] = self._magnetic_energy(st["s"])
        return st["energy"]

    def get_potential_energy(self):
        """Lattice energy (constant: the lattice is frozen) plus the magnetic energy."""
        st = self._sync()
        if st["EL"] is None:
            st["EL"] = float(self.ev.lattice(st["q"], _ENERGY).energy)
        return st["EL"] + self.get_magnetic_energy()

    def get_spin_temperature_sums(self):
        """(N, D) = (Σ_i |s_i × B_i|², Σ_i 2 s_i·B_i − self-curvature) as the
        integrators give them
        (:meth:`~ase_spin.md.observables.Observables.get_spin_temperature_sums`):
        ⟨N⟩/(k_B⟨D⟩) is the temperature sampled, a check of the sampling."""
        st = self._sync()
        s = st["s"]
        if not st["ops"]:
            return 0.0, 0.0
        B = np.zeros_like(s)
        with threads.threads_for(len(s)):
            for op in st["ops"]:
                op.field(s, B)
            if pinned_spins(self.atoms) is not None:
                s = np.where(pinned_spins(self.atoms)[:, None], 0.0, s)
            curvature = sum(op.self_curvature(s) for op in st["ops"])
        num = float((np.cross(s, B) ** 2).sum())
        return num, 2.0 * float(np.einsum("ij,ij->", s, B)) - curvature

    @property
    def colours(self):
        """The colours: arrays of the atoms moved together (no two interact)."""
        return list(self._sync()["colours"])


class MonteCarloLogger(IOContext):
    """A line per call: sweep, magnetic energy (eV), |M|, acceptance of the
    last sweep, cone half-angle (rad)."""

    def __init__(self, mc, logfile, mode="a"):
        self.mc = mc
        self.logfile = self.openfile(file=logfile, mode=mode)
        self.logfile.write("%-10s %18s %8s %7s %7s\n" % ("Sweep", "Emag[eV]", "|M|",
                                                        "accept", "cone"))

    def __call__(self):
        mc = self.mc
        m = mc.get_magnetization()
        self.logfile.write("%-10d %18.9f %8.5f %7.3f %7.4f\n" % (
            mc.nsteps, mc.get_magnetic_energy(), float(np.sqrt(m @ m)), mc.acceptance,
            mc.cone_angle))
        self.logfile.flush()
