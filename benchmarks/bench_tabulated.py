"""Step cost of a tabulated exchange J(r) against the compiled Cubic form.

    python benchmarks/bench_tabulated.py [--sizes 5 10] [--steps 20] [--rounds 5]

fcc Co scene (peers.md: LJ shifted, 100 K, 30° cone), exchange J(r) = 0.3 (1 − r/4.2)³ eV
either as the compiled ``Cubic(0.3, 4.2)`` or as ``Tabulated`` through 12 points of the
same curve (numpy spline evaluation per step). CollectivePRK at 0.5 fs; the two runs
alternate, so the ratio is measured under the same load; CPU seconds of the process (all
threads) per atom-step in µs, medians: less sensitive than wall time to other processes.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np
from ase import units

sys.path.insert(0, os.path.dirname(__file__))

from ase_spin import (CollectivePRK, Cubic, Exchange, LennardJones,  # noqa: E402
                      SpinLatticeCalculator, Tabulated)
from ase_spin.scenes import fcc_cobalt  # noqa: E402
from machine import describe  # noqa: E402


def dynamics(n, coupling):
    atoms = fcc_cobalt(n)
    atoms.calc = SpinLatticeCalculator([
        LennardJones(epsilon=0.4, sigma=2.2742, rc=4.7, cutoff="shift"), Exchange(coupling)])
    dyn = CollectivePRK(atoms, 0.5 * units.fs)
    dyn.run(2)  # compile, build the pair lists
    return dyn, len(atoms)


def main(argv=None):
    parser = argparse.ArgumentParser()
    parser.add_argument("--sizes", type=int, nargs="+", default=[5, 10])
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--rounds", type=int, default=5)
    args = parser.parse_args(argv)
    r = np.linspace(2.0, 4.2, 12)
    print(describe())
    print("| N | Cubic (compiled) µs/atom-step | Tabulated µs/atom-step | ratio |")
    print("|---|---|---|---|")
    for n in args.sizes:
        runs = {"cubic": dynamics(n, Cubic(0.3, 4.2)),
                "tab": dynamics(n, Tabulated(r, 0.3 * (1 - r / 4.2) ** 3))}
        times = {k: [] for k in runs}
        for _ in range(args.rounds):
            for k, (dyn, natoms) in runs.items():
                t0 = time.process_time()
                dyn.run(args.steps)
                times[k].append((time.process_time() - t0) / (args.steps * natoms) * 1e6)
        c, t = np.median(times["cubic"]), np.median(times["tab"])
        ratios = np.array(times["tab"]) / np.array(times["cubic"])
        print(f"| {runs['cubic'][1]} | {c:.2f} | {t:.2f} | {np.median(ratios):.2f} "
              f"({ratios.min():.2f}–{ratios.max():.2f}) |")


if __name__ == "__main__":
    main()
