"""Spirit (spirit-code) on the same pure-spin scene, for side-by-side checks and
benchmarks.

Not a run-time dependency: needs the ``spirit`` Python package (a wheel with its
C++ core, ``pip install spirit``; the test extra installs it). The scene is a
Heisenberg ferromagnet on a simple cubic lattice, periodic, nearest-neighbour
exchange only, no field, anisotropy, damping or temperature, the lattice frozen.

Conventions, read from Spirit 2.2.0's source (``Hamiltonian_Heisenberg.cpp``,
``Method_LLG.cpp``) and checked by tests/test_spirit.py:

- Energy: E = −Σ_<ij> J s_i·s_j with each pair once (Spirit's serial build adds
  both ends of each unique pair to the gradient), J in meV: ase_spin's
  :class:`~ase_spin.terms.Exchange` with J in eV.
- Dynamics without damping: ds_i/dt = −(γ/μB)(1/μ_i) s_i × B_i, B_i = −∂E/∂s_i
  (meV), γ in rad/(ps·T), μB in meV/T, μ_i in μB, t in ps. That is ase_spin's
  ``precession="moment", gyromagnetic="moment"`` equation
  ds_i/dt = −(g/(μ_i ħ)) s_i × B_i with g = γħ/μB from Spirit's own constants
  (2.00231932) and ħ in eV·(ASE time): :func:`spirit_units`.
- Spin order: Spirit's index runs over x fastest, then y, then z; the ASE Atoms
  here take Spirit's own positions, so atom i is spin i.
- ``parameters.llg.set_timestep`` passes a C float: steps that are not exact
  in single precision are refused here (use powers of two of a picosecond).
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from ase import Atoms, units

from ase_spin.calculator import SpinLatticeCalculator
from ase_spin.spins import get_spins, set_spins
from ase_spin.terms.couplings import Coupling
from ase_spin.terms.exchange import Exchange

__all__ = ["spirit_available", "load_spirit", "spirit_units", "SpiritHeisenberg",
           "ConstantCoupling", "run_collective", "run_splitting", "SOLVERS"]

#: Spirit's LLG solvers for dynamics (VP and the LBFGS solvers only minimise).
SOLVERS = ("RK4", "Heun", "Depondt", "SIB")
_SOLVER_NAMES = {"RK4": "SOLVER_RK4", "Heun": "SOLVER_HEUN", "Depondt": "SOLVER_DEPONDT",
                 "SIB": "SOLVER_SIB"}
_PS = 1000.0 * units.fs


def load_spirit():
    """A namespace with Spirit's modules (ImportError if it is not installed)."""
    from types import SimpleNamespace

    from spirit import (chain, constants, geometry, htst, parameters, simulation, state,
                        system, version)

    return SimpleNamespace(constants=constants, geometry=geometry, parameters=parameters,
                           simulation=simulation, state=state, system=system, version=version,
                           chain=chain, htst=htst)


def spirit_available():
    """True if ``import spirit`` works and its library loads."""
    try:
        load_spirit()
    except (ImportError, OSError):
        return False
    return True


def spirit_units():
    """``(g, hbar)``: the ase_spin parameters of Spirit's precession rate γ/(μB μ_i),
    g = γħ/μB with Spirit's constants and ħ in eV·(ASE time)."""
    c = load_spirit().constants
    return c.gamma * c.hbar / c.mu_B, c.hbar * 1e-3 * _PS


@contextlib.contextmanager
def _quiet_stdout():
    """Silence the C++ core's banner (written to file descriptor 1)."""
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):  # a captured or redirected stream
        yield
        return
    sys.stdout.flush()
    saved = os.dup(fd)
    with open(os.devnull, "w") as null:
        os.dup2(null.fileno(), fd)
        try:
            yield
        finally:
            os.dup2(saved, fd)
            os.close(saved)


