"""Steps on a busy machine: ase_spin with all threads, one thread and the
adaptive choice (the default), and LAMMPS, side by side, idle and with
CPU-bound competing processes.

    python benchmarks/busy_machine.py [--sizes 5 10 20] [--competitors 0 1] [--steps 40]

fcc Co (peers.md scene, N = 4n³), CollectivePRK order 2 at 0.1 fs. Each
condition starts ``--competitors`` processes spinning on the CPU for the
duration of its measurements. Prints µs per atom-step (median of --repeats
runs of --steps steps; each setting's runs one after the other, as a user's
run would go, so that the adaptive choice is timed over a continuous stretch
rather than right after another setting's slow steps) and the machine.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import sys
import time

import numpy as np
from ase import units

sys.path.insert(0, os.path.dirname(__file__))
# the drivers of LAMMPS and Spirit (lammps_peer, spirit_peer) live with the tests
sys.path.insert(0, os.path.join(os.path.dirname(__file__), os.pardir, "tests"))

from ase_spin import HBAR_LAMMPS, CollectivePRK  # noqa: E402
from lammps_peer import LammpsSpin, lammps_available  # noqa: E402
from ase_spin.scenes import fcc_cobalt  # noqa: E402
from ase_spin._jit.threads import chunks  # noqa: E402
from machine import describe  # noqa: E402


def spin(stop):
    x = 0.0
    while not stop.is_set():
        for _ in range(100000):
            x = x * 0.5 + 1.0


def measure(n, steps, repeats, with_lammps):
    settings = {f"{chunks()} threads": chunks(), "1 thread": 1, "auto": "auto"}
    dyns = {}
    for label, threads in settings.items():
        atoms = fcc_cobalt(n, conventions="lammps")
        dyns[label] = CollectivePRK(atoms, 0.1 * units.fs, hbar=HBAR_LAMMPS, threads=threads)
        dyns[label].run(4)  # compile, and let "auto" time both choices
    lmp = None
    if with_lammps:
        lmp = LammpsSpin(fcc_cobalt(n, conventions="lammps"), (0.4, 2.2742, 4.7, True),
                         (0.0446928, 0.003496, 1.4885, 4.0, False), timestep_fs=0.1)
        lmp.run(0)
    natoms = 4 * n**3
    times = {label: [] for label in [*settings, *(["LAMMPS"] if lmp else [])]}
    for label, dyn in dyns.items():
        for _ in range(repeats):
            t0 = time.perf_counter()
            dyn.run(steps)
            times[label].append((time.perf_counter() - t0) / steps / natoms * 1e6)
    for _ in range(repeats if lmp else 0):
        t0 = time.perf_counter()
        lmp.run(steps)
        times["LAMMPS"].append((time.perf_counter() - t0) / steps / natoms * 1e6)
    if lmp:
        lmp.close()
    return {label: float(np.median(v)) for label, v in times.items()}


def main(argv=None):
    parser = argparse.ArgumentParser()
    parser.add_argument("--sizes", type=int, nargs="+", default=[5, 10, 20])
    parser.add_argument("--competitors", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--steps", type=int, default=40)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    print(describe(), flush=True)
    with_lammps = lammps_available()
    for competitors in args.competitors:
        stop = mp.Event()
        procs = [mp.Process(target=spin, args=(stop,), daemon=True) for _ in range(competitors)]
        for p in procs:
            p.start()
        try:
            for n in args.sizes:
                row = measure(n, args.steps, args.repeats, with_lammps)
                text = "  ".join(f"{k}: {v:7.2f}" for k, v in row.items())
                ratio = (f"  auto/LAMMPS {row['auto'] / row['LAMMPS']:.2f}"
                         if "LAMMPS" in row else "")
                print(f"competitors {competitors}  N {4 * n**3:6d}  µs/atom-step  {text}{ratio}",
                      flush=True)
        finally:
            stop.set()
            for p in procs:
                p.join()


if __name__ == "__main__":
    main()
