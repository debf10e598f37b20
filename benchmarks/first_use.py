"""First-use compilation: start-up times with numba's disk cache cold and warm.

Copies the package to a temporary folder (no ``__pycache__``: a fresh copy),
then runs the same short script in new processes, first against the empty
cache (numba compiles every kernel the script needs), then again (numba loads
them from its cache). With ``--pip`` it also installs the copy into a new
virtual environment (``pip install --no-deps``, system packages visible) and
times a first run, a second run, and a run after ``pip install
--force-reinstall`` of the same source, reporting where the cache files went;
with ``--unwritable``, a copy whose folders numba cannot write to (a
system-wide install run by a user): the cache goes to the user's cache folder.

    python benchmarks/first_use.py [--unwritable] [--pip]
    python benchmarks/first_use.py --before OLD_TREE [--repeat 2]
    python benchmarks/first_use.py --after-compile

``--before`` measures another source tree (e.g. ``git worktree add /tmp/old
<commit>``) in the same run: for each repeat, each tree in turn (alternating),
a fresh copy cold then warm, and ``examples/demo.py`` (500 atoms, 500 steps)
in another fresh copy cold then warm; medians over the repeats. Besides wall
times it reports each process's CPU time (user + sys, children included),
which another job on the machine changes less: compilation runs on one core.

Stages of the script (fcc Co, 4·3³ = 108 atoms, LJ + Bethe–Slater exchange):
import ase_spin; one calculator evaluation (E, F, B, stress); 2 CollectivePRK
steps; 2 SuzukiTrotter steps; 2 CollectivePRK steps with Zeeman and uniaxial
anisotropy added (their own kernels).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CHILD = r"""
import json, time
t = [time.perf_counter()]
import ase_spin
t.append(time.perf_counter())
from ase import units
from ase.build import bulk
from ase_spin import (BetheSlater, CollectivePRK, Exchange, LennardJones, SpinLatticeCalculator,
                      SuzukiTrotter, UniaxialAnisotropy, Zeeman)
import numpy as np
def scene(extra=()):
    atoms = bulk("Co", "fcc", a=3.54, cubic=True).repeat(3)
    atoms.rattle(0.03, seed=1)
    ase_spin.set_spins(atoms, np.random.default_rng(0).normal(size=(len(atoms), 3)) + [0, 0, 3], 1.72)
    atoms.calc = SpinLatticeCalculator([LennardJones(0.4, 2.2742, 4.7, cutoff="shift"),
        Exchange(BetheSlater(0.0446928, 0.003496, 1.4885), rc=4.0), *extra])
    return atoms
a = scene()
a.get_potential_energy(); a.get_forces(); a.get_stress(); a.calc.get_magnetic_forces(a)
t.append(time.perf_counter())
CollectivePRK(scene(), 0.1 * units.fs).run(2)
t.append(time.perf_counter())
SuzukiTrotter(scene(), 0.1 * units.fs).run(2)
t.append(time.perf_counter())
CollectivePRK(scene([Zeeman([0, 0, 1.0]), UniaxialAnisotropy(0.01, [0, 0, 1])]), 0.1 * units.fs).run(2)
t.append(time.perf_counter())
print(json.dumps({"stages": [b - a for a, b in zip(t, t[1:])], "file": ase_spin.__file__}))
"""

#: A script whose combination of terms and integrators the built-in set of
#: ``ase-spin compile`` does not run: bcc Fe with exchange, DMI, cubic
#: anisotropy, biquadratic exchange and a field, NVE (order 4) then Langevin.
NEW_COMBINATION = r"""
import json, time
t0 = time.perf_counter()
import numpy as np
from ase import units
from ase.build import bulk
import ase_spin
atoms = bulk("Fe", "bcc", a=2.87, cubic=True).repeat(6)
ase_spin.set_spins(atoms, np.random.default_rng(0).normal(size=(len(atoms), 3)) + [0, 0, 3], 2.2)
atoms.calc = ase_spin.SpinLatticeCalculator([
    ase_spin.LennardJones(0.3, 2.3, 4.0, cutoff="shift"),
    ase_spin.Exchange(ase_spin.BetheSlater(0.03, 0.002, 1.4), rc=3.5),
    ase_spin.DMI(0.002, [0, 0, 1], rc=2.6), ase_spin.CubicAnisotropy(1e-4, 0.0),
    ase_spin.BiquadraticExchange(ase_spin.BetheSlater(0.003, 0.0, 1.4),
                                 ase_spin.BetheSlater(0.001, 0.0, 1.4), rc=2.6),
    ase_spin.Zeeman([0, 0, 2.0])])
