"""A CollectivePRK step with a long-range dipolar field: the midpoint solve
that holds the field fixed while exchange converges (the default,
``policy.held_operators``) against the plain solve that evaluates it every
sweep, side by side in one process on the same scene.

    python benchmarks/dipolar_step.py [--n 10] [--dt 0.25] [--rc 6] [--accuracy 1e-5]
                                      [--method pme] [--warmup 12] [--blocks 3] [--steps 4]

fcc Co (4n³ atoms, 300 K, spins in a 30° cone), LJ + Bethe–Slater exchange +
``Dipolar(rc, method, accuracy)`` with the physical prefactor, order 2. Both
runs take ``warmup`` steps untimed (compilation, the predictor's history),
then ``blocks`` blocks of ``steps`` steps each, interleaved (held, plain,
held, ...). Per step: the dipolar field evaluations (``field``, each the
midpoint field: the sum at q and at q̃), the dipolar force passes (``add``),
the midpoint sweeps, and the step time (median of the blocks); then the
ratio and how far the two runs' states are apart. A third run without the
dipolar term (``none``, same scene, same steps interleaved) gives what the
term costs against an exchange-only step.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from machine import describe  # noqa: E402


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--n", type=int, default=10)
    parser.add_argument("--dt", type=float, default=0.25, help="fs")
    parser.add_argument("--rc", type=float, default=6.0)
    parser.add_argument("--accuracy", type=float, default=1e-5)
    parser.add_argument("--method", default="pme", choices=["pme", "ewald"])
    parser.add_argument("--warmup", type=int, default=12)
    parser.add_argument("--blocks", type=int, default=3)
    parser.add_argument("--steps", type=int, default=4)
    args = parser.parse_args()

    from ase import units

    import ase_spin
    from ase_spin import CollectivePRK, Dipolar
    from ase_spin.md import policy
    from ase_spin.scenes import fcc_cobalt
    from ase_spin.terms.dipolar import DipolarOperator

    counts = {"field": 0, "add": 0}
    field, add = DipolarOperator.field, DipolarOperator.add

    def counted_field(self, *a, **k):
        counts["field"] += 1
        return field(self, *a, **k)

    def counted_add(self, *a, **k):
        counts["add"] += 1
        return add(self, *a, **k)

    DipolarOperator.field, DipolarOperator.add = counted_field, counted_add
    held_operators = policy.held_operators

    def plain(operators):
        return None

    runs = {}
    for name in ("held", "plain", "none"):
        extra = [] if name == "none" else [Dipolar(args.rc, args.method,
                                                   accuracy=args.accuracy)]
        atoms = fcc_cobalt(args.n, temperature_K=300.0, extra=extra)
        runs[name] = {"atoms": atoms, "dyn": CollectivePRK(atoms, args.dt * units.fs),
                      "field": 0, "add": 0, "sweeps": 0, "times": []}
    print(describe())
    print(f"# fcc Co, {len(runs['held']['atoms'])} atoms, LJ + exchange + Dipolar({args.rc}, "
          f"{args.method!r}, accuracy={args.accuracy:g}), CollectivePRK order 2, "
          f"{args.dt} fs; {args.warmup} steps untimed, then {args.blocks} blocks of "
          f"{args.steps} steps interleaved; load {os.getloadavg()[0]:.2f}", flush=True)

    def run(name, steps, timed):
        r = runs[name]
        policy.held_operators = plain if name == "plain" else held_operators
        try:
            counts["field"] = counts["add"] = 0
            sweeps = 0
            t = time.perf_counter()
            for _ in range(steps):
                r["dyn"].run(1)
                sweeps += r["dyn"].iterations
            elapsed = time.perf_counter() - t
        finally:
            policy.held_operators = held_operators
        if timed:
            r["times"].append(elapsed / steps)
            r["field"] += counts["field"]
            r["add"] += counts["add"]
            r["sweeps"] += sweeps

    for name in runs:
        run(name, args.warmup, False)
    for _ in range(args.blocks):
        for name in runs:
            run(name, args.steps, True)
    total = args.blocks * args.steps
    print(f"# {'solve':>6} {'fields/step':>12} {'adds/step':>10} {'sweeps/step':>12} "
          f"{'s/step':>8}")
    for name, r in runs.items():
        print(f"  {name:>6} {r['field'] / total:12.2f} {r['add'] / total:10.2f} "
              f"{r['sweeps'] / total:12.2f} {np.median(r['times']):8.3f}")
    ratio = np.median(runs["plain"]["times"]) / np.median(runs["held"]["times"])
    alone = np.median(runs["held"]["times"]) / np.median(runs["none"]["times"])
    a, b = runs["held"]["atoms"], runs["plain"]["atoms"]
    apart = max(float(np.abs(a.positions - b.positions).max()),
                float(np.abs(ase_spin.get_spins(a) - ase_spin.get_spins(b)).max()))
    print(f"# plain/held step time {ratio:.2f}; states apart by {apart:.1e} after "
          f"{args.warmup + total} steps; a held step costs {alone:.0f} steps without the "
          f"dipolar term; load {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
