"""Midpoint solvers of CollectivePRK against the step size: sweeps, failures, step time.

    python benchmarks/solver.py                 # the largest step of docs/benchmarks.md
    python benchmarks/solver.py --quick         # a smoke run (few steps, few dt)

For fcc Co (ase_spin.scenes.fcc_cobalt, 100 K, spins in a 30° cone) at each dt
and each solver (``CollectivePRK(solver=...)``: "jacobi", the plain
fixed-point iteration; "local", the locally exact sweep; "anderson", the
locally exact sweep with Anderson acceleration; "auto", the default: Jacobi
while it contracts fast, else Anderson), one run of
``--steps`` steps reports the midpoint sweeps per step (all stages) or the
error that stopped it and at which step, and the spin error at the end
against a reference run (order 6, dt = 0.02 fs; max |Δs| over spins): what
limits a large step, the solver or the accuracy. Then, at N = 4000, the step
time per solver (median of ``--rounds`` rounds of ``--chunk`` steps, the
solvers alternating round by round in one process, after warm-up steps).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings

import numpy as np
from ase import units

sys.path.insert(0, os.path.dirname(__file__))

from ase_spin import CollectivePRK, get_spins  # noqa: E402
from ase_spin.md import SpinConvergenceError  # noqa: E402
from ase_spin.scenes import fcc_cobalt  # noqa: E402
from machine import describe  # noqa: E402

SOLVERS = ("jacobi", "local", "anderson", "auto")


def reference(n, t_fs):
    atoms = fcc_cobalt(n)
    dt = 0.02
    CollectivePRK(atoms, dt * units.fs, order=6).run(int(round(t_fs / dt)))
    return get_spins(atoms)


def sweep_table(n, order, dts, t_fs, ref):
    print(f"\n# fcc Co N = {4 * n**3}, order {order}, {t_fs:g} fs per run: "
          f"sweeps/step (or the failure) | spin error at the end vs reference")
    print(f"{'dt fs':>6} " + " ".join(f"{s:>24}" for s in SOLVERS))
    for dt in dts:
        steps = int(round(t_fs / dt))
        cells = []
        for solver in SOLVERS:
            atoms = fcc_cobalt(n)
            dyn = CollectivePRK(atoms, dt * units.fs, order=order, solver=solver)
            try:
                dyn.run(steps)
                err = float(np.abs(get_spins(atoms) - ref).max())
                cells.append(f"{dyn.mean_iterations:7.1f} | {err:8.1e}")
            except SpinConvergenceError:
                cells.append(f"fails at step {dyn.nsteps}")
            except Exception as exc:  # the lattice may give up first
                cells.append(f"{type(exc).__name__} at {dyn.nsteps}")
        print(f"{dt:6.2f} " + " ".join(f"{c:>24}" for c in cells), flush=True)


def time_table(n, dts, rounds, chunk):
    print(f"\n# fcc Co N = {4 * n**3}, order 2: µs per atom-step, median of {rounds} × "
          f"{chunk} steps (solvers alternating), sweeps/step in brackets; load "
          f"{os.getloadavg()[0]:.2f}")
    print(f"{'dt fs':>6} " + " ".join(f"{s:>20}" for s in SOLVERS) + "  auto/jacobi")
    for dt in dts:
        dyns = {}
        for solver in SOLVERS:
            atoms = fcc_cobalt(n)
            dyns[solver] = CollectivePRK(atoms, dt * units.fs, solver=solver)
        times = {s: [] for s in SOLVERS}
        failed = set()
        for r in range(rounds + 1):
            for solver, dyn in dyns.items():
                if solver in failed:
                    continue
                t0 = time.perf_counter()
                try:
                    dyn.run(chunk)
                except SpinConvergenceError:
                    failed.add(solver)
                    continue
                if r:  # the first round warms up
                    times[solver].append((time.perf_counter() - t0) / chunk / (4 * n**3) * 1e6)
        med = {s: float(np.median(times[s])) if times[s] and s not in failed else None
               for s in SOLVERS}
        cells = [f"{med[s]:8.3f} ({dyns[s].mean_iterations:5.1f})" if med[s] else "fails"
                 for s in SOLVERS]
        ratio = f"{med['auto'] / med['jacobi']:.2f}" if med["auto"] and med["jacobi"] else "-"
        print(f"{dt:6.2f} " + " ".join(f"{c:>20}" for c in cells) + f"  {ratio:>15}",
              flush=True)


def main(argv=None):
    parser = argparse.ArgumentParser()
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--chunk", type=int, default=10)
    args = parser.parse_args(argv)
    warnings.simplefilter("ignore")  # the TimestepWarning of large steps is the point here
    print(describe(), f"\n# load {os.getloadavg()[0]:.2f}", flush=True)
    if args.quick:
        ref = reference(2, 4.0)
        sweep_table(2, 2, (0.5, 4.0), 4.0, ref)
        time_table(2, (0.1,), 1, 2)
        return
    t_fs = 48.0
    ref = reference(3, t_fs)
    dts = (0.25, 0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0)
    for order in (2, 4, 6):
        sweep_table(3, order, dts, t_fs, ref)
    time_table(10, (0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 3.0), args.rounds, args.chunk)


if __name__ == "__main__":
    main()
