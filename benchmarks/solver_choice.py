"""Which midpoint solver is cheapest at which step size: CollectivePRK's solvers
side by side on the fcc Co work–precision scene (work_precision.py's ``fcc500``:
N = 500, 0.5 ps, LAMMPS's ħ), wall time and midpoint sweeps per step.

    python benchmarks/solver_choice.py [--repeats 3] [--points 2:0.1 2:0.25 4:1 ...]

Each point (order:dt in fs) runs every solver for the whole 0.5 ps after a short
warm-up run (compilation, caches); the solvers alternate within every repeat, so
load from other jobs hits them alike. Prints the median wall time over the
repeats, its ratio to "auto" (the default), and the sweeps per step. All
solvers solve the same equation to the same tolerance (docs/dynamics.md, "The
midpoint solver"): this measures cost only.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np
from ase import units

sys.path.insert(0, os.path.dirname(__file__))
sys.path.insert(0, os.environ.get("ASE_SPIN_TREE") or os.path.join(os.path.dirname(__file__), ".."))

from ase_spin import CollectivePRK  # noqa: E402
from machine import describe  # noqa: E402
from work_precision import HBAR_LAMMPS, fcc_scene  # noqa: E402

SOLVERS = ("auto", "jacobi", "local", "anderson")
POINTS = ("2:0.1", "2:0.15", "2:0.25", "2:0.5", "4:0.5", "4:1", "4:2")
T_FS = 500.0


def run(order, dt, solver):
    """(wall seconds for 0.5 ps, sweeps per step), or (nan, nan) if the solver failed."""
    kw = dict(hbar=HBAR_LAMMPS, order=order, solver=solver)
    CollectivePRK(fcc_scene(5), dt * units.fs, **kw).run(10)
    dyn = CollectivePRK(fcc_scene(5), dt * units.fs, **kw)
    t0 = time.perf_counter()
    try:
        dyn.run(int(round(T_FS / dt)))
    except Exception as err:  # a solver that does not converge at this dt
        print(f"  order {order}, {dt} fs, {solver}: {type(err).__name__}")
        return np.nan, np.nan
    return time.perf_counter() - t0, dyn.total_iterations / dyn.total_steps


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--points", nargs="+", default=list(POINTS), help="order:dt_fs")
    ap.add_argument("--solvers", nargs="+", default=list(SOLVERS))
    args = ap.parse_args(argv)
    print(describe())
    print(f"fcc Co N = 500, {T_FS:g} fs per run, {args.repeats} repeats, load "
          f"{os.getloadavg()[0]:.2f}", flush=True)
    import warnings

    warnings.simplefilter("ignore")  # the timestep warnings of the large steps
    points = [(int(p.split(":")[0]), float(p.split(":")[1])) for p in args.points]
    wall = {(pt, s): [] for pt in points for s in args.solvers}
    sweeps = {}
    for _ in range(args.repeats):
        for pt in points:
            for solver in args.solvers:
                w, sw = run(*pt, solver)
                wall[(pt, solver)].append(w)
                sweeps[(pt, solver)] = sw
    print(f"load after: {os.getloadavg()[0]:.2f}")
    print(f"{'order':>5} {'dt fs':>6} " + " ".join(f"{s:>22}" for s in args.solvers))
    for pt in points:
        base = np.median(wall[(pt, "auto")]) if "auto" in args.solvers else np.nan
        cells = []
        for s in args.solvers:
            w = np.median(wall[(pt, s)])
            cells.append(f"{w:6.3f} s {w / base:5.2f}× {sweeps[(pt, s)]:5.1f}sw")
        print(f"{pt[0]:5d} {pt[1]:6.3g} " + " ".join(f"{c:>22}" for c in cells))
    print("(each cell: median wall time, its ratio to auto, midpoint sweeps per step)")


if __name__ == "__main__":
    main()