class ConstantCoupling(Coupling):
    """J(r) = J (eV) for r < rc, 0 beyond: one shell of equal couplings."""

    _parameters = {"J": "J", "rc": "rc"}

    def __init__(self, J, rc):
        self.J = float(J)
        self.rc = float(rc)
        self._finish()

    def values(self, r):
        return np.where(r < self.rc, self.J, 0.0), np.zeros_like(r)

    def __repr__(self):
        return f"ConstantCoupling(J={self.J}, rc={self.rc})"


def _config(n, a, J_meV, mu):
    return f"""
output_file_tag ase_spin
log_output_folder .
llg_output_folder .
save_input_initial 0
save_input_final 0
save_positions_initial 0
save_positions_final 0
save_neighbours_initial 0
save_neighbours_final 0
log_to_console 0
log_to_file 0
hamiltonian heisenberg_neighbours
boundary_conditions 1 1 1
external_field_magnitude 0.0
external_field_normal 0.0 0.0 1.0
mu_s {mu!r}
anisotropy_magnitude 0.0
anisotropy_normal 0.0 0.0 1.0
ddi_method none
n_shells_exchange 1
jij {J_meV!r}
n_shells_dmi 0
bravais_lattice sc
lattice_constant {a!r}
n_basis_cells {n} {n} {n}
llg_n_iterations 2000000000
llg_n_iterations_log 2000000000
llg_n_iterations_amortize 1
llg_temperature 0
llg_damping 0.0
llg_beta 0.0
llg_stt_magnitude 0.0
llg_force_convergence 0
llg_dt 0.0009765625
llg_output_any 0
llg_output_initial 0
llg_output_final 0
"""


class _SpiritState:
    """A Spirit state made from a config text, deleted by :meth:`close` (or
    on leaving a ``with`` block); ``positions`` Spirit's, in Å."""

    p = None

    def _setup(self, config):
        self.sp = load_spirit()
        with tempfile.TemporaryDirectory() as work:
            path = Path(work) / "spirit.cfg"
            path.write_text(config)
            with _quiet_stdout():
                self.p = self.sp.state.setup(str(path), quiet=True)
        self.nos = self.sp.system.get_nos(self.p)
        self.positions = np.array(self.sp.geometry.get_positions(self.p), dtype=float)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        if self.p is not None:
            with _quiet_stdout():
                self.sp.state.delete(self.p)
            self.p = None


