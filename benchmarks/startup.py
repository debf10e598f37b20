"""Where a short run's time goes in a fresh process: the start-up a user pays
once per script (numba's first use, each kernel loaded from numba's disk
cache) against the steps.

    python benchmarks/startup.py [--dt 0.142] [--order 2] [--runs 3]

The work-precision scene (fcc Co N = 500, LAMMPS's ħ and masses,
``benchmarks/work_precision.py``), ``CollectivePRK(atoms, dt, order=...)`` with
default settings, each run a new Python process with the kernels in numba's
cache (one untimed process fills it first). Timed as work_precision.py times
a run (from building the scene, ``import ase_spin`` not included): building
the scene, then ``dyn.run`` of 0.5 ps; every kernel numba loads from its
cache on the way, with its load time (numba's ``Cache.load_overload``,
wrapped for the measurement only); then the same run again in that process
(nothing left to load: the steps alone). Prints per run, then the median of
each phase; the start-up is the first run less the second.

Then where a step's time goes (``--pieces``, in one process after the runs):
µs per step of the same run, its midpoint sweeps and geometries (couplings
at q̃) in the last, and each pass over the pairs a step makes timed alone through
the public evaluator (``Evaluator.lattice``, ``spin_operators``, ``spin`` and an
operator's ``field``; each call a few µs of Python more than in the compiled
step), with each term's cutoff; then a whole sweep of the midpoint solver (its
fields and its update: a solve made to take three sweeps less one made to take
one, halved) and the exchange-force pass on one thread and split between two
(the kernel's threaded twin), as the compiled step could call them.

With ``--lammps`` (after ``--pieces``; LAMMPS importable, ``LD_LIBRARY_PATH=$VIRTUAL_ENV/lib``),
in the same run: LAMMPS's run of the same 0.5 ps at 0.5 fs (``fix nve/spin``,
one rank, a fresh process each, timed from creating its instance as
work_precision.py times it; the median of ``--runs``) and its lattice step
alone (``lj/cut`` + ``fix nve``, µs: benchmarks/lammps_skin.py), and the
floor of the collective step: the least every second-order coupled step must
do, each pass at the least measured cost — one Lennard-Jones pass at LAMMPS's
own lattice step, the exchange couplings at q̃, one exchange-force pass and
one whole sweep at the times above (each still carrying a few µs of Python: the
floor is over-estimated by that) — times the steps, plus numba's first use
(the first kernel's load). Its ratio to LAMMPS's time is the best this
method's steps at ``--dt`` can reach against LAMMPS here with its passes one
after another. Last, the force pass on two threads against one: whether
splitting a pass between the two cores, rather than running independent
passes side by side, could take a step below that floor.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))

#: What one child process runs (argv: dt in fs, order, steps).
_CHILD = r"""
import json, sys, time
from numba.core import caching
loads = []
_load = caching.Cache.load_overload
def timed_load(self, sig, ctx):
    t = time.perf_counter()
    got = _load(self, sig, ctx)
    loads.append((self._name.split(" at ")[0].removeprefix("<function "), time.perf_counter() - t))
    return got
caching.Cache.load_overload = timed_load
sys.path[:0] = [HERE, TESTS]
import work_precision as wp
from ase import units
dt, order, steps = float(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3])
make, t_end, kw, _, _, _ = wp.scene_setup("fcc500")
t0 = time.perf_counter()
atoms = make()
t1 = time.perf_counter()
dyn = wp.CollectivePRK(atoms, dt * units.fs, order=order, **kw)
dyn.run(steps)
t2 = time.perf_counter()
first = len(loads)
dyn.run(steps)  # the same again in this process: the steps alone
t3 = time.perf_counter()
print(json.dumps({"scene": t1 - t0, "run": t2 - t1, "again": t3 - t2,
                  "per step": (t3 - t2) / steps, "total": t2 - t0,
                  "loads": loads[:first], "loads again": len(loads) - first}))
