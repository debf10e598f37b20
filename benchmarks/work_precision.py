"""Error against wall time: CollectivePRK (orders 2, 4, 6), the SuzukiTrotter
baseline and LAMMPS `fix nve/spin` on 1 and 2 MPI ranks, all in one run on one
machine.

    python benchmarks/work_precision.py \
        [--scenes fcc500 chain] [--out docs/figures/work_precision] [--quick] \
        [--min-dt 0.1 --repeats 5] [--lammps-ranks 1 2] [--in-process]

Scenes: fcc Co (peers.md, N = 4n³: `fcc500`, `fcc4000`; `fcc500-field`: the same
with a 10 T field and uniaxial anisotropy, `scenes.field_anisotropy_terms`; 0.5 ps, moment convention,
LAMMPS's ħ, masses carrying LAMMPS's force-to-acceleration constant so that
every code integrates the same equations) and the paper's chain (T = 1). Every
final state is compared with one DOP853 solution of the equations of motion
(rtol 1e-13): RMS over atoms of |s_i − s_ref,i| (spins) and |r_i − r_ref,i| (Å).

What a user's run costs: by default each timed run is a fresh Python process
(``--one``), the package's default settings (``CollectivePRK(atoms, dt,
order=...)``, threads "auto"), its kernels loaded from numba's disk cache (one
untimed warm-up process fills it first); the time runs from building the
scene (Atoms and calculator) to the end of ``dyn.run``: set-up, first step and
loading the kernels included, the interpreter's start and ``import ase_spin``
not (printed apart). LAMMPS (when `lammps` is importable; the peers.md input)
is timed alike, from creating its instance to the end of the run, on 1 rank
and under ``mpiexec -n 2`` (its best on two cores, peers.md). Repeats are
interleaved (every point once, then again), wall times are medians of
--repeats runs (a point whose run took over 20 s is not repeated), with the
load average beside them. ``--in-process`` times ``dyn.run`` alone in this
process after warming it up (the kernels already loaded: the steady cost).
"""

from __future__ import annotations

import time

_T_START = time.perf_counter()  # before the heavy imports: what `import ase_spin` costs

import argparse  # noqa: E402
import json  # noqa: E402
import os  # noqa: E402
import shutil  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from ase import units  # noqa: E402

sys.path.insert(0, os.path.dirname(__file__))
# the drivers of LAMMPS and Spirit (lammps_peer, spirit_peer) live with the tests
sys.path.insert(0, os.path.join(os.path.dirname(__file__), os.pardir, "tests"))

import ase_spin  # noqa: E402
from ase_spin import CollectivePRK, SuzukiTrotter  # noqa: E402
from lammps_peer import LammpsSpin, lammps_available  # noqa: E402
from ase_spin.md.ode import reference_solution  # noqa: E402
from ase_spin.scenes import (FIELD_ANISOTROPY_LAMMPS, fcc_cobalt,  # noqa: E402
                             field_anisotropy_terms, paper_chain)
from machine import describe  # noqa: E402

HBAR_LAMMPS = ase_spin.HBAR_LAMMPS
#: LAMMPS metal units turn force/mass into acceleration with 1/1.0364269e-4
#: (Å/ps² per eV/Å/amu), 5.5e-8 off the CODATA value: masses × this ratio here.
MASS_RATIO = (1000.0 * units.fs) ** 2 * 1.0364269e-4
LJ = (0.4, 2.2742, 4.7, True)
EXCHANGE = (0.0446928, 0.003496, 1.4885, 4.0, False)

