"""Midpoint sweeps and wall time per step of CollectivePRK on fcc Co (N = 500),
lattice frozen and moving, at the step sizes where the solver works hardest.

    PYTHONPATH=TREE python benchmarks/sweeps_per_step.py     # one source tree

For each (lattice, order, dt): 10 steps to fill the predictor, then 40 steps
timed (``dyn.run``, default solver "auto" and threads), sweeps per step over
those 40 and the stages "auto" switched to Anderson. Run it in two trees one
after the other for a before/after (the machine and load printed first).
"""

import os
import sys
import time
import warnings

from ase import units

sys.path.insert(0, os.path.dirname(__file__))

from ase_spin import CollectivePRK  # noqa: E402
from ase_spin.scenes import fcc_cobalt  # noqa: E402
from machine import describe  # noqa: E402

CASES = ((4, 1.0), (4, 1.25), (4, 2.0), (2, 0.25), (2, 0.5), (6, 2.0))


def main():
    warnings.simplefilter("ignore")  # the TimestepWarning of large steps is the point here
    print(describe(), f"\n# load {os.getloadavg()[0]:.2f}", flush=True)
    for lattice in ("frozen", "moving"):
        for order, dt in CASES:
            atoms = fcc_cobalt(5)
            dyn = CollectivePRK(atoms, dt * units.fs, order=order, lattice=lattice)
            dyn.run(10)
            n0, s0 = dyn.total_steps, dyn.total_iterations
            t0 = time.perf_counter()
            dyn.run(40)
            wall = time.perf_counter() - t0
            sweeps = (dyn.total_iterations - s0) / (dyn.total_steps - n0)
            anderson = sorted(stage for stage, _ in dyn._state.modes)
            print(f"{lattice:6s} order {order} dt {dt:4.2f} fs: {sweeps:6.1f} sweeps/step, "
                  f"{wall / 40 * 1e3:5.2f} ms/step, Anderson stages {anderson}", flush=True)


if __name__ == "__main__":
    main()
