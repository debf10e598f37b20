"""Time and memory of one neighbour-list build on fcc Co (rattled), cutoff
4.7 + 0.3 Å, and of the two sub-lists the LJ + exchange scene asks for.

    python benchmarks/neighbor_build.py [--sizes 20 40 63]

Each size in its own process (peak = its maximum resident set; rise = above
the peak before the build, the kernels loaded on a small cell first).
"""

import argparse
import json
import os
import subprocess
import sys


def child(n):
    import resource
    import time

    from ase.build import bulk

    from ase_spin.neighbors import NeighborCache

    a = bulk("Co", "fcc", a=3.54, cubic=True).repeat(n)
    a.rattle(0.02, seed=1)
    small = bulk("Co", "fcc", a=3.54, cubic=True).repeat(3)
    NeighborCache(4.7, 0.3).update(small.positions, small.cell.array, small.pbc)
    r0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    cache = NeighborCache(4.7, 0.3)
    t0 = time.perf_counter()
    cache.update(a.positions, a.cell.array, a.pbc)
    t1 = time.perf_counter()
    cache.sublist(4.0, half=True)
    cache.sublist(4.7, half=True)
    t2 = time.perf_counter()
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    print(json.dumps({"N": len(a), "build_s": t1 - t0, "sublists_s": t2 - t1,
                      "peak_MB": peak / 1024, "rise_MB": (peak - r0) / 1024}))


def main(argv=None):
    parser = argparse.ArgumentParser()
    parser.add_argument("--sizes", type=int, nargs="+", default=[20, 40, 63])
    parser.add_argument("--child", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        child(args.child)
        return
    here = os.path.dirname(os.path.abspath(__file__))
    sys.path.insert(0, here)
    from machine import describe

    print(describe(), f"load {os.getloadavg()[0]:.1f}")
    print(f"{'N':>9} {'build s':>8} {'sublists s':>10} {'peak MB':>8} {'rise MB':>8}")
    for n in args.sizes:
        out = subprocess.run([sys.executable, __file__, "--child", str(n)], check=True,
                             capture_output=True, text=True).stdout
        r = json.loads(out.strip().splitlines()[-1])
        print(f"{r['N']:9d} {r['build_s']:8.2f} {r['sublists_s']:10.2f} {r['peak_MB']:8.0f} "
              f"{r['rise_MB']:8.0f}", flush=True)


if __name__ == "__main__":
    main()