LAMMPS = "LAMMPS fix nve/spin"
# (label, kind, options, steps in fs or in units of the chain's time)
FCC_METHODS = [
    ("CollectivePRK order 2", "prk", {"order": 2}, [0.5, 0.25, 0.15, 0.1, 0.05, 0.025]),
    ("CollectivePRK order 4", "prk", {"order": 4}, [2.0, 1.5, 1.25, 1.0, 0.5, 0.25, 0.125]),
    ("CollectivePRK order 6", "prk", {"order": 6}, [2.0, 1.0, 0.5, 0.25, 0.125]),
    ("SuzukiTrotter (Cayley)", "st", {"rotation": "cayley"}, [0.5, 0.2, 0.1, 0.05, 0.025]),
    ("SuzukiTrotter order 4 (Cayley)", "st", {"rotation": "cayley", "order": 4},
     [4.0, 3.0, 2.0, 1.0, 0.5, 0.25, 0.125]),
    (LAMMPS, "lammps", {}, [0.5, 0.2, 0.1, 0.05, 0.025, 0.01, 0.0025]),
]
CHAIN_METHODS = [
    ("CollectivePRK order 2", "prk", {"order": 2}, [2.0**-k for k in range(4, 11)]),
    ("CollectivePRK order 4", "prk", {"order": 4}, [2.0**-k for k in range(3, 8)]),
    ("CollectivePRK order 6", "prk", {"order": 6}, [2.0**-k for k in range(3, 7)]),
    ("SuzukiTrotter (Cayley)", "st", {"rotation": "cayley"}, [2.0**-k for k in range(4, 11)]),
    ("SuzukiTrotter (exact)", "st", {"rotation": "exact"}, [2.0**-k for k in range(4, 11)]),
]


def fcc_scene(n, field=False):
    atoms = fcc_cobalt(n, extra=field_anisotropy_terms() if field else (), conventions="lammps")
    velocities = atoms.get_velocities()
    atoms.set_masses(atoms.get_masses() * MASS_RATIO)
    atoms.set_velocities(velocities)
    return atoms


def warm_up_list_updates(make, kind, options, dt, integrator_kw):
    """Take a method through pair-list rebuilds and filterings (the fine skin,
    docs/calculator.md) before timing: a timed run meets them once atoms have
    moved a quarter of the skin, and the first use in a process of the code
    they need (the list kernels, the single compiled step that follows a
    filtering) is ~60 ms of loading from numba's cache, not a cost of the
    method; the four warm-up steps load the rest. Here a skin of 0.002 Å
    makes them happen within 40 steps of 0.1 fs (at most the method's own
    step: an atom may move half the skin in one)."""
    atoms = make()
    atoms.calc = ase_spin.SpinLatticeCalculator(atoms.calc.hamiltonian.terms, skin=0.002)
    cls = CollectivePRK if kind == "prk" else SuzukiTrotter
    cls(atoms, min(dt, 0.1 * units.fs), **integrator_kw, **options).run(40)


def rms(a, b):
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


def scene_setup(scene):
    """(build the Atoms, run length, integrator keywords, unit of the steps
    (fs or the chain's time unit), fcc size n, field on) of a scene."""
    if scene.startswith("fcc"):
        n = {"fcc500": 5, "fcc4000": 10, "fcc500-field": 5}[scene]
        field = scene.endswith("-field")
        return (lambda: fcc_scene(n, field)), 500.0 * units.fs, {"hbar": HBAR_LAMMPS}, units.fs, \
            n, field
    return paper_chain, 1.0, {"hbar": 1.0, "precession": "spin"}, 1.0, None, False


def run_ours(make, kind, options, dt, t_end, integrator_kw, set_up_timed=False):
    """Wall time, final positions and spins, mean sweeps a step. The clock
    starts at ``dyn.run``, or with ``set_up_timed`` before the scene is built
    (a fresh process: set-up, first step and loading the kernels included)."""
    t0 = time.perf_counter()
    atoms = make()
    cls = CollectivePRK if kind == "prk" else SuzukiTrotter
    dyn = cls(atoms, dt, **integrator_kw, **options)
    steps = int(round(t_end / dt))
    if not set_up_timed:
        t0 = time.perf_counter()
    dyn.run(steps)
    wall = time.perf_counter() - t0
    return wall, atoms.positions.copy(), ase_spin.get_spins(atoms), dyn.mean_iterations


