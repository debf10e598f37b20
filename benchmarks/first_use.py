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

Stages of the script (fcc Co, 4·3³ = 108 atoms, LJ + Bethe–Slater exchange):
import ase_spin; one calculator evaluation (E, F, B, stress); 2 CollectivePRK
steps; 2 SuzukiTrotter steps; 2 CollectivePRK steps with Zeeman and uniaxial
anisotropy added (their own kernels).
"""

from __future__ import annotations

import argparse
import json
import os
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

STAGES = ["import ase_spin", "calculator E, F, B, stress", "CollectivePRK, 2 steps",
          "SuzukiTrotter, 2 steps", "CollectivePRK + Zeeman + anisotropy, 2 steps"]


def run_child(python, env, cwd):
    start = _now()
    done = subprocess.run([python, "-c", CHILD], capture_output=True, text=True, env=env,
                          cwd=cwd, timeout=1800)
    wall = _now() - start
    if done.returncode:
        raise SystemExit(done.stderr)
    result = json.loads(done.stdout.strip().splitlines()[-1])
    result["wall"] = wall
    result["announced"] = "compiling numba kernels" in done.stderr
    return result


def _now():
    import time

    return time.perf_counter()


def _clean_env(**extra):
    env = {k: v for k, v in os.environ.items()
           if k not in ("NUMBA_CACHE_DIR", "PYTHONPATH", "ASE_SPIN_QUIET_COMPILE")}
    env.update(extra)
    return env


def _copy_source(dest):
    dest.mkdir(parents=True)
    shutil.copytree(ROOT / "ase_spin", dest / "ase_spin",
                    ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, dest / name)


def _cache_files(folder):
    return sorted(str(p) for p in Path(folder).rglob("*.nbi"))


def table(rows):
    names = [name for name, _ in rows]
    print("| stage | " + " | ".join(names) + " |")
    print("|---|" + "---|" * len(names))
    for k, stage in enumerate(STAGES):
        print(f"| {stage} | " + " | ".join(f"{r['stages'][k]:.2f}" for _, r in rows) + " |")
    print("| whole process (wall) | " + " | ".join(f"{r['wall']:.2f}" for _, r in rows) + " |")
    print("| compilation announced | " + " | ".join("yes" if r["announced"] else "no"
                                                   for _, r in rows) + " |")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pip", action="store_true",
                        help="also time a pip install into a fresh virtual environment")
    parser.add_argument("--unwritable", action="store_true",
                        help="also time a copy whose package folders numba cannot write to")
    args = parser.parse_args()
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