class SpiritHeisenberg(_SpiritState):
    """A Spirit state of n³ spins (simple cubic, lattice constant ``a`` Å, periodic,
    nearest-neighbour exchange ``J_meV``, moments ``mu`` μB) and the same scene as
    ASE Atoms (:meth:`atoms`). Runs restart from the spins given.

    Spirit looks for a file named ``STOP`` in the working directory at the start
    of every run: run it where there is none. Use as a context manager, or call
    :meth:`close`.
    """

    def __init__(self, n, a=2.5, J_meV=10.0, mu=2.0):
        if int(n) != n or n < 3:
            raise ValueError(f"n must be a whole number ≥ 3 (n³ spins, periodic), got {n!r}")
        self.n, self.a, self.J_meV, self.mu = int(n), float(a), float(J_meV), float(mu)
        self._setup(_config(self.n, self.a, self.J_meV, self.mu))
        if self.nos != self.n**3:
            raise RuntimeError(f"Spirit made {self.nos} spins, not {self.n**3}")

    # -- the same scene in ase_spin ----------------------------------------------

    def atoms(self, spins):
        """ASE Atoms at Spirit's positions with ``spins``, moments μ and the
        exchange of this scene (J in eV, first shell: rc = 1.2 a)."""
        atoms = Atoms(f"Fe{self.nos}", positions=self.positions,
                      cell=np.eye(3) * self.n * self.a, pbc=True)
        set_spins(atoms, spins, magnitudes=self.mu)
        rc = 1.2 * self.a  # the second shell is at √2 a
        atoms.calc = SpinLatticeCalculator(
            [Exchange(ConstantCoupling(self.J_meV * 1e-3, rc), rc=rc)])
        return atoms

    def integrator_options(self):
        """Keyword arguments of ase_spin's integrators for Spirit's equation."""
        g, hbar = spirit_units()
        return dict(hbar=hbar, precession="moment", gyromagnetic="moment", g=g,
                    lattice="frozen")

    # -- Spirit -------------------------------------------------------------------

    def set_spins(self, spins):
        spins = np.asarray(spins, dtype=float)
        if spins.shape != (self.nos, 3):
            raise ValueError(f"spins must have shape ({self.nos}, 3), got {spins.shape}")
        view = self.sp.system.get_spin_directions(self.p)
        view[:] = spins / np.linalg.norm(spins, axis=1)[:, None]
        self.sp.system.update_data(self.p)

    def spins(self):
        return np.array(self.sp.system.get_spin_directions(self.p), dtype=float)

    def energy_meV(self):
        """Spirit's own energy of its current spins (a float32 through its C API)."""
        self.sp.system.update_data(self.p)
        return self.sp.system.get_energy(self.p)

    def start(self, solver, dt_ps):
        """Allocate ``solver`` (one of :data:`SOLVERS`) for single steps of dt_ps ps
        (Spirit computes the first field here)."""
        if solver not in _SOLVER_NAMES:
            raise ValueError(f"solver must be one of {SOLVERS}, got {solver!r}")
        if float(np.float32(dt_ps)) != dt_ps:
            raise ValueError(f"dt_ps = {dt_ps!r} is not exact in single precision, which "
                             "Spirit's set_timestep passes: use e.g. a power of two")
        sim = self.sp.simulation
        self.sp.parameters.llg.set_timestep(self.p, dt_ps)
        sim.start(self.p, sim.METHOD_LLG, getattr(sim, _SOLVER_NAMES[solver]), single_shot=True)

    def steps(self, count):
        self.sp.simulation.n_shot(self.p, int(count))

    def stop(self):
        self.sp.simulation.stop(self.p)

    def run(self, solver, dt_ps, steps, spins):
        """``(final spins, wall time of the steps in s)`` of ``steps`` steps from
        ``spins``; the solver's set-up is not timed."""
        self.set_spins(spins)
        self.start(solver, dt_ps)
        t0 = time.perf_counter()
        self.steps(steps)
        wall = time.perf_counter() - t0
        self.stop()
        return self.spins(), wall


def run_collective(scene, spins, order, dt_ps, steps, threads=None, tol=None):
    """``(final spins, wall time of the steps, mean sweeps per step)`` of
    CollectivePRK on ``scene`` (a :class:`SpiritHeisenberg`), set-up not timed."""
    from ase_spin.md.collective import CollectivePRK

    dyn = CollectivePRK(scene.atoms(spins), dt_ps * _PS, order=order, threads=threads,
                        tol=tol, **scene.integrator_options())
    return _timed_run(dyn, steps)


def run_splitting(scene, spins, order, dt_ps, steps, rotation="cayley"):
    """``(final spins, wall time of the steps, nan)`` of :class:`SuzukiTrotter`
    (sequential sweeps: one thread) on ``scene``, set-up not timed."""
    from ase_spin.md.splitting import SuzukiTrotter

    dyn = SuzukiTrotter(scene.atoms(spins), dt_ps * _PS, order=order, rotation=rotation,
                        **scene.integrator_options())
    return _timed_run(dyn, steps)


def _timed_run(dyn, steps):
    prepare = getattr(dyn, "_sync", None)  # pair operators, outside the timed steps
    if prepare is not None:
        prepare()
    t0 = time.perf_counter()
    dyn.run(steps)
    wall = time.perf_counter() - t0
    sweeps = dyn.total_iterations / max(dyn.total_steps, 1) if dyn.total_iterations else np.nan
    return get_spins(dyn.atoms), wall, sweeps