def lammps_fixes(field):
    if not field:
        return ()
    return (f"fix 2 all precession/spin {FIELD_ANISOTROPY_LAMMPS}", "fix_modify 2 energy yes")


def run_lammps(n, dt_fs, t_fs, field=False, set_up_timed=False):
    """As :func:`run_ours` (``set_up_timed``: from creating the instance)."""
    return lammps_run(n, dt_fs, t_fs, field, set_up_timed)[:4]


def lammps_run(n, dt_fs, t_fs, field, set_up_timed):
    """:func:`run_lammps`'s results, and this process's MPI rank."""
    atoms = fcc_cobalt(n, conventions="lammps")
    t0 = time.perf_counter()
    lmp = LammpsSpin(atoms, LJ, EXCHANGE, timestep_fs=dt_fs, fixes=lammps_fixes(field))
    lmp.run(0)
    if not set_up_timed:
        t0 = time.perf_counter()
    lmp.run(int(round(t_fs / dt_fs)))
    wall = time.perf_counter() - t0
    x, _, s = lmp.state()
    rank = lmp.lmp.extract_setting("world_rank")
    lmp.close()
    return wall, x, s, float("nan"), rank


def warm_up(scene, methods):
    """Load (or compile, into numba's cache) what each method's run needs: four
    steps (the first alone, then a block of them, fused.collective_block) and
    the pair-list updates."""
    make, _, kw, unit, _, _ = scene_setup(scene)
    for kind, options, dt in methods:
        run_ours(make, kind, options, dt * unit, 4 * dt * unit, kw)
        if scene.startswith("fcc"):
            warm_up_list_updates(make, kind, options, dt * unit, kw)


def one(spec):
    """One timed run (``--one``): the final state to ``spec["out"]`` (.npy),
    times and sweeps printed as JSON by rank 0."""
    import_s = time.perf_counter() - _T_START
    make, t_end, kw, unit, n, field = scene_setup(spec["scene"])
    timed = spec["set_up_timed"]
    if spec["kind"] == "lammps":
        wall, x, s, it, rank = lammps_run(n, spec["dt"], t_end / units.fs, field, timed)
    else:
        wall, x, s, it = run_ours(make, spec["kind"], spec["options"], spec["dt"] * unit, t_end,
                                  kw, timed)
        rank = 0
    if rank == 0:
        np.save(spec["out"], np.stack([x, s]))
        print(json.dumps({"wall": wall, "iterations": it, "import_s": import_s}))


def mpiexec():
    for candidate in (shutil.which("mpiexec"), os.path.join(sys.prefix, "bin", "mpiexec")):
        if candidate and os.path.exists(candidate):
            return candidate
    return None


def child(args, ranks=1):
    """Run this script with ``args`` in a fresh process (under ``mpiexec -n
    ranks`` if ranks > 1); its last line of output."""
    cmd = [sys.executable, os.path.abspath(__file__), *args]
    env = dict(os.environ)
    if ranks > 1:
        cmd = [mpiexec(), "-n", str(ranks), *cmd]
        env.update(OMP_NUM_THREADS="1", NUMBA_NUM_THREADS="1")
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
    if done.returncode:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{done.stderr[-3000:]}")
    lines = done.stdout.strip().splitlines()
    return lines[-1] if lines else ""


def lammps_label(ranks):
    return LAMMPS if ranks == 1 else f"{LAMMPS}, {ranks} ranks"


def reference(scene, keep=None):
    """The DOP853 final positions and spins of a scene; with ``keep`` (a
    folder) read from ``keep/reference_<scene>.npy`` if there, else computed
    and written there."""
    path = Path(keep) / f"reference_{scene}.npy" if keep else None
    if path is not None and path.exists():
        print(f"# {scene}: DOP853 reference read from {path}", flush=True)
        xr, sr = np.load(path)
        return xr, sr
    make, t_end, kw, _, _, _ = scene_setup(scene)
    t0 = time.perf_counter()
    xr, _, sr = reference_solution(make(), t_end, **kw)
    print(f"# {scene}: DOP853 reference in {time.perf_counter() - t0:.1f} s", flush=True)
    if path is not None:
        np.save(path, np.stack([xr, sr]))
    return xr, sr