ase_spin.CollectivePRK(atoms, 0.1 * units.fs, order=4).run(5)
ase_spin.Langevin(atoms, 0.1 * units.fs, 300.0, spin_damping=0.05, friction=0.001, rng=1).run(5)
print(json.dumps({"wall": time.perf_counter() - t0}))
"""

STAGES = ["import ase_spin", "calculator E, F, B, stress", "CollectivePRK, 2 steps",
          "SuzukiTrotter, 2 steps", "CollectivePRK + Zeeman + anisotropy, 2 steps"]


def _timed(argv, env, cwd):
    """Run a process; (its CompletedProcess, wall s, CPU s of it and its children)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = _now()
    done = subprocess.run(argv, capture_output=True, text=True, env=env, cwd=cwd, timeout=1800)
    wall = _now() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if done.returncode:
        raise SystemExit(done.stderr)
    return done, wall, cpu


def run_child(python, env, cwd):
    done, wall, cpu = _timed([python, "-c", CHILD], env, cwd)
    result = json.loads(done.stdout.strip().splitlines()[-1])
    result["wall"] = wall
    result["cpu"] = cpu
    result["announced"] = "compiling numba kernels" in done.stderr
    return result


def run_demo(python, env, cwd):
    """examples/demo.py as a user runs it: wall and CPU time of the process, and
    the time of its first 50 steps as it prints them (with compilation)."""
    done, wall, cpu = _timed([python, str(ROOT / "examples" / "demo.py")], env, cwd)
    first = re.search(r"the first 50 in ([0-9.]+) s", done.stdout)
    return {"wall": wall, "cpu": cpu, "first50": float(first.group(1)) if first else float("nan")}


def _now():
    import time

    return time.perf_counter()


def _clean_env(**extra):
    env = {k: v for k, v in os.environ.items()
           if k not in ("NUMBA_CACHE_DIR", "PYTHONPATH", "ASE_SPIN_QUIET_COMPILE")}
    env.update(extra)
    return env


