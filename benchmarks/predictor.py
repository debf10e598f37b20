"""How well the midpoint predictor's rows extrapolate, and what a step costs,
CollectivePRK order 2 on the fcc Co work–precision scene (N = 500, 0.5 ps).

    PYTHONPATH=TREE python benchmarks/predictor.py [--dts 0.1 0.15 0.25] [--repeats 3]
    PYTHONPATH=TREE python benchmarks/predictor.py --timing-only     # another tree

1. The increments W − s of 400 steps at 0.15 fs are recorded (the general
   path: CollectivePRK._remember_midpoint), and each row of the predictor's
   coefficient table (kernels.COEFFICIENTS: exact orders, and this tree's
   least-squares row if it has one) predicts every increment from the 16
   before it: median and largest max-norm error over the steps.
2. Wall time of the whole 0.5 ps run (``dyn.run``, the compiled blocks; the
   pair-list code warmed up first as benchmarks/work_precision.py does),
   the best of ``--repeats``, µs per step and sweeps per step. Run it in two
   trees one after the other (``--timing-only`` in a tree without the
   least-squares row) for a before/after; the machine and load printed first.
"""

import argparse
import os
import sys
import time
import warnings

import numpy as np
from ase import units

sys.path.insert(0, os.path.dirname(__file__))

from ase_spin import CollectivePRK  # noqa: E402
from ase_spin.md import kernels  # noqa: E402
from machine import describe  # noqa: E402
from work_precision import fcc_scene, warm_up_list_updates  # noqa: E402

T_FS = 500.0


def record_increments(dt_fs, steps):
    """The midpoint increments W − s of ``steps`` steps (general path)."""
    from ase_spin.md import fused

    saved = fused.collective_step, fused.collective_block
    fused.collective_step = lambda *args: None
    fused.collective_block = lambda *args: (0, 0, 0, 0)
    increments = []
    original = CollectivePRK._remember_midpoint

    def spy(self, stage, W):
        increments.append(W - self._state.s)
        return original(self, stage, W)

    CollectivePRK._remember_midpoint = spy
    try:
        CollectivePRK(fcc_scene(5), dt_fs * units.fs).run(steps)
    finally:
        CollectivePRK._remember_midpoint = original
        fused.collective_step, fused.collective_block = saved
    return np.array(increments)


def row_errors(X):
    """Per row of the coefficient table: (median, max) over steps of the
    max-norm error predicting X[n + 1] from X[n], X[n − 1], …"""
    depth = kernels.COEFFICIENTS.shape[1]
    out = []
    for k, c in enumerate(kernels.COEFFICIENTS):
        errors = [np.abs(np.tensordot(c, X[n - np.arange(depth)], axes=1) - X[n + 1]).max()
                  for n in range(40, len(X) - 1)]
        out.append((k, float(np.median(errors)), float(np.max(errors)), float(np.abs(c).sum())))
    return out


def timing(dt_fs, repeats):
    warm_up_list_updates(lambda: fcc_scene(5), "prk", {}, dt_fs * units.fs, {})
    steps = int(round(T_FS / dt_fs))
    walls = []
    for _ in range(repeats):
        dyn = CollectivePRK(fcc_scene(5), dt_fs * units.fs)
        t0 = time.perf_counter()
        dyn.run(steps)
        walls.append(time.perf_counter() - t0)
    return min(walls), steps, dyn.mean_iterations


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--dts", type=float, nargs="+", default=[0.1, 0.15, 0.25])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--timing-only", action="store_true")
    args = parser.parse_args(argv)
    warnings.simplefilter("ignore")
    print(describe(), f"\n# load {os.getloadavg()[0]:.2f}", flush=True)
    if not args.timing_only:
        X = record_increments(0.15, 400)
        print("# predicting each increment at 0.15 fs from the ones before it "
              f"(|W − s| up to {np.abs(X).max():.3f})")
        print("# row  median_err  max_err  sum|c|")
        seen = set()
        for k, med, big, gain in row_errors(X):
            key = tuple(kernels.COEFFICIENTS[k])
            if key in seen:  # a row repeating another (a stand-in)
                continue
            seen.add(key)
            print(f"{k:5d}  {med:.2e}  {big:.2e}  {gain:7.0f}", flush=True)
    print("# dt_fs  wall_s  us_per_step  sweeps_per_step")
    for dt in args.dts:
        wall, steps, sweeps = timing(dt, args.repeats)
        print(f"{dt:6.3g}  {wall:7.4f}  {wall / steps * 1e6:7.1f}  {sweeps:6.3f}", flush=True)


if __name__ == "__main__":
    main()
