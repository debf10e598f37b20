"""Peak and resident memory per atom after each step of a CollectivePRK run on
fcc Co (order 2, 0.1 fs), and the step's time and midpoint sweeps: how the
peak grows while the predictor's history fills.

    python benchmarks/memory_steps.py [--n 63] [--steps 16] [--full-depth]

``--full-depth`` keeps all 12 predictor increments whatever the size (raises
``collective.LARGE_SYSTEM`` past N), to see what they would cost. Peak is the
kernel's VmHWM of this process (bytes per atom, set-up included), resident VmRSS.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))


def _status(key):
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(key):
                return int(line.split()[1]) * 1024
    raise KeyError(key)


def main(argv=None):
    parser = argparse.ArgumentParser()
    parser.add_argument("--n", type=int, default=63, help="fcc Co repeats (4n³ atoms)")
    parser.add_argument("--steps", type=int, default=16)
    parser.add_argument("--full-depth", action="store_true")
    args = parser.parse_args(argv)
    sys.path.insert(0, HERE)
    from ase import units
    from machine import describe

    from ase_spin import CollectivePRK
    from ase_spin.md import collective
    from ase_spin.scenes import fcc_cobalt

    print(describe(), f"load {os.getloadavg()[0]:.1f}", flush=True)
    atoms = fcc_cobalt(args.n)
    N = len(atoms)
    if args.full_depth:
        collective.LARGE_SYSTEM = N + 1
    dyn = CollectivePRK(atoms, 0.1 * units.fs)
    print(f"# N = {N}, predictor depth {collective.predictor_depth(1, N)}")
    print(f"{'step':>4} {'peak B/atom':>12} {'RSS B/atom':>11} {'s':>7} {'sweeps':>7}")
    before = 0
    for k in range(args.steps):
        t0 = time.perf_counter()
        dyn.run(1)
        dt = time.perf_counter() - t0
        sweeps, before = dyn.total_iterations - before, dyn.total_iterations
        print(f"{k + 1:4d} {_status('VmHWM') / N:12.0f} {_status('VmRSS') / N:11.0f} "
              f"{dt:7.3f} {sweeps:7d}", flush=True)
    print(f"# load {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    main()
