"""A log line for spin–lattice dynamics, in the style of ASE's MDLogger."""

from __future__ import annotations

import numbers
import os
import sys
import weakref
from collections import deque

from ase import units
from ase.parallel import world
from ase.utils import IOContext

from ..validate import warn_user

__all__ = ["SpinMDLogger", "LangevinLogger", "SPIN_TEMPERATURE_WINDOW"]


#: Log lines the spin temperature Ts is averaged over (:class:`SpinMDLogger`)
SPIN_TEMPERATURE_WINDOW = 10
#: Ts is written only where the window's denominator exceeds this many times
#: its thermal fluctuation at high temperature (see :class:`SpinMDLogger`)
SPIN_TEMPERATURE_MARGIN = 3.0
#: decimals of the energies in the log (eV): 10⁻⁹ eV, to judge conservation
ENERGY_DECIMALS = 9


class SpinMDLogger(IOContext):
    r"""Writes, per call: time (ps), total, potential, kinetic and magnetic
    energy (eV, 9 decimals: enough to follow the conservation of Etot; the
    magnetic energy is the spin-dependent terms' energy, LAMMPS ``compute
    spin``'s), lattice temperature T (K), mean spin |M|, spin temperature Ts
    (K) and midpoint iterations of the last step. Columns are aligned under
    their header while |E| < 10⁷ eV.

    **Ts** is the configurational spin temperature averaged over the last
    ``spin_temperature_window`` log lines (default
    :data:`SPIN_TEMPERATURE_WINDOW`, 10; this line included, fewer at the
    start of the log). Each line k gives the sums N_k = Σ_i |s_i × B_i|²
    = |∇E|² and D_k = ∇²E = Σ_i (2 s_i·B_i − Σ_{t⊥s_i} t·∂B_i/∂s_i t) on
    the spheres
    (:meth:`~ase_spin.md.observables.Observables.get_spin_temperature_sums`),
    and

    .. math:: k_B T_s = \frac{\sum_k N_k}{\sum_k D_k},

    a ratio of averages, as the identity ⟨|∇E|²⟩ = k_B T ⟨∇²E⟩ of the
    Boltzmann distribution makes it a temperature. For exchange, DMI and
    fields D = 2 Σ s·B, and one line's ratio (``spin_temperature_window=1``)
    is LAMMPS ``compute spin``'s estimator (Nurdin and Schotte), whose
    denominator crosses zero above T_C: one sample then reads any number of
    either sign. ⟨D⟩ itself is positive at any finite T, but shrinks as T
    grows (∇²E averages to zero at infinite T: no configurational estimator
    on spheres escapes this) while D's fluctuation does not: at high T its
    standard deviation is 2 √⟨N⟩ for couplings bilinear in the spins (√2
    √⟨N⟩ for fields). So Ts is written as ``nan`` when the window's ΣD_k
    is below :data:`SPIN_TEMPERATURE_MARGIN` (3) times 2 √(ΣN_k), the
    fluctuation of ΣD_k for independent lines: the window then holds too
    little to tell the temperature (a longer window or log interval
    tells it). A written Ts is positive, never above √(ΣN_k)/(6 k_B), with
    a statistical error of about a third at most (more if the lines are
    correlated in time). Many ``nan`` in a row mean the written values are
    those of windows with a large D, biased low: lengthen the window. Out of
    equilibrium (a quench, a heat current) Ts is a number, not a
    temperature.

    Reads everything from the integrator's own state (``dyn.get_*``): no
    calculator call, and only one cheap pass over the spin terms for the
    magnetic energy and fields.
    """

    def __init__(self, dyn, logfile, header=True, mode="a", comm=world,
                 spin_temperature_window=SPIN_TEMPERATURE_WINDOW):
        self._dyn = weakref.ref(dyn)
        self.comm = comm
        self.logfile = self.openfile(file=logfile, mode=mode, comm=comm)
        window = spin_temperature_window
        if isinstance(window, bool) or not isinstance(window, numbers.Integral) or window < 1:
            raise ValueError("spin_temperature_window must be a whole number of log lines "
                             f">= 1, got {window!r}")
        #: the sums (N_k, D_k) of the last log lines (at most the window)
        self.spin_temperature_samples = deque(maxlen=int(window))
        width = ENERGY_DECIMALS + 9  # |E| < 10⁷ eV with its sign
        self.hdr = f"%-12s {' '.join([f'%{width}s'] * 4)} %8s %8s %9s %5s" % (
            "Time[ps]", "Etot[eV]", "Epot[eV]", "Ekin[eV]", "Emag[eV]", "T[K]",
            "|M|", "Ts[K]", "iter")
        self.energy_format = f"%{width}.{ENERGY_DECIMALS}f"
        self.fmt = (f"%-12.7f {' '.join([self.energy_format] * 4)} %8.1f %8.5f %9.1f "
                    "%5d\n")
        if header:
            self.logfile.write(self.hdr + "\n")

    @property
    def dyn(self):
        return self._dyn()

    def __getstate__(self):
        """A copy (pickle, deepcopy) appends to the same file (a restart
        continues the log); a log written to a stream that is not a named file
        (a StringIO, a pipe) goes nowhere in the copy, with a warning."""
        state = {k: v for k, v in self.__dict__.items()
                 if k not in ("logfile", "_exitstack", "_dyn", "comm")}
        state["dyn"] = self._dyn()
        fd = self.logfile
        name = getattr(fd, "name", None)
        if fd is sys.stdout:
            state["file"] = "-"
        elif isinstance(name, str) and os.path.isfile(name):
            fd.flush()
            state["file"] = os.path.abspath(name)
        else:
            warn_user(f"the copy of the log line writing to {fd!r:.60} goes to "
                      "os.devnull: only a named file or '-' can be reopened")
            state["file"] = None
        return state

    def __setstate__(self, state):
        dyn = state.pop("dyn")
        file = state.pop("file")
        self.__dict__.update(state)
        self._dyn = weakref.ref(dyn)
        self.comm = world
        self.logfile = self.openfile(file=file, mode="a", comm=world)

    def spin_temperature(self, dyn):
        """Ts of this line (K; see the class docstring): the sums of the
        current state added to the window, their ratio returned (nan where the
        window cannot tell it, or without magnetic atoms; 0 K for spins at
        rest along their fields)."""
        num, den = dyn.get_spin_temperature_sums()
        samples = self.spin_temperature_samples
        samples.append((num, den))
        N = sum(n for n, _ in samples)
        D = sum(d for _, d in samples)
        if not D > 2.0 * SPIN_TEMPERATURE_MARGIN * N ** 0.5:  # nan too: no spins
            return float("nan")
        return N / (units.kB * D)

    def values(self, dyn):
        """The numbers of one line, in the order of the header."""
        epot = dyn.get_potential_energy()
        ekin = dyn.get_kinetic_energy()
        m = dyn.get_magnetization()
        return (dyn.get_time() / (1000 * units.fs), epot + ekin, epot, ekin,
                dyn.get_magnetic_energy(), dyn.get_temperature(), float((m @ m) ** 0.5),
                self.spin_temperature(dyn), dyn.iterations)

    def __call__(self):
        self.logfile.write(self.fmt % self.values(self.dyn))
        self.logfile.flush()


class LangevinLogger(SpinMDLogger):
    """:class:`SpinMDLogger`'s line (time, energies, T, |M|, Ts, sweeps)
    followed by Ebath, the energy the baths put in since the start, and
    Econs = Etot − Ebath (eV, 9 decimals as the energies): the quantity a
    Langevin run conserves, up to the step's own energy error."""

    def __init__(self, dyn, logfile, header=True, mode="a", **kwargs):
        super().__init__(dyn, logfile, header=False, mode=mode, **kwargs)
        width = ENERGY_DECIMALS + 9
        self.hdr += f" %{width}s %{width}s" % ("Ebath[eV]", "Econs[eV]")
        self.fmt = self.fmt[:-1] + f" {self.energy_format} {self.energy_format}\n"
        if header:
            self.logfile.write(self.hdr + "\n")

    def values(self, dyn):
        line = super().values(dyn)
        bath = dyn.get_bath_energy()
        return (*line, bath, line[1] - bath)