"""


def child(dt, order, steps):
    code = _CHILD.replace("HERE", repr(HERE)).replace(
        "TESTS", repr(os.path.join(HERE, os.pardir, "tests")))
    done = subprocess.run([sys.executable, "-c", code, str(dt), str(order), str(steps)],
                          capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def pieces(dt, order, steps=1000, repeats=5, calls=300):
    """The step and its passes over the pairs, µs each (minimum of
    ``repeats`` blocks, this process warm): see the module docstring."""
    import numpy as np
    from ase import units

    sys.path[:0] = [HERE, os.path.join(HERE, os.pardir, "tests")]
    import work_precision as wp
    from ase_spin import get_spins
    from ase_spin.terms.base import Want

    make, _, kw, _, _, _ = wp.scene_setup("fcc500")
    atoms = make()
    dyn = wp.CollectivePRK(atoms, dt * units.fs, order=order, **kw)
    dyn.run(steps // 10)

    def best(run, n):
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            run()
            times.append((time.perf_counter() - t0) / n * 1e6)
        return min(times)

    sweeps0, n0 = dyn.total_iterations, dyn.nsteps
    out = {"step": best(lambda: dyn.run(steps), steps)}
    out["sweeps a step"] = (dyn.total_iterations - sweeps0) / (dyn.nsteps - n0)
    out["geometries, the last step"] = dyn.geometry_evaluations
    ev = dyn.ev
    q = atoms.positions.copy()
    W = get_spins(atoms)
    F = np.zeros_like(q)
    B = np.zeros_like(q)
    ops = ev.spin_operators(q, half=True)
    there = ev.spin_operators(q, half=True)

    def repeat(f):
        def run():
            for _ in range(calls):
                f()
        return run

    passes = {
        "lattice forces": lambda: ev.lattice(q, Want(forces=True), forces=F),
        "couplings at new positions": lambda: ev.spin_operators(q, out=there, mean_with=ops,
                                                                half=True),
        "spin terms' forces": lambda: ev.spin(ops, W, Want(forces=True), forces=F),
        "a sweep's fields": lambda: [op.field(W, B, True) for op in there],
    }
    passes.update(_kernel_passes(there[0], W, dt * units.fs, dyn, calls))

    def passes_now():
        got = {name: best(repeat(f), calls) for name, f in passes.items()}
        # a whole sweep (fields and update) as the step's solver makes it: three
        # sweeps less one, halved (a solve's set-up and end points cancel)
        got["a sweep"] = 0.5 * (got.pop("a solve of 3 sweeps") - got.pop("a solve of 1 sweep"))
        return got

    out.update(passes_now())
    return out, {type(t).__name__: t.cutoff for t in ev.hamiltonian.terms}, passes_now


def _kernel_passes(op, W, h, dyn, calls):
    """The kernels a small system's step calls, timed from Python as it calls
    them (its serial twins): the midpoint solver forced to make 1 and 3
    sweeps (no tolerance it can meet), and the exchange-force pass on one
    thread and on two (its threaded twin, two chunks) — whether splitting a
    pass between the two cores pays at this size."""
    import numpy as np

    from ase_spin.md import kernels
    from ase_spin.terms.exchange_passes import spin_pass_half_kernel

    pairs, c = op.linear_pairs()  # (J: what J̄ costs the same)
    # c_i = hσ/ħ · r_i, r_i = 1: the scene's LAMMPS gyromagnetic convention
    scale = np.full(len(W), h * dyn.sigma / dyn.hbar)
    buffers = [np.zeros_like(W) for _ in range(4)]

    def solve(sweeps):
        start = W.copy()
        kernels.midpoint_solve_half.serial(
            1, pairs.row, pairs.j, c, W, start, buffers[0], buffers[1], scale, 0.0, 0.0, sweeps,
            0.5, buffers[2], buffers[3], 0, True, kernels.NO_FIELD, kernels.NO_ORDER,
            kernels.NO_ORDER, kernels.NO_FIELD)

    data = op.compiled()[3]
    _, row, nbr, image, images, J, G, _, offset, _, _ = data
    F = np.zeros_like(W)
    none, rows = np.zeros(0), np.zeros((0, 3))
    no, yes = np.bool_(False), np.bool_(True)

    def forces(kernel, chunks):
        kernel(chunks, row, nbr, image, images, J, none, G, rows, W, W, offset, rows, F, none,
               no, yes, no, no, no)

    return {"a solve of 1 sweep": lambda: solve(1), "a solve of 3 sweeps": lambda: solve(3),
            "forces, one thread": lambda: forces(spin_pass_half_kernel.serial, 1),
            "forces, two threads": lambda: forces(spin_pass_half_kernel.parallel, 2)}


def floor(got, passes_now, first_use, total, steps, runs):
    """Print LAMMPS's times and the floor of the collective step against them
    (see the module docstring): LAMMPS's runs interleaved with timings of the
    passes again (``passes_now``), the least of each taken."""
    sys.path[:0] = [HERE, os.path.join(HERE, os.pardir, "tests")]
    import work_precision as wp
    from lammps_skin import lattice_step_time

    spec = {"scene": "fcc500", "kind": "lammps", "options": {}, "dt": 0.5,
            "out": os.devnull, "set_up_timed": True}
    walls, lattice, ours = [], [], [got]
    for _ in range(runs):  # interleaved: the machine's swings fall on both alike
        walls.append(json.loads(wp.child(["--one", json.dumps(spec)]))["wall"])
        lattice.append(lattice_step_time(1000))
        ours.append(passes_now())
    wall = min(walls)

    def least(name):
        return min(o[name] for o in ours)

    passes = {"LAMMPS's lattice step (lj/cut + fix nve)": min(lattice),
              "couplings at q̃": least("couplings at new positions"),
              "one exchange-force pass": least("spin terms' forces"),
              "one sweep (fields and update)": least("a sweep")}
    step = sum(passes.values())
    run = first_use + steps * step * 1e-6
    print(f"\nLAMMPS fix nve/spin, 0.5 ps at 0.5 fs, one rank, fresh processes: "
          f"{' '.join(f'{w:.3f}' for w in walls)} s (least {wall:.3f})")
    print(f"the floor of a coupled step ({steps} steps; the least of {runs + 1} timings each):")
    for name, value in passes.items():
        print(f"  {name:42s} {value:8.2f} µs")
    print(f"  {'a step':42s} {step:8.2f} µs, against {got['step']:.2f} µs as run")
    print(f"  numba's first use {first_use:.3f} s + {steps} steps: {run:.3f} s = "
          f"{run / wall:.2f} of LAMMPS's least time (the fresh runs above, median: "
          f"{total:.3f} s, {total / wall:.2f})")
    print(f"an exchange-force pass split between the two cores: "
          f"{least('forces, two threads'):.2f} µs, on one {least('forces, one thread'):.2f} µs")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--dt", type=float, default=0.142, help="fs (default 0.142: the "
                        "order-2 step that reaches LAMMPS's error at 0.5 fs)")
    parser.add_argument("--order", type=int, default=2)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--pieces", action="store_true", help="then each pass over the "
                        "pairs a step makes, timed alone")
    parser.add_argument("--lammps", action="store_true", help="with --pieces: LAMMPS's run "
                        "in the same run, and the floor of the collective step against it")
    args = parser.parse_args(argv)
    sys.path.insert(0, HERE)
    from machine import describe

    print(describe())
    print(f"# load average at start: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    steps = int(round(500.0 / args.dt))
    child(args.dt, args.order, steps)  # fills numba's cache, untimed
    runs = [child(args.dt, args.order, steps) for _ in range(args.runs)]
    for k, run in enumerate(runs):
        loads = run["loads"]
        print(f"\nrun {k + 1}: {steps} steps of {args.dt} fs, order {args.order}: "
              f"{run['total']:.3f} s; {len(loads)} kernels loaded in "
              f"{sum(t for _, t in loads):.3f} s")
        for name, t in loads:
            print(f"  {1e3 * t:7.1f} ms  {name}")
    print(f"\nmedians of {args.runs} runs (s):")
    for key in ("scene", "run", "again", "total"):
        print(f"  {key:14s} {statistics.median(r[key] for r in runs):.3f}")
    print(f"  {'start-up':14s} {statistics.median(r['run'] - r['again'] for r in runs):.3f}"
          "  (the run less the same run again)")
    print(f"  {'loads':14s} {statistics.median(sum(t for _, t in r['loads']) for r in runs):.3f}"
          f"  (the first: {statistics.median(r['loads'][0][1] for r in runs):.3f}, "
          "numba's first use included)")
    print(f"  {'per step':14s} {1e6 * statistics.median(r['per step'] for r in runs):.0f} µs"
          f" (the run again; kernels loaded in it: {max(r['loads again'] for r in runs)})")
    if args.pieces:
        got, cutoffs, passes_now = pieces(args.dt, args.order)
        print(f"\nwhere a step goes (this process, warm; cutoffs {cutoffs} Å):")
        for name, value in got.items():
            unit = "" if "step" in name and name != "step" else " µs"
            print(f"  {name:28s} {value:8.2f}{unit}")
        if args.lammps:
            first_use = statistics.median(r["loads"][0][1] for r in runs)
            total = statistics.median(r["total"] for r in runs)
            floor(got, passes_now, first_use, total, steps, args.runs)
    print(f"# load average at end: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
