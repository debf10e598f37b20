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

    from spirit import constants, geometry, parameters, simulation, state, system, version

    return SimpleNamespace(constants=constants, geometry=geometry, parameters=parameters,
                           simulation=simulation, state=state, system=system, version=version)


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


class SpiritHeisenberg:
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
        self.sp = load_spirit()
        self.n, self.a, self.J_meV, self.mu = int(n), float(a), float(J_meV), float(mu)
        with tempfile.TemporaryDirectory() as work:
            path = Path(work) / "sc.cfg"
            path.write_text(_config(self.n, self.a, self.J_meV, self.mu))
            with _quiet_stdout():
                self.p = self.sp.state.setup(str(path), quiet=True)
        self.nos = self.sp.system.get_nos(self.p)
        if self.nos != self.n**3:
            raise RuntimeError(f"Spirit made {self.nos} spins, not {self.n**3}")
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