def measure(scene, methods, repeats, quick, fresh=True, lammps_ranks=(1, 2), keep=None):
    """Rows (label, dt, median wall s, spin RMS, position RMS, sweeps a step,
    runs, median load average) of every method at every step."""
    make, t_end, kw, unit, n, _ = scene_setup(scene)
    xr, sr = reference(scene, keep)
    points, ours = [], []
    for label, kind, options, steps in methods:
        steps = steps[:3] if quick else steps
        if kind != "lammps":
            if steps:
                ours.append((kind, options, steps[0]))
            points += [(label, kind, options, dt, 1) for dt in steps]
            continue
        if not lammps_available():
            print(f"# {label}: lammps not importable, skipped")
            continue
        if scene == "fcc4000":  # LAMMPS at 0.01 fs and below: 8 and 35 min at this size
            steps = [dt for dt in steps if dt >= 0.025]
        for ranks in lammps_ranks:
            if ranks > 1 and mpiexec() is None:
                print(f"# {label} on {ranks} ranks: no mpiexec, skipped")
                continue
            points += [(lammps_label(ranks), kind, options, dt, ranks) for dt in steps]
    t0 = time.perf_counter()
    if fresh:  # untimed: fills numba's cache, so that every timed process loads from it
        child(["--warm-up", json.dumps({"scene": scene, "methods": ours})])
    else:
        warm_up(scene, ours)
    print(f"# {scene}: warm-up in {time.perf_counter() - t0:.1f} s", flush=True)
    walls = {(p[0], p[3], p[4]): [] for p in points}
    loads, found = {k: [] for k in walls}, {}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(repeats):  # interleaved: each point once a round, alternate directions
            for label, kind, options, dt, ranks in (points if r % 2 == 0 else points[::-1]):
                key = (label, dt, ranks)
                if walls[key] and max(walls[key]) > 20.0:
                    continue
                load = os.getloadavg()[0]
                if fresh or ranks > 1:
                    out = os.path.join(tmp, "state.npy")
                    spec = {"scene": scene, "kind": kind, "options": options, "dt": dt,
                            "out": out, "set_up_timed": fresh}
                    res = json.loads(child(["--one", json.dumps(spec)], ranks))
                    x, s = np.load(out)
                    wall, it, import_s = res["wall"], res["iterations"], res["import_s"]
                elif kind == "lammps":
                    wall, x, s, it = run_lammps(n, dt, t_end / units.fs, scene.endswith("-field"))
                    import_s = float("nan")
                else:
                    wall, x, s, it = run_ours(make, kind, options, dt * unit, t_end, kw)
                    import_s = float("nan")
                walls[key].append(wall)
                loads[key].append(load)
                found.setdefault(key, (rms(s, sr), rms(x, xr), it))
                es, ex, _ = found[key]
                print(f"{scene:8s} round {r + 1} {label:32s} dt {dt:<7.4g} wall {wall:8.4f} s "
                      f"(import {import_s:4.2f} s)  spin RMS {es:.3e}  pos RMS {ex:.3e}  "
                      f"sweeps/step {it:6.2f}  load {load:.2f}", flush=True)
    rows = []
    for label, kind, options, dt, ranks in points:
        key = (label, dt, ranks)
        es, ex, it = found[key]
        rows.append((label, dt, float(np.median(walls[key])), es, ex, it, len(walls[key]),
                     float(np.median(loads[key]))))
    return rows


