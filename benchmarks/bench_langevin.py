"""Cost of a thermostatted step (Langevin: both baths on) against an NVE
CollectivePRK step, side by side on the same fcc Co crystal, at two sizes.

    python benchmarks/bench_langevin.py [--n 10 20] [--dt 0.1] [--steps 40] [--rounds 5]
    python benchmarks/bench_langevin.py --compare /work/main   # before/after
    python benchmarks/bench_langevin.py --threads 2            # a fixed thread count
    python benchmarks/bench_langevin.py --warmup 300           # past the first rebuild

``--compare TREE``: this tree's ase_spin and TREE's, each in its own process
(one round per process, the trees alternating round by round), the ratio
Langevin/NVE printed per tree and round, then the medians.

For each size (4n³ atoms: 4 000 and 32 000 by default) the two integrators run
alternately in rounds of ``steps`` steps each (so load changes on the machine
hit both alike, and the sizes are interleaved round by round); printed: the
machine, µs per atom-step (median over rounds), midpoint sweeps and geometry
evaluations per step, and the ratio Langevin/NVE of the round medians with its
range over rounds. No observer is attached (one would add its own work, and change
no number of the run: docs/dynamics.md, "Reproducibility").
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np
from ase import units

sys.path.insert(0, os.path.dirname(__file__))
sys.path.insert(0, os.environ.get("ASE_SPIN_TREE") or os.path.join(os.path.dirname(__file__), ".."))

from ase_spin import CollectivePRK, Langevin  # noqa: E402
from ase_spin.scenes import fcc_cobalt  # noqa: E402
from machine import describe  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, nargs="+", default=[10, 20],
                    help="4n³ atoms (10: 4000, 20: 32000)")
    ap.add_argument("--dt", type=float, default=0.1, help="fs")
    ap.add_argument("--steps", type=int, default=40)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--warmup", type=int, default=20,
                    help="steps before timing (compilation, the predictor's history); 300 "
                         "takes fcc Co at 300 K and 0.1 fs past its first pair-list rebuild, "
                         "the steady state of a long run")
    ap.add_argument("--temperature", type=float, default=300.0)
    ap.add_argument("--compare", default=None, help="another source tree (before/after)")
    ap.add_argument("--threads", default="auto",
                    help='"auto" (the default, as users run) or a fixed count: "auto" probes '
                         "the other count now and then, which scatters short rounds")
    ap.add_argument("--json", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.compare:
        return compare(args)
    T = args.temperature
    print(describe())
    print(f"load average before: {os.getloadavg()[0]:.2f}")
    dyns = {}
    for n in args.n:
        dyns[n] = {
            "NVE": CollectivePRK(fcc_cobalt(n, temperature_K=T), args.dt * units.fs,
                                 threads=args.threads),
            "Langevin": Langevin(fcc_cobalt(n, temperature_K=T), args.dt * units.fs, T,
                                 spin_damping=0.1, friction=0.01 / units.fs, rng=1,
                                 threads=args.threads),
        }
        for d in dyns[n].values():  # compile, fill the predictor history
            d.run(args.warmup)
    times = {n: {k: [] for k in dyns[n]} for n in dyns}
    stats = {n: {k: [0, 0, 0] for k in dyns[n]} for n in dyns}
    for _ in range(args.rounds):
        for n in dyns:
            natoms = 4 * n**3
            for name, d in dyns[n].items():
                it0, steps0 = d.total_iterations, d.total_steps
                geoms = 0
                t0 = time.perf_counter()
                d.run(args.steps)
                times[n][name].append((time.perf_counter() - t0) / (args.steps * natoms) * 1e6)
                s = stats[n][name]
                s[0] += d.total_iterations - it0
                s[1] += d.total_steps - steps0
                s[2] += geoms
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    if args.json:
        print("JSON " + json.dumps({str(4 * n**3): {k: float(np.median(v)) for k, v in
                                                      times[n].items()} for n in times}))
    print(f"fcc Co, dt = {args.dt} fs, T = {T} K (Langevin: λ = 0.1, γ = 0.01/fs); "
          f"{args.rounds} alternating rounds of {args.steps} steps")
    print(f"{'N':>7} {'':>9} {'µs/atom-step':>13} {'sweeps/step':>12} {'ratio (rounds)':>24}")
    for n in dyns:
        natoms = 4 * n**3
        for name in dyns[n]:
            it, st, _ = stats[n][name]
            line = f"{natoms:7d} {name:>9} {np.median(times[n][name]):13.3f} {it / st:12.2f}"
            if name == "Langevin":
                r = np.array(times[n]["Langevin"]) / np.array(times[n]["NVE"])
                med = np.median(times[n]["Langevin"]) / np.median(times[n]["NVE"])
                line += f" {med:10.3f} ({r.min():.3f}–{r.max():.3f})"
            print(line)


def compare(args):
    here = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
    trees = {"this tree": here, "compared": os.path.abspath(args.compare)}
    print(describe())
    print(f"this tree: {here}; compared: {trees['compared']}; {args.rounds} rounds, each tree "
          f"in its own process per round, {args.steps} steps per integrator and size")
    res = {k: [] for k in trees}
    for r in range(args.rounds):
        for name, tree in trees.items():
            cmd = [sys.executable, os.path.abspath(__file__), "--json", "--rounds", "1",
                   "--steps", str(args.steps), "--dt", str(args.dt), "--warmup",
                   str(args.warmup), "--threads", str(args.threads), "--n",
                   *map(str, args.n)]
            env = dict(os.environ, ASE_SPIN_TREE=tree)
            out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True).stdout
            data = json.loads(next(line for line in out.splitlines()
                                   if line.startswith("JSON "))[5:])
            res[name].append(data)
            print(f"round {r} {name:9s} load {os.getloadavg()[0]:5.2f}: " + "  ".join(
                f"N={n}: NVE {d['NVE']:.3f} Langevin {d['Langevin']:.3f} µs/atom-step, "
                f"ratio {d['Langevin'] / d['NVE']:.3f}" for n, d in data.items()), flush=True)
    print("median ratio Langevin/NVE over rounds:")
    for name in trees:
        for n in res[name][0]:
            r = [d[n]["Langevin"] / d[n]["NVE"] for d in res[name]]
            print(f"  {name:9s} N = {n:>6}: {np.median(r):.3f} ({min(r):.3f}–{max(r):.3f})")


if __name__ == "__main__":
    main()
