"""Small systems: one CollectivePRK step against one evaluation, where Python's
overhead shows (issue 13, item 4).

    python benchmarks/small_systems.py                        # this tree
    python benchmarks/small_systems.py --compare OLD_TREE NEW_TREE --rounds 3

Two scenes: fcc Co with N = 500 (ase_spin.scenes.fcc_cobalt(5): LJ + Bethe–Slater
exchange, 100 K, dt = 0.1 fs, moment convention, order 2) and the paper's chain
(scenes.paper_chain: 30 atoms, ħ = 1, precession="spin", h = 2⁻⁶, order 2, as
``benchmarks/long_run.py chain``). For each: µs per step (``dyn.run``, default
threads, i.e. ``threads="auto"``: all threads or one, whichever is faster), µs per
evaluation (``Evaluator.evaluate``: energy, forces and magnetic forces; with all
threads and with one, the faster) and their ratio; steps and
evaluations timed alternately in blocks (median over blocks), midpoint sweeps
and geometries per step; and, in a fresh process per scene, µs per step of
its first ``dyn.run(2000)`` (numba's cache warm, by one untimed fresh process
first: loading the kernels from it included), what a user's first short run
of the default path costs. Nothing
is switched: the paths timed are the defaults. ``--compare`` runs this in a fresh process per tree
(PYTHONPATH set to it), alternating the trees round by round, after one warm-up
run of each (numba's caches); a worktree of an older commit: ``git worktree
add /tmp/old <commit>``. Prints the machine and the load average.
"""

import argparse
import json
import os
import subprocess
import sys
import time

FIRST_RUN_STEPS = 2000


def scenes():
    """name -> (build the Atoms, the integrator for them, steps per timed block)."""
    from ase import units

    from ase_spin import CollectivePRK
    from ase_spin.scenes import fcc_cobalt, paper_chain

    return {
        "fcc Co N=500": (lambda: fcc_cobalt(5),
                         lambda a: CollectivePRK(a, 0.1 * units.fs), 20),
        "paper chain N=30": (paper_chain,
                             lambda a: CollectivePRK(a, 2.0**-6, hbar=1.0,
                                                     precession="spin"), 400),
    }


def first_run(name, steps=FIRST_RUN_STEPS):
    """µs per step of this process's first ``dyn.run(steps)`` of a scene."""
    build, integrator, _ = scenes()[name]
    dyn = integrator(build())
    t0 = time.perf_counter()
    dyn.run(steps)
    return (time.perf_counter() - t0) / steps * 1e6


def first_runs(tree=None):
    """:func:`first_run` of each scene, each in a fresh process (of ``tree``)."""
    env = dict(os.environ)
    if tree is not None:
        env["PYTHONPATH"] = os.path.abspath(tree)
    out = {}
    for name in scenes():
        res = subprocess.run([sys.executable, os.path.abspath(__file__), "--first-run", name],
                             cwd=tree, env=env, check=True, capture_output=True, text=True)
        out[name] = round(float(res.stdout.strip().splitlines()[-1]), 2)
    return out


def measure(blocks=15):
    import numba as nb
    import numpy as np

    from ase_spin import Want

    want = Want(energy=True, forces=True, magnetic_forces=True)
    out = {}
    most = nb.get_num_threads()
    for name, (build, integrator, steps) in scenes().items():
        atoms = build()
        dyn = integrator(atoms)
        dyn.run(2 * steps)
        ev, _ = atoms.calc.bound_evaluator(atoms)
        step_times, eval_times = [], []
        before = (dyn.total_iterations, dyn.total_steps)
        for _ in range(blocks):
            t0 = time.perf_counter()
            dyn.run(steps)
            step_times.append((time.perf_counter() - t0) / steps)
            q = atoms.positions.copy()
            s = dyn._state.s.copy()
            best = np.inf
            for n in {1, most}:  # one thread or all, whichever is faster now
                nb.set_num_threads(n)
                t0 = time.perf_counter()
                for _ in range(steps):
                    ev.evaluate(q, s, want)
                best = min(best, (time.perf_counter() - t0) / steps)
            nb.set_num_threads(most)
            eval_times.append(best)
        step = float(np.median(step_times)) * 1e6
        evaluation = float(np.median(eval_times)) * 1e6
        taken = dyn.total_steps - before[1]
        sweeps = (dyn.total_iterations - before[0]) / taken
        geometries = []  # counted after the timing: an observer costs time
        dyn.attach(lambda: geometries.append(dyn.geometry_evaluations), interval=1)
        dyn.run(20)
        out[name] = {"step_us": round(step, 2), "eval_us": round(evaluation, 2),
                     "step/eval": round(step / evaluation, 3),
                     "sweeps": round(sweeps, 2),
                     "geometries": round(float(np.mean(geometries[1:])), 2)}
    return out


def main(argv=None):
    parser = argparse.ArgumentParser()
    parser.add_argument("--compare", nargs=2, metavar=("OLD_TREE", "NEW_TREE"))
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--blocks", type=int, default=15)
    parser.add_argument("--json", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--first-run", metavar="SCENE", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.first_run:
        print(first_run(args.first_run))
        return
    sys.path.insert(0, os.path.dirname(__file__))
    if not args.compare:
        first_runs()  # untimed: fills numba's cache if cold; the timed runs load from it
        first = first_runs()
        result = measure(args.blocks)
        for name, us in first.items():
            result[name][f"first_run{FIRST_RUN_STEPS}_us"] = us
        if args.json:
            print(json.dumps(result))
            return
        from machine import describe

        print(describe(), f"load {os.getloadavg()[0]:.1f}")
        for name, r in result.items():
            print(name, json.dumps(r))
        print(f"load {os.getloadavg()[0]:.1f}")
        return
    sys.path.insert(0, os.path.abspath(args.compare[1]))  # describe() names the new tree's version
    from machine import describe

    print(describe(), flush=True)
    script = os.path.abspath(__file__)

    def run(tree):
        env = dict(os.environ, PYTHONPATH=os.path.abspath(tree))
        out = subprocess.run([sys.executable, script, "--json", "--blocks", str(args.blocks)],
                             cwd=tree, env=env, check=True, capture_output=True,
                             text=True).stdout
        return json.loads(out.strip().splitlines()[-1])

    for tree in args.compare:  # warm numba's caches
        run(tree)
    for r in range(args.rounds):
        for label, tree in zip(("old", "new"), args.compare):
            load = os.getloadavg()[0]
            for name, res in run(tree).items():
                print(f"round {r + 1} {label} (load {load:.1f}) {name} {json.dumps(res)}",
                      flush=True)


if __name__ == "__main__":
    main()
