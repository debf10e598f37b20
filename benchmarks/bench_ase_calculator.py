"""What an ASE calculator as the lattice part costs per step, against the calculator alone.

    python benchmarks/bench_ase_calculator.py [--n 6] [--steps 10] [--repeats 5]

fcc Ni (4n³ atoms, a = 3.52 Å, rattled 0.05 Å, random spins of 0.6 μB) with ASE's EMT.
Prints the median time (ms) of: one EMT calculation (energy + forces, positions
changed each time); a step of ASE's VelocityVerlet with EMT; a step of
CollectivePRK with [EMT()] (no spin terms: velocity Verlet) and with
[EMT(), Exchange] (rc = 3.0 Å), and each one's ratio to the EMT calculation.
The variants run interleaved, repeat by repeat, so that load on the machine
affects them alike: compare the ratios, not the times.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np
from ase import units
from ase.build import bulk
from ase.calculators.emt import EMT
from ase.md.verlet import VelocityVerlet

sys.path.insert(0, os.path.dirname(__file__))

from ase_spin import (BetheSlater, CollectivePRK, Exchange, SpinLatticeCalculator,  # noqa: E402
                      set_spins)
from machine import describe  # noqa: E402


def nickel(n):
    atoms = bulk("Ni", "fcc", a=3.52, cubic=True).repeat(n)
    atoms.rattle(0.05, seed=1)
    rng = np.random.default_rng(1)
    set_spins(atoms, rng.normal(size=(len(atoms), 3)), 0.6)
    return atoms


def main(argv=None):
    parser = argparse.ArgumentParser()
    parser.add_argument("--n", type=int, default=6)
    parser.add_argument("--steps", type=int, default=10)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)
    dt = 1.0 * units.fs
    exchange = Exchange(BetheSlater(0.0446928, 0.003496, 1.4885), rc=3.0)

    alone = nickel(args.n)
    alone.calc = EMT()

    def emt_call():
        alone.positions[0, 0] += 1e-6  # a new state each time
        alone.get_forces()

    runs = {}
    ase_atoms = nickel(args.n)
    ase_atoms.calc = EMT()
    ase_dyn = VelocityVerlet(ase_atoms, dt)
    runs["ASE VelocityVerlet + EMT"] = lambda: ase_dyn.run(args.steps)
    for name, terms in (("CollectivePRK, [EMT()]", [EMT()]),
                        ("CollectivePRK, [EMT(), Exchange]", [EMT(), exchange])):
        atoms = nickel(args.n)
        atoms.calc = SpinLatticeCalculator(terms)
        dyn = CollectivePRK(atoms, dt)
        dyn.run(2)  # compile, bind
        runs[name] = (lambda d: lambda: d.run(args.steps))(dyn)
    emt_call()
    times = {"one EMT calculation": []}
    times.update({k: [] for k in runs})
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        for _ in range(args.steps):
            emt_call()
        times["one EMT calculation"].append((time.perf_counter() - t0) / args.steps)
        for name, run in runs.items():
            t0 = time.perf_counter()
            run()
            times[name].append((time.perf_counter() - t0) / args.steps)
    print(describe())
    print(f"# fcc Ni, N = {len(alone)}, {args.steps} steps x {args.repeats} repeats, "
          "interleaved")
    ref = np.median(times["one EMT calculation"])
    print(f"{'':36s} {'ms':>8s} {'/ EMT call':>10s}")
    for name, t in times.items():
        m = np.median(t)
        print(f"{name:36s} {1e3 * m:8.2f} {m / ref:10.2f}")


if __name__ == "__main__":
    main()
