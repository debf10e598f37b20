"""CollectivePRK on a frozen lattice, two source trees against each other (e.g.
before and after a change to the spins-only step), alternating in one run.

    python benchmarks/frozen_before_after.py --trees /path/to/before /path/to/after \
        [--cells 5 10] [--points 2:0.05 2:0.25 2:1 4:0.5 4:1 4:2] [--repeats 3]

Scene: fcc Co (``ase_spin.scenes.fcc_cobalt``, 4 n³ atoms: 500 at n = 5, 4000 at
n = 10), its exchange and Lennard-Jones terms, ``lattice="frozen"``, the default
solver; each point ``order:dt_fs`` runs 25 fs (at least 20 steps) after a few
untimed steps. Each measurement runs in a fresh process with PYTHONPATH set to
the tree, its kernels compiled and loaded first (untimed), the trees alternating
within every repeat. Prints per tree, size and point: µs per atom-step (median
of --repeats), midpoint sweeps per step, the sweep order each stage ended in
(0 index, 1 colour, 2 index for good; "-" before there was a choice), and
the largest difference of the two trees' final spins.
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
POINTS = ["2:0.05", "2:0.25", "2:1", "4:0.5", "4:1", "4:2"]

CHILD = r"""
import json, time, warnings
warnings.simplefilter("ignore")
import numpy as np
from ase import units
from ase_spin import CollectivePRK, get_spins
from ase_spin.scenes import fcc_cobalt
cells, order, dt = {cells!r}, {order!r}, {dt!r}
steps = max(20, int(round(25.0 / dt)))
for warm in range(2):  # the first compiles (or loads) every kernel the run needs
    atoms = fcc_cobalt(cells)
    dyn = CollectivePRK(atoms, dt * units.fs, order=order, lattice="frozen")
    dyn.run(3)
    before = dyn.total_iterations
    t0 = time.perf_counter()
    dyn.run(steps if warm else 4)
    wall = time.perf_counter() - t0
st = dyn._state
print(json.dumps(dict(us=wall / steps / len(atoms) * 1e6,
                      sweeps=(dyn.total_iterations - before) / steps,
                      orders=[int(x) for x in getattr(st, "sweep_order", [])],
                      spins=get_spins(atoms).ravel().tolist())))
"""


def child(tree, cells, order, dt):
    env = dict(os.environ, PYTHONPATH=tree)
    code = CHILD.format(cells=cells, order=order, dt=dt)
    code += f"import ase_spin; assert ase_spin.__file__.startswith({tree!r})\n"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         cwd=tree)
    if out.returncode:
        raise RuntimeError(out.stderr[-2000:])
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--trees", nargs=2, required=True)
    ap.add_argument("--cells", type=int, nargs="+", default=[5, 10])
    ap.add_argument("--points", nargs="+", default=POINTS, help="order:dt_fs")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    points = [(int(p.split(":")[0]), float(p.split(":")[1])) for p in args.points]
    sys.path.insert(0, HERE)
    from machine import describe

    print(describe(), flush=True)
    results = {}
    for rep in range(args.repeats):
        for cells in args.cells:
            for order, dt in points:
                for tree in args.trees:
                    r = child(os.path.abspath(tree), cells, order, dt)
                    r["load"] = os.getloadavg()[0]
                    results.setdefault((tree, cells, order, dt), []).append(r)
        print(f"# repeat {rep + 1} done, load {os.getloadavg()[0]:.2f}", flush=True)
    before, after = args.trees
    print(f"\n{'atoms':>6s} {'order':>5s} {'dt fs':>6s} {'before us':>10s} {'after us':>9s} "
          f"{'after/before':>12s} {'sweeps':>13s} {'orders after':>14s} {'max |ds|':>9s} "
          f"{'load':>9s}")
    for cells in args.cells:
        for order, dt in points:
            b = results[(before, cells, order, dt)]
            a = results[(after, cells, order, dt)]
            tb = np.median([r["us"] for r in b])
            ta = np.median([r["us"] for r in a])
            ds = np.abs(np.array(a[0]["spins"]) - np.array(b[0]["spins"])).max()
            loads = [r["load"] for r in a + b]
            orders = "".join(map(str, a[0]["orders"])) or "-"
            print(f"{4 * cells ** 3:6d} {order:5d} {dt:6.3g} {tb:10.3f} {ta:9.3f} {ta / tb:12.2f} "
                  f"{b[0]['sweeps']:6.1f}->{a[0]['sweeps']:5.1f} {orders:>14s} {ds:9.1e} "
                  f"{min(loads):4.1f}-{max(loads):3.1f}")


if __name__ == "__main__":
    main()
