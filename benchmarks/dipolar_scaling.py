"""Cost of the dipolar term against N: the Ewald sum over k-vectors
(``Dipolar(method="ewald")``) against smooth particle-mesh Ewald
(``method="pme"``), on fcc Co (4n³ atoms, spins in a 30° cone), with the
Bethe–Slater exchange's field on the same atoms for scale.

    python benchmarks/dipolar_scaling.py [--sizes 6 10 16 25 32] [--ewald-sizes 6 10]
                                         [--rc 6] [--accuracy 1e-5] [--threads 1 2]

Each (method, N) runs in its own process (peak memory is per process). Per row:
the operator's preparation at new positions (``Evaluator.spin_operators``:
pair geometry, the k-space phases or the spline weights), one field
evaluation from the prepared operator (what a midpoint-solve iteration asks),
one energy + forces + magnetic forces evaluation from scratch
(``Evaluator.evaluate``), and the exchange field from its prepared operator;
best of three. With ``--threads``, the field is also timed with each of those
thread counts, interleaved (the counts side by side in one process). The
peak resident memory is per process, also per atom. Then the log-log slopes
of the times against N.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

from machine import best_time, describe  # noqa: E402


def child(n, method, rc, accuracy, counts):
    import resource
    import time

    import numba

    from ase_spin import Dipolar, Hamiltonian, Want, get_spins
    from ase_spin._jit import threads
    from ase_spin.scenes import fcc_cobalt, fcc_cobalt_terms

    atoms = fcc_cobalt(n)
    s = get_spins(atoms)
    N = len(atoms)
    mu = np.full(N, 1.72)
    term = Dipolar(rc, method, accuracy=accuracy)
    ev = Hamiltonian([term]).bind(atoms.numbers, atoms.cell.array, atoms.pbc, mu)
    ex = Hamiltonian([fcc_cobalt_terms()[1]]).bind(atoms.numbers, atoms.cell.array, atoms.pbc,
                                                   mu)
    q = atoms.positions

    def best(f, reps=3):
        return best_time(f, N, reps)

    B = np.zeros_like(s)
    prepare = best(lambda: ev.spin_operators(q, half=True), 2)
    ops = ev.spin_operators(q, half=True)
    field = best(lambda: ops[0].field(s, B))
    evaluate = best(lambda: ev.evaluate(q, s, Want(energy=True, forces=True,
                                                   magnetic_forces=True)), 2)
    by_threads = {}
    if counts:
        default = numba.get_num_threads()
        with threads.threads_for(N):
            for _ in range(3):
                for c in counts:
                    numba.set_num_threads(c)
                    t = time.perf_counter()
                    ops[0].field(s, B)
                    t = time.perf_counter() - t
                    by_threads[c] = min(by_threads.get(c, t), t)
        numba.set_num_threads(default)
    exops = ex.spin_operators(q, half=True)
    exchange = best(lambda: exops[0].field(s, B))
    mesh = term.mesh_size(atoms.cell.array) if method == "pme" else None
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(json.dumps({"N": N, "method": method, "mesh": mesh, "order": term.spline_order
                      if method == "pme" else None, "prepare": prepare, "field": field,
                      "evaluate": evaluate, "exchange": exchange, "peak_MB": peak,
                      "by_threads": by_threads}))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[6, 10, 16, 25, 32])
    parser.add_argument("--ewald-sizes", type=int, nargs="*", default=[4, 6, 8])
    parser.add_argument("--rc", type=float, default=6.0)
    parser.add_argument("--accuracy", type=float, default=1e-5)
    parser.add_argument("--threads", type=int, nargs="*", default=[],
                        help="also time the field with each of these thread counts")
    parser.add_argument("--child", nargs=2)
    args = parser.parse_args()
    if args.child:
        child(int(args.child[0]), args.child[1], args.rc, args.accuracy, args.threads)
        return
    rows = []
    print(describe())
    print(f"rc = {args.rc} Å, accuracy = {args.accuracy:g}; load {os.getloadavg()[0]:.2f}")
    print(f"{'N':>8} {'method':>6} {'mesh':>16} {'prepare s':>10} {'field s':>10} "
          f"{'E+F s':>10} {'field/exch':>10} {'peak MB':>8} {'kB/atom':>8}"
          + "".join(f" {f'field {c} thr':>12}" for c in args.threads))
    for method, sizes in (("pme", args.sizes), ("ewald", args.ewald_sizes)):
        for n in sizes:
            out = subprocess.run([sys.executable, __file__, "--child", str(n), method,
                                  "--rc", str(args.rc), "--accuracy", str(args.accuracy),
                                  "--threads", *map(str, args.threads)],
                                 capture_output=True, text=True, check=False)
            if out.returncode:
                print(f"{method} n={n}: failed\n{out.stderr[-2000:]}")
                continue
            r = json.loads(out.stdout.strip().splitlines()[-1])
            rows.append(r)
            mesh = "x".join(map(str, r["mesh"])) + f" p{r['order']}" if r["mesh"] else "-"
            print(f"{r['N']:>8} {method:>6} {mesh:>16} {r['prepare']:>10.4f} {r['field']:>10.4f} "
                  f"{r['evaluate']:>10.4f} {r['field'] / r['exchange']:>10.1f} "
                  f"{r['peak_MB']:>8.0f} {r['peak_MB'] * 1024 / r['N']:>8.1f}"
                  + "".join(f" {r['by_threads'][str(c)]:>12.4f}" for c in args.threads),
                  flush=True)
    for method in ("pme", "ewald"):
        sel = [r for r in rows if r["method"] == method]
        if len(sel) > 1:
            N = np.log([r["N"] for r in sel])
            slopes = {key: np.polyfit(N, np.log([r[key] for r in sel]), 1)[0]
                      for key in ("prepare", "field", "evaluate")}
            print(f"{method}: log-log slopes " + ", ".join(f"{k} {v:.2f}"
                                                            for k, v in slopes.items()))


if __name__ == "__main__":
    main()