def _film_config(shape, boundaries, a, J_meV, D_meV, K_meV, field_T, mu, convergence_meV):
    """A Spirit input file of a square lattice (sc, ``shape`` cells, one layer
    when shape[2] = 1) with nearest-neighbour exchange, Néel DMI in the plane,
    uniaxial anisotropy and a field along z."""
    text = _config(3, a, J_meV, mu)
    replace = {
        "boundary_conditions 1 1 1": "boundary_conditions " + " ".join(
            str(int(b)) for b in boundaries),
        "n_basis_cells 3 3 3": "n_basis_cells " + " ".join(str(int(k)) for k in shape),
        "external_field_magnitude 0.0": f"external_field_magnitude {field_T!r}",
        "anisotropy_magnitude 0.0": f"anisotropy_magnitude {K_meV!r}",
        # dm_chirality 2: Spirit's Néel chirality, which is D_ij = D e_ij × ẑ of
        # ase_spin's DMI(D, ẑ) (the energies agree: tests/test_spirit.py)
        "n_shells_dmi 0": (f"n_shells_dmi {1 if D_meV else 0}\ndij {D_meV!r}\n"
                           "dm_chirality 2"),
        "llg_force_convergence 0": f"llg_force_convergence {convergence_meV!r}",
    }
    for old, new in replace.items():
        if old not in text:
            raise RuntimeError(f"Spirit config template changed: no {old!r}")
        text = text.replace(old, new)
    return text + f"gneb_force_convergence {convergence_meV!r}\ngneb_n_iterations 2000000000\n" \
        "gneb_n_iterations_log 2000000000\ngneb_output_any 0\n"


