"""LJ + exchange step time of both integrators, for comparing code versions.

    python benchmarks/step_time.py                                  # this tree
    python benchmarks/step_time.py --compare OLD_TREE NEW_TREE --rounds 3 [--sizes 10 20]

fcc Co (peers.md scene) at N = 500 and 4 000 (``--sizes``: repeats n, 4n³ atoms), 0.1 fs, default threads; median
of 5 × 20 steps after 5 warm-up steps, µs per atom-step. ``--compare`` runs the
measurement in a fresh process per tree (PYTHONPATH set to it), alternating
the trees round by round (a worktree of an older commit: ``git worktree add
/tmp/old <commit>``), after one warm-up run of each (numba's caches).
"""

import argparse
import json
import os
import subprocess
import sys
import time


def measure(sizes=(5, 10)):
    import numpy as np
    from ase import units

    from ase_spin import CollectivePRK, SuzukiTrotter
    from ase_spin.scenes import fcc_cobalt

    out = {}
    for n in sizes:
        for cls in (CollectivePRK, SuzukiTrotter):
            atoms = fcc_cobalt(n)
            dyn = cls(atoms, 0.1 * units.fs)
            dyn.run(5)
            times = []
            for _ in range(5):
                t0 = time.perf_counter()
                dyn.run(20)
                times.append((time.perf_counter() - t0) / 20 / len(atoms) * 1e6)
            out[f"{cls.__name__} N={len(atoms)}"] = round(float(np.median(times)), 4)
    return out


def main(argv=None):
    parser = argparse.ArgumentParser()
    parser.add_argument("--compare", nargs=2, metavar=("OLD_TREE", "NEW_TREE"))
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--sizes", type=int, nargs="+", default=[5, 10])
    args = parser.parse_args(argv)
    if not args.compare:
        print(json.dumps(measure(args.sizes)))
        return
    sys.path.insert(0, os.path.dirname(__file__))
    sys.path.insert(0, os.path.abspath(args.compare[1]))  # describe() names the new tree's version
    from machine import describe

    print(describe(), f"load {os.getloadavg()[0]:.1f}", flush=True)
    script = os.path.abspath(__file__)

    def run(tree):
        env = dict(os.environ, PYTHONPATH=os.path.abspath(tree))
        sizes = [str(n) for n in args.sizes]
        out = subprocess.run([sys.executable, script, "--sizes", *sizes], cwd=tree, env=env, check=True,
                             capture_output=True, text=True).stdout
        return json.loads(out.strip().splitlines()[-1])

    for tree in args.compare:  # warm numba's caches
        run(tree)
    for r in range(args.rounds):
        for label, tree in zip(("old", "new"), args.compare):
            print(f"round {r + 1} {label} {json.dumps(run(tree))}", flush=True)


if __name__ == "__main__":
    main()
