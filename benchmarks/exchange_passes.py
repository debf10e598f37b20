"""The exchange operator's passes alone, for comparing code versions: the
preparation at q̃ (J, J'd/r or J'/r, J̄ = ½(J + J_q)), the lattice-force pass
and the force-and-virial pass (of an operator prepared with ``virial=True``), on the fcc Co scene's exchange (Bethe–Slater, half list).

    python benchmarks/exchange_passes.py [--sizes 5 10 20]            # this tree
    python benchmarks/exchange_passes.py --compare OLD_TREE NEW_TREE --rounds 3 \
        [--sizes 5 10 20]

ns per atom, median of 7 repeats (each ≥ 2·10⁶ atom-passes) in the threads a
run of that size uses (serial below 1 500 atoms). ``--compare`` runs each tree
in a fresh process (PYTHONPATH set to it), alternating the trees round by round
after one warm-up run of each (numba's caches). Public API only
(``Evaluator.spin_operators``, ``Evaluator.spin``), so any tree runs it.
"""

import argparse
import json
import os
import subprocess
import sys
import time


def measure(sizes):
    import numpy as np

    from ase_spin import Want, get_spins
    from ase_spin._jit import threads
    from ase_spin.scenes import fcc_cobalt

    out = {}
    for n in sizes:
        atoms = fcc_cobalt(n)
        ev, _ = atoms.calc.bound_evaluator(atoms)
        q = atoms.positions.copy()
        qt = q + 1e-3
        s = get_spins(atoms)
        N = len(atoms)
        reps = max(3, int(2e6 / N))
        with threads.threads_for(N):
            ops = ev.spin_operators(q, half=True)  # as the integrators prepare them
            nxt = ev.spin_operators(qt, mean_with=ops, half=True)
            stress_ops = ev.spin_operators(q, virial=True, half=True)
            F = np.zeros_like(q)

            def geometry():
                ev.spin_operators(qt, out=nxt, mean_with=ops, half=True)

            def forces():
                ev.spin(ops, s, Want(forces=True), forces=F)

            def virial():
                ev.spin(stress_ops, s, Want(forces=True, virial=True), forces=F)

            for name, f in (("geometry", geometry), ("forces", forces),
                            ("forces+virial", virial)):
                times = []
                for _ in range(7):
                    t0 = time.perf_counter()
                    for _ in range(reps):
                        f()
                    times.append((time.perf_counter() - t0) / reps / N * 1e9)
                out[f"{name} N={N}"] = round(float(np.median(times)), 2)
    return out


def main(argv=None):
    parser = argparse.ArgumentParser()
    parser.add_argument("--compare", nargs=2, metavar=("OLD_TREE", "NEW_TREE"))
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--sizes", type=int, nargs="+", default=[5, 10, 20])
    args = parser.parse_args(argv)
    if not args.compare:
        print(json.dumps(measure(args.sizes)))
        return
    sys.path.insert(0, os.path.dirname(__file__))
    sys.path.insert(0, os.path.abspath(args.compare[1]))
    from machine import describe

    print(describe(), f"load {os.getloadavg()[0]:.1f}", flush=True)
    script = os.path.abspath(__file__)

    def run(tree):
        env = dict(os.environ, PYTHONPATH=os.path.abspath(tree))
        sizes = [str(n) for n in args.sizes]
        res = subprocess.run([sys.executable, script, "--sizes", *sizes], cwd=tree, env=env,
                             check=True, capture_output=True, text=True).stdout
        return json.loads(res.strip().splitlines()[-1])

    for tree in args.compare:  # warm numba's caches
        run(tree)
    results = {"old": [], "new": []}
    for r in range(args.rounds):
        for label, tree in zip(("old", "new"), args.compare):
            res = run(tree)
            results[label].append(res)
            print(f"round {r + 1} {label} {json.dumps(res)}", flush=True)
    print(f"# medians over rounds, ns/atom (load {os.getloadavg()[0]:.1f} at the end)")
    print(f"{'pass':>24} {'old':>8} {'new':>8} {'new/old':>8}")
    for key in results["old"][0]:
        old = sorted(r[key] for r in results["old"])[len(results["old"]) // 2]
        new = sorted(r[key] for r in results["new"])[len(results["new"]) // 2]
        print(f"{key:>24} {old:8.2f} {new:8.2f} {new / old:8.3f}")


if __name__ == "__main__":
    main()
