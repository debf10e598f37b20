"""Long runs: energy error, its drift, spin lengths and momentum over many steps.

    python benchmarks/long_run.py chain --steps 100000 --dt 0.015625
    python benchmarks/long_run.py fcc --n 5 --steps 100000 --dt 0.1

chain: the paper's experiment (ħ = 1, spin convention, dt in its time units);
fcc: the peers.md fcc Co scene (moment convention, dt in fs). Prints the largest
energy error, a straight line fitted to the energy error against time (its
change over the run, beside the error's own spread), the largest | |s_i| − 1 |
(no renormalisation anywhere) and the change of total momentum.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np
from ase import units

sys.path.insert(0, os.path.dirname(__file__))

from ase_spin import CollectivePRK  # noqa: E402
from ase_spin.scenes import fcc_cobalt, paper_chain  # noqa: E402
from machine import describe  # noqa: E402


def main(argv=None):
    parser = argparse.ArgumentParser()
    parser.add_argument("scene", choices=["chain", "fcc"])
    parser.add_argument("--steps", type=int, default=100_000)
    parser.add_argument("--dt", type=float, default=None)
    parser.add_argument("--n", type=int, default=5)
    parser.add_argument("--order", type=int, default=2)
    parser.add_argument("--samples", type=int, default=2000)
    args = parser.parse_args(argv)
    if args.scene == "chain":
        atoms = paper_chain()
        dt = args.dt or 2.0**-6
        dyn = CollectivePRK(atoms, dt, hbar=1.0, precession="spin", order=args.order)
        label = f"paper chain, h = {dt:g}"
    else:
        atoms = fcc_cobalt(args.n)
        dt = args.dt or 0.1
        dyn = CollectivePRK(atoms, dt * units.fs, order=args.order)
        label = f"fcc Co N = {len(atoms)}, dt = {dt:g} fs"
    e0 = dyn.get_total_energy()
    p0 = atoms.get_momenta().sum(axis=0)
    times, errors, lengths = [], [], []

    def record():
        times.append(dyn.get_time())
        errors.append(dyn.get_total_energy() - e0)
        s = dyn._state.s[dyn.ev.magnetic]
        lengths.append(float(np.abs(np.sqrt((s * s).sum(axis=1)) - 1.0).max()))

    dyn.attach(record, interval=max(1, args.steps // args.samples))
    t0 = time.perf_counter()
    dyn.run(args.steps)
    wall = time.perf_counter() - t0
    times, errors = np.array(times), np.array(errors)
    slope, intercept = np.polyfit(times, errors, 1)
    residual = errors - (slope * times + intercept)
    print(f"{label}, order {args.order}, {args.steps} steps in {wall:.1f} s "
          f"({wall / args.steps * 1e6:.1f} µs/step), {dyn.mean_iterations:.2f} sweeps/step")
    print(f"energy error: max |E - E0| = {np.abs(errors).max():.3e} eV, std {errors.std():.3e}")
    print(f"fitted drift over the run: {slope * times[-1]:.3e} eV "
          f"(residual std {residual.std():.3e})")
    print(f"spin lengths: max | |s| - 1 | = {max(lengths):.2e}")
    print(f"total momentum change: {np.abs(atoms.get_momenta().sum(axis=0) - p0).max():.2e}")
    print(describe())


if __name__ == "__main__":
    main()
