"""A log line for spin–lattice dynamics, in the style of ASE's MDLogger."""

from __future__ import annotations

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
        self.dyn = weakref.proxy(dyn)
        self.logfile = self.openfile(file=logfile, mode=mode, comm=comm)
        n = len(dyn.atoms)
        digits = 4 if n <= 100 else 3 if n <= 1000 else 2 if n <= 10000 else 1
        self.hdr = "%-10s %13s %13s %13s %13s %8s %8s %9s %5s" % (
            "Time[ps]", "Etot[eV]", "Epot[eV]", "Ekin[eV]", "Emag[eV]", "T[K]",
            "|M|", "Ts[K]", "iter")
        e = f"%13.{digits}f"
        self.fmt = f"%-10.4f {e} {e} {e} {e} %8.1f %8.5f %9.1f %5d\n"
        if header:
            self.logfile.write(self.hdr + "\n")

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
