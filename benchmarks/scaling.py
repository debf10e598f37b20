"""Throughput and scaling of CollectivePRK on fcc Co: µs per atom-step and peak
memory against N (500 to 10⁶), one thread against two, sweeps per step against dt.

    python benchmarks/scaling.py [--sizes 5 10 20 40 63] [--threads 1 2] [--dts ...]
    python benchmarks/scaling.py --sizes 63 136 --threads 2 --dts     # 10⁶ and 10⁷ atoms only

Each (N, threads) runs in its own process (numba's thread count is fixed per
process, and peak memory is per process): the scene is built, two warm-up steps
run (neighbour list, kernels loaded), then timed steps. Peak memory is the
process's maximum resident set size.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))


def child(n, steps, dt_fs):
    import resource
    import time

    import numba
    from ase import units

    from ase_spin import CollectivePRK
    from ase_spin.scenes import fcc_cobalt

    t0 = time.perf_counter()
    atoms = fcc_cobalt(n)
    dyn = CollectivePRK(atoms, dt_fs * units.fs)
    dyn.run(2)
    setup = time.perf_counter() - t0
    before = (dyn.total_iterations, dyn.total_steps)
    t0 = time.perf_counter()
    dyn.run(steps)
    wall = time.perf_counter() - t0
    sweeps = (dyn.total_iterations - before[0]) / (dyn.total_steps - before[1])
    peak_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    print(json.dumps({"N": len(atoms), "threads": numba.get_num_threads(), "dt": dt_fs,
                      "us_per_atom_step": wall / steps / len(atoms) * 1e6,
                      "s_per_step": wall / steps, "sweeps": sweeps, "setup_s": setup,
                      "peak_MB": peak_kb / 1024}))


def spawn(n, steps, dt, threads):
    env = dict(os.environ, NUMBA_NUM_THREADS=str(threads))
    out = subprocess.run([sys.executable, __file__, "--child", str(n), str(steps), str(dt)],
                         env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None):
    parser = argparse.ArgumentParser()
    parser.add_argument("--sizes", type=int, nargs="+", default=[5, 10, 20, 40, 63])
    parser.add_argument("--threads", type=int, nargs="+", default=[2, 1])
    parser.add_argument("--dts", type=float, nargs="*", default=[0.05, 0.1, 0.2, 0.5, 1.0, 2.0])
    parser.add_argument("--child", nargs=3, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        child(int(args.child[0]), int(args.child[1]), float(args.child[2]))
        return
    sys.path.insert(0, HERE)
    from machine import describe

    print(describe())
    print("# fcc Co, dt = 0.1 fs, order 2")
    print(f"{'N':>9} {'threads':>7} {'µs/atom-step':>13} {'s/step':>8} {'sweeps':>7} "
          f"{'setup s':>8} {'peak MB':>8} {'B/atom':>7}")
    for n in args.sizes:
        for threads in args.threads:
            if threads == 1 and n > 20:
                continue  # one thread at the largest sizes: the trend is clear by then
            steps = max(3, int(4e6 / (4 * n**3)))
            r = spawn(n, steps, 0.1, threads)
            print(f"{r['N']:9d} {r['threads']:7d} {r['us_per_atom_step']:13.3f} "
                  f"{r['s_per_step']:8.4f} {r['sweeps']:7.2f} {r['setup_s']:8.1f} "
                  f"{r['peak_MB']:8.0f} {r['peak_MB'] * 2**20 / r['N']:7.0f}", flush=True)
    if args.dts:
        print("# sweeps per step against dt, N = 4000, 2 threads")
    for dt in args.dts:  # none: skipped
        r = spawn(10, max(20, int(40 / dt)), dt, max(args.threads))
        print(f"dt {dt:5.2f} fs: {r['sweeps']:6.2f} sweeps/step, "
              f"{r['us_per_atom_step']:.3f} µs/atom-step", flush=True)


if __name__ == "__main__":
    main()
