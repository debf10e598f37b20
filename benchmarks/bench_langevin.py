"""Cost of a thermostatted step (Langevin: both baths on) against an NVE
CollectivePRK step, side by side on the same fcc Co crystal.

    python benchmarks/bench_langevin.py [--n 10] [--dt 0.1] [--steps 100] [--rounds 5]

The two integrators run alternately in rounds of ``steps`` steps each (so load
changes on the machine hit both alike); printed: µs per atom-step (median over
rounds), midpoint sweeps and geometry evaluations per step, and the ratio
Langevin/NVE of the round medians and its range over rounds.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np
from ase import units

sys.path.insert(0, os.path.dirname(__file__))

from ase_spin import CollectivePRK, Langevin  # noqa: E402
from ase_spin.scenes import fcc_cobalt  # noqa: E402
from machine import describe  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=10, help="4n³ atoms (10: 4000)")
    ap.add_argument("--dt", type=float, default=0.1, help="fs")
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--temperature", type=float, default=300.0)
    args = ap.parse_args(argv)
    T = args.temperature
    dyns = {
        "NVE": CollectivePRK(fcc_cobalt(args.n, temperature_K=T), args.dt * units.fs),
        "Langevin": Langevin(fcc_cobalt(args.n, temperature_K=T), args.dt * units.fs, T,
                             spin_damping=0.1, friction=0.01 / units.fs, rng=1),
    }
    natoms = 4 * args.n**3
    for d in dyns.values():  # compile, fill the predictor history
        d.run(20)
    times = {k: [] for k in dyns}
    stats = {k: [0, 0, 0] for k in dyns}
    for _ in range(args.rounds):
        for name, d in dyns.items():
            it0, steps0 = d.total_iterations, d.total_steps
            geoms = 0

            def count(d=d):
                nonlocal geoms
                geoms += d.geometry_evaluations

            d.attach(count, interval=1)
            t0 = time.perf_counter()
            d.run(args.steps)
            times[name].append((time.perf_counter() - t0) / (args.steps * natoms) * 1e6)
            d.observers.pop()
            s = stats[name]
            s[0] += d.total_iterations - it0
            s[1] += d.total_steps - steps0
            s[2] += geoms
    print(describe())
    print(f"fcc Co, N = {natoms}, dt = {args.dt} fs, T = {T} K (Langevin: λ = 0.1, "
          f"γ = 0.01/fs); {args.rounds} alternating rounds of {args.steps} steps")
    print(f"{'':>10} {'µs/atom-step':>13} {'sweeps/step':>12} {'geoms/step':>11}")
    for name in dyns:
        it, st, ge = stats[name]
        print(f"{name:>10} {np.median(times[name]):13.3f} {it / st:12.2f} {ge / st:11.2f}")
    ratios = np.array(times["Langevin"]) / np.array(times["NVE"])
    print(f"ratio Langevin/NVE: {np.median(times['Langevin']) / np.median(times['NVE']):.3f} "
          f"(per round {ratios.min():.3f}–{ratios.max():.3f})")


if __name__ == "__main__":
    main()