def at_error(rows, label, target, value=2, column=3):
    """Wall time (``value`` 2; the step: 1) ``label`` needs for spin (column
    3) or position (4) RMS error ``target``, by log-log interpolation between
    two neighbouring steps of its ladder whose errors bracket it (the largest
    such steps: where the error is not monotone in the step, as near a
    resonance, never between points the ladder does not join); None where no
    two neighbours bracket it."""
    pts = sorted(((r[1], r[column], r[value]) for r in rows if r[0] == label), reverse=True)
    for (_, e0, t0), (_, e1, t1) in zip(pts, pts[1:]):
        if min(e0, e1) <= target <= max(e0, e1) and min(e0, e1) > 0:
            f = np.log(target / e0) / np.log(e1 / e0) if e1 != e0 else 0.0
            return float(np.exp(np.log(t0) + f * np.log(t1 / t0)))
    return None


def time_at_error(rows, label, target, column=3):
    return at_error(rows, label, target, 2, column)


LEVELS = (4e-2, 1e-2, 3e-3, 1e-3, 3e-4, 1e-4, 1e-5, 1.1e-6)


def equal_error_table(rows):
    """A markdown table: at LAMMPS's loosest error (1 rank) and every level of
    :data:`LEVELS` below it, LAMMPS's time on 1 and on 2 ranks, the fastest
    CollectivePRK (order and its interpolated step) and the fastest
    SuzukiTrotter, each with its ratio to both; and a line with the largest
    CollectivePRK / LAMMPS ratios."""
    labels = list(dict.fromkeys(r[0] for r in rows))
    one_rank = [r[3] for r in rows if r[0] == LAMMPS]
    two = lammps_label(2) if lammps_label(2) in labels else None
    loosest = max(one_rank) if one_rank else LEVELS[0]
    levels = [loosest] + [t for t in LEVELS if t < 0.95 * loosest]

    def best(prefix, target):
        times = {label: time_at_error(rows, label, target) for label in labels
                 if label.startswith(prefix)}
        times = {k: v for k, v in times.items() if v is not None}
        if not times:
            return None, None
        label = min(times, key=times.get)
        return label, times[label]

    def ratio(t, ref):
        return f"{t / ref:.2f}" if t is not None and ref is not None else "-"

    def seconds(t):
        return f"{t:.3f}" if t is not None else "-"

    lines = [("| spin RMS | LAMMPS 1 rank (s) | LAMMPS 2 ranks (s) | best CollectivePRK "
              "(order, dt fs) | its time (s) | / LAMMPS 1 | / LAMMPS 2 | best SuzukiTrotter "
              "| / LAMMPS 1 | / LAMMPS 2 |"), "|" + "---|" * 10]
    worst = {1: (0.0, None), 2: (0.0, None)}
    for target in levels:
        ref1 = time_at_error(rows, LAMMPS, target)
        ref2 = time_at_error(rows, two, target) if two else None
        c_label, c_time = best("CollectivePRK", target)
        s_label, s_time = best("SuzukiTrotter", target)
        if c_label is None and s_label is None:
            continue
        c_text = "-"
        if c_label:
            order = c_label.split("order ")[-1]
            c_text = f"{order}, {at_error(rows, c_label, target, value=1):.3g}"
            for ranks, ref in ((1, ref1), (2, ref2)):
                if ref is not None and c_time / ref > worst[ranks][0]:
                    worst[ranks] = (c_time / ref, target)
        s_text = ("order 4" if "order 4" in s_label else "order 2") if s_label else "-"
        lines.append(f"| {target:.3g} | {seconds(ref1)} | {seconds(ref2)} | {c_text} | "
                     f"{seconds(c_time)} | {ratio(c_time, ref1)} | {ratio(c_time, ref2)} | "
                     f"{s_text} | {ratio(s_time, ref1)} | {ratio(s_time, ref2)} |")
    for ranks, (w, target) in worst.items():
        if target is not None:
            lines.append(f"largest best-CollectivePRK / LAMMPS {ranks} rank{'s' * (ranks > 1)}: "
                         f"{w:.2f} (at spin RMS {target:.3g})")
    return lines


