"""Cost of one CollectivePRK step on the fcc Co scene, against one full evaluation.

    python benchmarks/bench_md.py [--sizes 5 10 20] [--dt 0.1] [--order 2]

For each 4n³-atom crystal (peers.md scene: 100 K, 30° spin cone, moment
convention, dt in fs): µs per atom-step (median of repeats), midpoint sweeps and
geometry evaluations per step, and the ratio to one full evaluation
(`Evaluator.evaluate`: energy, forces, magnetic forces; the faster of its
threaded and serial kernels) and to one ASE calculator call (`get_potential_energy` + `get_forces` + magnetic forces).
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np
from ase import units

sys.path.insert(0, os.path.dirname(__file__))

import ase_spin  # noqa: E402
from ase_spin import CollectivePRK, Want
from ase_spin._jit import threads  # noqa: E402
from ase_spin.scenes import fcc_cobalt  # noqa: E402
from machine import describe  # noqa: E402


def median_time(fn, repeats):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def main(argv=None):
    parser = argparse.ArgumentParser()
    parser.add_argument("--sizes", type=int, nargs="+", default=[5, 10, 20])
    parser.add_argument("--dt", type=float, default=0.1)
    parser.add_argument("--order", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)
    print(f"fcc Co, dt = {args.dt} fs, order {args.order}; µs per atom(-step), medians of "
          f"{args.repeats}")
    print(f"{'N':>8} {'step':>8} {'sweeps':>7} {'geoms':>6} {'full eval':>10} {'ratio':>6} "
          f"{'ASE calc':>9} {'ratio':>6}")
    default_serial_below = threads.SERIAL_BELOW
    for n in args.sizes:
        atoms = fcc_cobalt(n)
        N = len(atoms)
        dyn = CollectivePRK(atoms, args.dt * units.fs, order=args.order)
        dyn.run(5)
        steps = max(5, int(1e5 / N))
        ev, _ = atoms.calc.bound_evaluator(atoms)
        want = Want(energy=True, forces=True, magnetic_forces=True)
        before = (dyn.total_iterations, dyn.total_steps)
        # step and evaluation timed alternately, so that both see the same
        # machine (this one is shared and its speed drifts by tens of %)
        step_times, full_times = [], {0: [], 10**9: []}
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            dyn.run(steps)
            step_times.append((time.perf_counter() - t0) / steps)
            spins = ase_spin.get_spins(atoms)
            for serial_below in full_times:  # threaded and serial kernels
                threads.SERIAL_BELOW = serial_below
                ev.evaluate(atoms.positions, spins, want)
                full_times[serial_below].append(
                    median_time(lambda: ev.evaluate(atoms.positions, spins, want), 3))
            threads.SERIAL_BELOW = default_serial_below
        step = float(np.median(step_times))
        full = min(float(np.median(t)) for t in full_times.values())
        sweeps = (dyn.total_iterations - before[0]) / (dyn.total_steps - before[1])

        def via_ase():
            atoms.calc.results.clear()
            atoms.get_potential_energy()
            atoms.get_forces()
            atoms.calc.get_magnetic_forces(atoms)

        via_ase()
        ase_time = median_time(via_ase, args.repeats)
        us = 1e6 / N
        print(f"{N:8d} {step * us:8.3f} {sweeps:7.2f} {dyn.geometry_evaluations:6d} "
              f"{full * us:10.3f} {step / full:6.2f} {ase_time * us:9.3f} {step / ase_time:6.2f}")
    print(describe())


if __name__ == "__main__":
    main()