def _copy_source(dest, root=ROOT):
    dest.mkdir(parents=True)
    shutil.copytree(root / "ase_spin", dest / "ase_spin",
                    ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(root / name, dest / name)


def _load():
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def _median(values):
    values = sorted(values)
    n = len(values)
    return values[n // 2] if n % 2 else 0.5 * (values[n // 2 - 1] + values[n // 2])


def compare(before, repeat):
    """Cold and warm start of two trees, alternating, ``repeat`` rounds; medians."""
    trees = {"before": before, "after": ROOT}
    runs = {(name, kind): [] for name in trees for kind in ("cold", "warm", "demo cold",
                                                          "demo warm")}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        neutral = tmp / "run"
        neutral.mkdir()
        for r in range(repeat):
            for name, root in trees.items():
                copy = tmp / f"{name}{r}"
                _copy_source(copy, root)
                env = _clean_env(PYTHONPATH=str(copy))
                runs[name, "cold"].append(run_child(sys.executable, env, neutral))
                runs[name, "warm"].append(run_child(sys.executable, env, neutral))
                demo = tmp / f"{name}{r}demo"
                _copy_source(demo, root)
                env = _clean_env(PYTHONPATH=str(demo))
                runs[name, "demo cold"].append(run_demo(sys.executable, env, neutral))
                runs[name, "demo warm"].append(run_demo(sys.executable, env, neutral))
                print(f"# round {r + 1}, {name}: cold {runs[name, 'cold'][-1]['wall']:.1f} s, "
                      f"warm {runs[name, 'warm'][-1]['wall']:.1f} s, demo cold "
                      f"{runs[name, 'demo cold'][-1]['wall']:.1f} s, demo warm "
                      f"{runs[name, 'demo warm'][-1]['wall']:.1f} s (load {_load()})",
                      flush=True)
    columns = [(f"{kind}, {name}", runs[name, kind]) for kind in ("cold", "warm")
               for name in trees]
    print(f"\nmedians of {repeat} round(s), seconds; before = {before}, after = {ROOT}\n")
    print("| stage | " + " | ".join(c for c, _ in columns) + " |")
    print("|---|" + "---|" * len(columns))
    for k, stage in enumerate(STAGES):
        print(f"| {stage} | " + " | ".join(f"{_median([x['stages'][k] for x in xs]):.2f}"
                                           for _, xs in columns) + " |")
    for key, label in (("wall", "whole process (wall)"), ("cpu", "whole process (CPU)")):
        print(f"| {label} | " + " | ".join(f"{_median([x[key] for x in xs]):.2f}"
                                           for _, xs in columns) + " |")
    print("\nexamples/demo.py (500 atoms, 500 steps), seconds:\n")
    columns = [(f"{kind}, {name}", runs[name, f"demo {kind}"]) for kind in ("cold", "warm")
               for name in trees]
    print("| | " + " | ".join(c for c, _ in columns) + " |")
    print("|---|" + "---|" * len(columns))
    for key, label in (("first50", "first 50 steps (as printed)"),
                       ("wall", "whole process (wall)"), ("cpu", "whole process (CPU)")):
        print(f"| {label} | " + " | ".join(f"{_median([x[key] for x in xs]):.2f}"
                                           for _, xs in columns) + " |")


def after_compile():
    """A fresh copy: ``ase-spin compile`` (its built-in set), then the 108-atom
    script, examples/demo.py, the command line on examples/co_fcc.toml and
    :data:`NEW_COMBINATION` in new processes."""
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        copy = tmp / "copy"
        _copy_source(copy)
        neutral = tmp / "run"
        neutral.mkdir()
        env = _clean_env(PYTHONPATH=str(copy))
        _, compile_wall, compile_cpu = _timed(
            [sys.executable, "-c", "from ase_spin.app.cli import main; main(['compile'])"],
            env, neutral)
        rows = [("ase-spin compile", compile_wall, compile_cpu)]
        script = run_child(sys.executable, env, neutral)
        rows.append(("108-atom script (built-in terms)", script["wall"], script["cpu"]))
        demo = run_demo(sys.executable, env, neutral)
        rows.append(("examples/demo.py", demo["wall"], demo["cpu"]))
        shutil.copy(ROOT / "examples" / "co_fcc.toml", neutral)
        _, wall, cpu = _timed([sys.executable, "-c",
                               "from ase_spin.app.cli import main; main(['run', 'co_fcc.toml'])"],
                              env, neutral)
        rows.append(("ase-spin run examples/co_fcc.toml (500 atoms, 2000 steps)", wall, cpu))
        for label in ("new combination, first run", "new combination, second run"):
            done, wall, cpu = _timed([sys.executable, "-c", NEW_COMBINATION], env, neutral)
            rows.append((label, wall, cpu))
        print("Fresh copy; ase-spin compile, then scripts in new processes:\n")
        print("| run | wall (s) | CPU (s) |\n|---|---|---|")
        for label, wall, cpu in rows:
            print(f"| {label} | {wall:.1f} | {cpu:.1f} |")


def _cache_files(folder):
    return sorted(str(p) for p in Path(folder).rglob("*.nbi"))


def table(rows):
    names = [name for name, _ in rows]
    print("| stage | " + " | ".join(names) + " |")
    print("|---|" + "---|" * len(names))
    for k, stage in enumerate(STAGES):
        print(f"| {stage} | " + " | ".join(f"{r['stages'][k]:.2f}" for _, r in rows) + " |")
    print("| whole process (wall) | " + " | ".join(f"{r['wall']:.2f}" for _, r in rows) + " |")
    print("| whole process (CPU) | " + " | ".join(f"{r['cpu']:.2f}" for _, r in rows) + " |")
    print("| compilation announced | " + " | ".join("yes" if r["announced"] else "no"
                                                   for _, r in rows) + " |")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pip", action="store_true",
                        help="also time a pip install into a fresh virtual environment")
    parser.add_argument("--unwritable", action="store_true",
                        help="also time a copy whose package folders numba cannot write to")
    parser.add_argument("--before", metavar="OLD_TREE",
                        help="another source tree to measure in the same run, alternating")
    parser.add_argument("--repeat", type=int, default=2, help="rounds with --before")
    parser.add_argument("--after-compile", action="store_true",
                        help="ase-spin compile in a fresh copy, then scripts: built-in terms, "
                             "the demo, a combination the built-in set does not run")
    args = parser.parse_args()
    sys.path.insert(0, str(ROOT / "benchmarks"))
    sys.path.insert(0, str(ROOT))
    from machine import describe

    print(describe(), flush=True)
    print(f"# load average at start: {_load()}", flush=True)
    if args.after_compile:
        after_compile()
        print(f"\n# load average at end: {_load()}")
        return
    if args.before:
        compare(Path(args.before).resolve(), args.repeat)
        print(f"\n# load average at end: {_load()}")
        return
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        copy = tmp / "copy"
        _copy_source(copy)
        neutral = tmp / "run"
        neutral.mkdir()
        env = _clean_env(PYTHONPATH=str(copy))
        rows = [("cold (s)", run_child(sys.executable, env, neutral)),
                ("warm (s)", run_child(sys.executable, env, neutral))]
        print("Fresh copy of the source tree (cache in its __pycache__ folders):\n")
        table(rows)
        print(f"\ncache index files written: {len(_cache_files(copy))}")
        if args.unwritable:
            # a package folder numba cannot write to (a system-wide install): a file
            # where __pycache__ would be makes numba's in-tree cache fail as a
            # read-only folder does (OSError), even for root
            blocked = tmp / "blocked"
            _copy_source(blocked)
            for folder in (blocked / "ase_spin").rglob("*"):
                if folder.is_dir() and folder.name != "__pycache__":
                    (folder / "__pycache__").write_text("")
            (blocked / "ase_spin" / "__pycache__").write_text("")
            user_cache = tmp / "xdg"
            env = _clean_env(PYTHONPATH=str(blocked), XDG_CACHE_HOME=str(user_cache))
            rows = [("cold (s)", run_child(sys.executable, env, neutral)),
                    ("warm (s)", run_child(sys.executable, env, neutral))]
            print("\nPackage folder not writable (cache in the user's cache folder):\n")
            table(rows)
            print(f"\ncache index files in $XDG_CACHE_HOME/numba: "
                  f"{len(_cache_files(user_cache / 'numba'))}, beside the modules: "
                  f"{len(_cache_files(blocked))}")
        if not args.pip:
            return
        venv = tmp / "venv"
        subprocess.run([sys.executable, "-m", "venv", "--system-site-packages", str(venv)],
                       check=True)
        python = str(venv / "bin" / "python")
        pip = [python, "-m", "pip", "install", "-q", "--no-deps"]
        source = tmp / "source"
        _copy_source(source)
        subprocess.run([*pip, str(source)], check=True)
        env = _clean_env()
        first = run_child(python, env, neutral)
        second = run_child(python, env, neutral)
        installed = Path(first["file"]).parent
        n_installed = len(_cache_files(installed))
        subprocess.run([*pip, "--force-reinstall", str(source)], check=True)
        left = len(_cache_files(installed))
        third = run_child(python, env, neutral)
        print(f"\npip install into a virtual environment ({installed}):\n")
        table([("first run (s)", first), ("second run (s)", second),
               ("after reinstall (s)", third)])
        print(f"\ncache index files beside the installed modules after the first runs: "
              f"{n_installed}; left after pip install --force-reinstall: {left}")


if __name__ == "__main__":
    main()
