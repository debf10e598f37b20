"""CollectivePRK on the fcc Co work–precision scene, two source trees against each
other (e.g. before and after a solver change), with LAMMPS, alternating in one run.

    PYTHONPATH=. LD_LIBRARY_PATH=$VIRTUAL_ENV/lib python benchmarks/solver_before_after.py \
        --trees /path/to/before /path/to/after [--repeats 3] [--points 2:0.1 4:1 ...]
        [--lammps-dt 0.5 0.2 0.1]   # no values: no LAMMPS runs

The scene and reference are benchmarks/work_precision.py's `fcc500` (N = 500, 0.5 ps,
DOP853 reference). Each measurement runs in a fresh process with PYTHONPATH set to
the tree (kernels compiled and loaded there first, untimed); the trees and LAMMPS
alternate within every repeat, so load from other jobs hits them alike. Prints per
tree and point: wall time (median of --repeats), spin RMS error against the
reference, midpoint sweeps per step, and the load average when it ran.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
POINTS = [(4, 2.0), (4, 1.5), (4, 1.25), (4, 1.0), (4, 0.5), (2, 0.1)]
LAMMPS_DT = [0.5, 0.2, 0.1]

CHILD = r"""
import json, sys, time, warnings
sys.path.insert(0, {bench!r})
warnings.simplefilter("ignore")
import numpy as np
from ase import units
from work_precision import fcc_scene, HBAR_LAMMPS, rms, run_lammps
kind, order, dt = {kind!r}, {order!r}, {dt!r}
if kind == "lammps":
    wall, x, s, _ = run_lammps(5, dt, 500.0)
    sweeps = float("nan")
else:
    from ase_spin import CollectivePRK, get_spins
    warm = fcc_scene(5)
    CollectivePRK(warm, dt * units.fs, order=order, hbar=HBAR_LAMMPS).run(4)  # + a block
    atoms = fcc_scene(5)
    dyn = CollectivePRK(atoms, dt * units.fs, order=order, hbar=HBAR_LAMMPS)
    steps = int(round(500.0 / dt))
    t0 = time.perf_counter()
    dyn.run(steps)
    wall = time.perf_counter() - t0
    s = get_spins(atoms)
    sweeps = dyn.mean_iterations
sr = np.load({ref!r})
print(json.dumps(dict(wall=wall, err=rms(s, sr), sweeps=sweeps)))
"""


def reference(path):
    code = (f"import sys; sys.path.insert(0, {HERE!r}); import numpy as np; "
            "from ase import units; from work_precision import fcc_scene, HBAR_LAMMPS; "
            "from ase_spin.md.ode import reference_solution; "
            "xr, _, sr = reference_solution(fcc_scene(5), 500 * units.fs, hbar=HBAR_LAMMPS); "
            f"np.save({path!r}, sr)")
    subprocess.run([sys.executable, "-c", code], check=True, env=os.environ)


def child(tree, kind, order, dt, ref):
    env = dict(os.environ)
    env["PYTHONPATH"] = tree or os.path.dirname(HERE)  # LAMMPS: this tree's scene code
    code = CHILD.format(bench=HERE, kind=kind, order=order, dt=dt, ref=ref)
    code += f"import ase_spin; assert ase_spin.__file__.startswith({tree or ''!r}), ase_spin.__file__\n"
    # run from the tree (python -c puts the working directory first on sys.path)
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         cwd=tree or tempfile.gettempdir())
    if out.returncode:
        raise RuntimeError(out.stderr[-2000:])
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--trees", nargs=2, required=True)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--points", nargs="+", default=[f"{o}:{dt:g}" for o, dt in POINTS],
                    help="order:dt_fs (default: %(default)s)")
    ap.add_argument("--lammps-dt", nargs="*", type=float, default=LAMMPS_DT,
                    help="LAMMPS's steps, fs (none: no LAMMPS runs)")
    args = ap.parse_args(argv)
    points = [(int(p.split(":")[0]), float(p.split(":")[1])) for p in args.points]
    sys.path.insert(0, HERE)
    from machine import describe

    print(describe(), flush=True)
    ref = os.path.join(tempfile.mkdtemp(), "ref.npy")
    reference(ref)
    results = {}
    for rep in range(args.repeats):
        for order, dt in points:
            for tree in args.trees:
                r = child(tree, "prk", order, dt, ref)
                r["load"] = os.getloadavg()[0]
                results.setdefault((tree, order, dt), []).append(r)
        for dt in args.lammps_dt:
            r = child(None, "lammps", None, dt, ref)
            r["load"] = os.getloadavg()[0]
            results.setdefault(("LAMMPS", None, dt), []).append(r)
        print(f"# repeat {rep + 1} done, load {os.getloadavg()[0]:.2f}", flush=True)
    print(f"\n{'tree':40s} {'order':>5s} {'dt fs':>6s} {'wall s':>8s} {'spin RMS':>9s} "
          f"{'sweeps/step':>11s} {'load':>10s}")
    for (tree, order, dt), rs in results.items():
        walls = [r["wall"] for r in rs]
        loads = [r["load"] for r in rs]
        print(f"{tree:40s} {order if order else '-':>5} {dt:6.3g} {np.median(walls):8.3f} "
              f"{rs[0]['err']:9.2e} {rs[0]['sweeps']:11.1f} {min(loads):4.1f}-{max(loads):4.1f}")
    before, after = args.trees
    print("\nafter/before wall-time ratio per point:")
    for order, dt in points:
        b = np.median([r["wall"] for r in results[(before, order, dt)]])
        a = np.median([r["wall"] for r in results[(after, order, dt)]])
        print(f"  order {order} dt {dt:g} fs: {a / b:.2f}")


if __name__ == "__main__":
    main()
