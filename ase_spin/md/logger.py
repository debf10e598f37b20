"""A log line for spin–lattice dynamics, in the style of ASE's MDLogger."""

from __future__ import annotations

import os
import sys
import warnings
import weakref

from ase import units
from ase.parallel import world
from ase.utils import IOContext

__all__ = ["SpinMDLogger"]


class SpinMDLogger(IOContext):
    """Writes, per call: time (ps), total, potential, kinetic and magnetic
    energy (eV; the spin-dependent terms' energy, LAMMPS ``compute spin``'s
    magnetic energy), lattice temperature T (K), mean spin |M|, spin temperature
    Ts (K, LAMMPS ``compute spin``'s estimator) and midpoint iterations of the
    last step.

    Reads everything from the integrator's own state (``dyn.get_*``): no
    calculator call, and only one cheap pass over the spin terms for the
    magnetic energy and fields.
    """

    def __init__(self, dyn, logfile, header=True, mode="a", comm=world):
        self._dyn = weakref.ref(dyn)
        self.comm = comm
        self.logfile = self.openfile(file=logfile, mode=mode, comm=comm)
        n = len(dyn.atoms)
        digits = 4 if n <= 100 else 3 if n <= 1000 else 2 if n <= 10000 else 1
        self.hdr = "%-12s %13s %13s %13s %13s %8s %8s %9s %5s" % (
            "Time[ps]", "Etot[eV]", "Epot[eV]", "Ekin[eV]", "Emag[eV]", "T[K]",
            "|M|", "Ts[K]", "iter")
        e = f"%13.{digits}f"
        self.fmt = f"%-12.7f {e} {e} {e} {e} %8.1f %8.5f %9.1f %5d\n"
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
            warnings.warn(f"the copy of the log line writing to {fd!r:.60} goes to "
                          "os.devnull: only a named file or '-' can be reopened",
                          stacklevel=2)
            state["file"] = None
        return state

    def __setstate__(self, state):
        dyn = state.pop("dyn")
        file = state.pop("file")
        self.__dict__.update(state)
        self._dyn = weakref.ref(dyn)
        self.comm = world
        self.logfile = self.openfile(file=file, mode="a", comm=world)

    def __call__(self):
        dyn = self.dyn
        epot = dyn.get_potential_energy()
        ekin = dyn.get_kinetic_energy()
        emag = dyn.get_magnetic_energy()
        m = dyn.get_magnetization()
        mnorm = float((m @ m) ** 0.5)
        ts = dyn.get_spin_temperature()
        t = dyn.get_time() / (1000 * units.fs)
        self.logfile.write(self.fmt % (t, epot + ekin, epot, ekin, emag,
                                       dyn.get_temperature(), mnorm, ts,
                                       dyn.iterations))
        self.logfile.flush()


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