class SpiritFilm(_SpiritState):
    """A Spirit state of a square lattice of nx × ny × nz spins (lattice
    constant ``a`` Å; ``periodic``: Spirit's boundary conditions per axis)
    with nearest-neighbour exchange J, interfacial (Néel) DMI D, uniaxial
    anisotropy K along z (all meV) and a field (T) along z, moments ``mu`` μB;
    and the same scene as ASE Atoms (:meth:`atoms`): ase_spin's DMI(D, ẑ) is
    Spirit's ``dm_chirality 2``, its field term uses Spirit's μB.

    Minimisation (:meth:`minimise`) and the GNEB (:meth:`gneb`) stop when
    Spirit's largest torque falls below ``convergence`` (meV, Spirit's units:
    the same max_i |s_i × B_i| as ase_spin's ``fmax`` × 1000). Run where there
    is no file named ``STOP``; use as a context manager.
    """

    def __init__(self, shape, periodic=(True, True, False), a=2.5, J_meV=10.0, D_meV=0.0,
                 K_meV=0.0, field_T=0.0, mu=2.0, convergence_meV=1e-7):
        self.shape = tuple(int(k) for k in shape)
        self.periodic = tuple(bool(p) for p in periodic)
        self.a, self.J_meV, self.D_meV = float(a), float(J_meV), float(D_meV)
        self.K_meV, self.field_T, self.mu = float(K_meV), float(field_T), float(mu)
        self._setup(_film_config(self.shape, self.periodic, self.a, self.J_meV, self.D_meV,
                                 self.K_meV, self.field_T, self.mu, float(convergence_meV)))

    def atoms(self, spins):
        """ASE Atoms at Spirit's positions with ``spins`` and this Hamiltonian
        (exchange as a nearest-neighbour Bethe–Slater J(r) with J(a) = J)."""
        from ase_spin.terms import DMI, BetheSlater, UniaxialAnisotropy, Zeeman

        cell = np.diag([k * self.a if k > 1 or p else 10.0 * self.a
                        for k, p in zip(self.shape, self.periodic)])
        atoms = Atoms(f"Fe{self.nos}", positions=self.positions, cell=cell,
                      pbc=self.periodic)
        set_spins(atoms, spins, magnitudes=self.mu)
        rc = 1.2 * self.a
        J = self.J_meV * 1e-3
        terms = [Exchange(BetheSlater(J * np.e / 4.0, 0.0, self.a), rc=rc)]
        if self.D_meV:
            terms.append(DMI(self.D_meV * 1e-3, [0.0, 0.0, 1.0], rc=rc))
        if self.K_meV:
            terms.append(UniaxialAnisotropy(self.K_meV * 1e-3, [0.0, 0.0, 1.0]))
        if self.field_T:
            terms.append(Zeeman(self.field_T, [0.0, 0.0, 1.0], g=1.0,
                                mu_B=self.sp.constants.mu_B * 1e-3))
        atoms.calc = SpinLatticeCalculator(terms)
        return atoms

    # -- one image or a chain of them ---------------------------------------------

    def set_spins(self, spins, image=-1):
        spins = np.asarray(spins, dtype=float)
        view = self.sp.system.get_spin_directions(self.p, idx_image=image)
        view[:] = spins / np.linalg.norm(spins, axis=1)[:, None]
        self.sp.system.update_data(self.p, idx_image=image)

    def spins(self, image=-1):
        return np.array(self.sp.system.get_spin_directions(self.p, idx_image=image),
                        dtype=float)

    def energy_meV(self, image=-1):
        """Spirit's energy (single precision through its C API)."""
        self.sp.system.update_data(self.p, idx_image=image)
        return self.sp.system.get_energy(self.p, idx_image=image)

    def minimise(self, spins, solver="LBFGS_OSO"):
        """``(spins, seconds)``: Spirit's minimiser (``LBFGS_OSO`` or ``VP``)
        from ``spins`` to its convergence."""
        sim = self.sp.simulation
        self.set_spins(spins)
        t0 = time.perf_counter()
        sim.start(self.p, sim.METHOD_LLG, getattr(sim, f"SOLVER_{solver}"))
        seconds = time.perf_counter() - t0
        return self.spins(), seconds

    def gneb(self, images, climbing=True, spring=None, iterations=-1):
        """Spirit's GNEB (VP solver) on the band ``images`` ((M, N, 3) spins, the
        ends relaxed); with ``climbing`` the highest inner image after a
        first relaxation climbs. Returns the relaxed images (M, N, 3)."""
        sp = self.sp
        images = np.asarray(images, dtype=float)
        sp.chain.set_length(self.p, len(images))
        for k, s in enumerate(images):
            self.set_spins(s, image=k)
        sp.chain.update_data(self.p)
        if spring is not None:
            sp.parameters.gneb.set_spring_force(self.p, spring, 0.0)
        sim = sp.simulation
        sim.start(self.p, sim.METHOD_GNEB, sim.SOLVER_VP, n_iterations=iterations)
        if climbing:
            E = np.array([self.energy_meV(k) for k in range(len(images))])
            top = 1 + int(np.argmax(E[1:-1]))
            sp.parameters.gneb.set_climbing_falling(self.p, sp.parameters.gneb.IMAGE_CLIMBING,
                                                    idx_image=top)
            sim.start(self.p, sim.METHOD_GNEB, sim.SOLVER_VP, n_iterations=iterations)
        return np.array([self.spins(k) for k in range(len(images))])

    def htst(self, minimum, saddle):
        """Spirit's HTST between spins ``minimum`` and ``saddle`` (each (N, 3),
        stationary to its 1e-8 meV): ``(prefactor in 1/s, Hessian eigenvalues
        at the minimum and at the saddle in meV/rad², ascending)``, single
        precision. Spirit's velocity matrix takes the effective field from its
        Hessian, −H s, which leaves out a field's linear Zeeman term: with a
        field its prefactor is not the HTST one (docs/landscapes.md)."""
        sp = self.sp
        sp.chain.set_length(self.p, 2)
        self.set_spins(minimum, image=0)
        self.set_spins(saddle, image=1)
        prefactor = sp.htst.calculate(self.p, 0, 1)
        return (float(prefactor), np.sort(np.array(sp.htst.get_eigenvalues_min(self.p))),
                np.sort(np.array(sp.htst.get_eigenvalues_sp(self.p))))