def plot(results, out):
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib not installed: no plot")
        return
    scenes = list(results)
    fig, axes = plt.subplots(len(scenes), 2, figsize=(11, 4.2 * len(scenes)), squeeze=False)
    for (scene, rows), (ax_s, ax_x) in zip(results.items(), axes):
        labels = list(dict.fromkeys(r[0] for r in rows))
        for label in labels:
            sel = [r for r in rows if r[0] == label]
            style = "--" if "LAMMPS" in label else ("-." if "Suzuki" in label else "-")
            for ax, k in ((ax_s, 3), (ax_x, 4)):
                ax.loglog([r[2] for r in sel], [r[k] for r in sel], style, marker="o", ms=4,
                          label=label)
        ax_s.set(xlabel="wall time (s)", ylabel="spin RMS error", title=f"{scene}: spins")
        ax_x.set(xlabel="wall time (s)", ylabel="position RMS error (Å)",
                 title=f"{scene}: positions")
        ax_s.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "work_precision.png", dpi=110)


def main(argv=None):
    parser = argparse.ArgumentParser()
    parser.add_argument("--scenes", nargs="+", default=["fcc500", "chain"],
                        choices=["fcc500", "fcc4000", "fcc500-field", "chain"])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", default="work_precision_output")
    parser.add_argument("--quick", action="store_true", help="three steps per method")
    parser.add_argument("--min-dt", type=float, default=0.0,
                        help="leave out steps below this (fs; the chain: its time unit): "
                             "the loose-accuracy end alone, e.g. with more --repeats")
    parser.add_argument("--lammps-ranks", type=int, nargs="+", default=[1, 2],
                        help="MPI ranks of the LAMMPS runs (more than 1: under mpiexec)")
    parser.add_argument("--in-process", action="store_true",
                        help="time dyn.run alone, in this process, its kernels loaded (the "
                             "steady cost), instead of a fresh process a run")
    parser.add_argument("--keep-reference", action="store_true",
                        help="read the DOP853 reference from --out if an earlier run left it "
                             "there, else write it there")
    parser.add_argument("--one", help=argparse.SUPPRESS)
    parser.add_argument("--warm-up", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.one:
        one(json.loads(args.one))
        return
    if args.warm_up:
        spec = json.loads(args.warm_up)
        warm_up(spec["scene"], spec["methods"])
        return
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    mode = "in-process (dyn.run alone, kernels loaded)" if args.in_process else (
        "a fresh process a run (set-up, first step and loading the kernels timed)")
    header = f"{describe()}\n# {mode}; load average at start {os.getloadavg()[0]:.2f}"
    print(header, flush=True)
    results = {}
    for scene in args.scenes:
        methods = CHAIN_METHODS if scene == "chain" else FCC_METHODS
        methods = [(label, kind, options, [dt for dt in steps if dt >= args.min_dt])
                   for label, kind, options, steps in methods]
        results[scene] = measure(scene, methods, args.repeats, args.quick,
                                 fresh=not args.in_process, lammps_ranks=args.lammps_ranks,
                                 keep=out if args.keep_reference else None)
    with open(out / "work_precision.txt", "w") as f:
        f.write(header + f"; at end {os.getloadavg()[0]:.2f}\n")
        f.write("# scene method dt wall_s spin_rms pos_rms sweeps_per_step runs load\n")
        for scene, rows in results.items():
            for label, dt, wall, es, ex, it, runs, load in rows:
                f.write(f"{scene}\t{label}\t{dt:.6g}\t{wall:.5f}\t{es:.4e}\t{ex:.4e}\t{it:.2f}"
                        f"\t{runs}\t{load:.2f}\n")
        for scene, rows in results.items():
            if any(r[0].startswith("LAMMPS") for r in rows):
                f.write(f"# {scene}: wall time at equal spin RMS error (interpolated)\n")
                print(f"# {scene}: wall time at equal spin RMS error (interpolated)")
                for line in equal_error_table(rows):
                    f.write("# " + line + "\n")
                    print(line)
    print(f"# load average at end {os.getloadavg()[0]:.2f}")
    plot(results, out)
    print(f"wrote {out}/work_precision.txt and .png")


if __name__ == "__main__":
    main()
