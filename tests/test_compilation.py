"""What numba compiles: one specialisation per kernel for a scene."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import PACKAGE_PATH, finish

ROOT = Path(__file__).resolve().parents[1]

SCRIPT = r"""
import gc, json
from ase import units
from numba.core.registry import CPUDispatcher
import ase_spin
from ase_spin.scenes import dipolar_sums, fcc_cobalt, field_anisotropy_terms, other_spin_terms

for n in (3, 8):  # 108 atoms (serial kernels), 2048 (threaded)
    for extra in ((), field_anisotropy_terms()):
        atoms = fcc_cobalt(n, extra=extra)
        atoms.rattle(0.02, seed=1)
        atoms.get_potential_energy(); atoms.get_stress(); atoms.calc.get_magnetic_forces(atoms)
        ase_spin.CollectivePRK(atoms, 0.1 * units.fs).run(3)
        ase_spin.CollectivePRK(atoms, 0.1 * units.fs, order=4).run(2)
        ase_spin.SuzukiTrotter(atoms, 0.1 * units.fs).run(2)
        ase_spin.Langevin(atoms, 0.1 * units.fs, 100.0, spin_damping=0.01, friction=0.01,
                          rng=0).run(2)
# every other spin term (per-term kernels), and a frozen lattice's compiled runs
atoms = fcc_cobalt(3, extra=other_spin_terms())
atoms.rattle(0.02, seed=1)
ase_spin.CollectivePRK(atoms, 0.1 * units.fs).run(3)
ase_spin.Langevin(atoms, 0.1 * units.fs, 100.0, spin_damping=0.01, friction=0.01, rng=0).run(2)
ase_spin.CollectivePRK(fcc_cobalt(3), 0.1 * units.fs, lattice="frozen").run(4)
# the dipolar sums over k-vectors and on a mesh, as ase-spin compile runs them
for n, methods in ((3, ("ewald", "pme")), (8, ("pme",))):
    atoms = fcc_cobalt(n, extra=dipolar_sums(methods))
    atoms.rattle(0.02, seed=1)
    atoms.get_stress()
    ase_spin.CollectivePRK(atoms, 0.1 * units.fs).run(3)
signatures = {}
for d in gc.get_objects():
    if isinstance(d, CPUDispatcher) and d.py_func.__module__.startswith("ase_spin"):
        signatures[f"{d.py_func.__module__}.{d.py_func.__qualname__}"] = [
            str(s) for s in d.signatures]
print(json.dumps(signatures))
"""

#: Kernels called with several array types on purpose (``same`` compares
#: positions, masses and atomic numbers).
SEVERAL = {"ase_spin.md.kernels.same"}


def start_scan():
    """The scan of :data:`SCRIPT` in a child process, started (conftest.py
    starts it when the test run begins: its compilation then runs on a core the
    test process leaves free, and fills numba's cache for the tests after it)."""
    env = {**os.environ, "PYTHONPATH": PACKAGE_PATH, "ASE_SPIN_QUIET_COMPILE": "1"}
    # run from the folder of that copy: "-c" puts the working folder first on sys.path
    return subprocess.Popen([sys.executable, "-c", SCRIPT], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env, cwd=PACKAGE_PATH,
                            start_new_session=True)


#: The scan started by conftest.py, if it was (else the test starts it).
started = []


def test_each_kernel_is_compiled_for_one_set_of_argument_types():
    """Small and large systems, with and without single-site terms, through the
    calculator and four integrators (the small system's fused step included),
    every other spin term, a frozen lattice and the dipolar Ewald and mesh
    sums: every kernel but ``same`` is specialised once (arguments normalised
    where they enter: contiguous arrays, float and int64 scalars), so a scene
    compiles each kernel once."""
    scan = started.pop() if started else start_scan()
    stdout, stderr = finish(scan, timeout=1200)
    assert scan.returncode == 0, stderr
    signatures = json.loads(stdout.strip().splitlines()[-1])
    assert len(signatures) > 20, signatures  # the scan saw the kernels
    several = {k: v for k, v in signatures.items() if len(v) > 1 and k not in SEVERAL}
    assert not several, json.dumps(several, indent=1)


def test_compile_with_names_a_skeleton_after_the_package_source(monkeypatch):
    """A skeleton compiled with bound functions is cached under a name carrying
    a hash of the whole package's source: an edit of any helper it runs (in
    any module) gives a new cache entry instead of the stale machine code."""
    from ase_spin._jit import cache as compilation
    from ase_spin._jit.cloning import compile_with
    from ase_spin.md import fused_skeletons, kernels

    def name():
        fn = compile_with(fused_skeletons.run_frozen_steps, {"solve": kernels.midpoint_solve.serial,
                                                   "extrapolate": kernels.extrapolate_rows.serial,
                                                   "best_order": kernels.best_order_rows}, "x")
        return fn.py_func.__qualname__

    assert compilation.source_digest() and name() == name()
    first = name()
    monkeypatch.setattr(compilation, "_digest", b"another source")
    assert name() != first


def test_stale_cached_kernels_are_removed_once_per_source(tmp_path):
    """A cache folder stamped with another source digest (or none) loses this
    package's cached kernels — those of its own folder's modules only — and is
    stamped; with the current stamp nothing is removed."""
    from ase_spin._jit import cache as compilation

    package = tmp_path / "pkg"
    cache = tmp_path / "cache"
    package.mkdir()
    cache.mkdir()
    (package / "kernels.py").write_text("")
    ours = ["kernels.kick-12.py311.nbi", "kernels.kick-12.py311.1.nbc"]
    theirs = ["other.f-3.py311.nbi", "kernels.txt"]
    for name in ours + theirs:
        (cache / name).write_bytes(b"x")
    folders = {str(cache): package}
    removed = compilation.clear_stale_caches(folders, b"one")
    assert sorted(removed) == sorted(str(cache / n) for n in ours)
    assert sorted(p.name for p in cache.iterdir()) == sorted(theirs + [compilation.STAMP])
    assert (cache / compilation.STAMP).read_text().strip() == b"one".hex()
    (cache / ours[0]).write_bytes(b"x")  # compiled again from the same source: kept
    assert compilation.clear_stale_caches(folders, b"one") == []
    assert compilation.clear_stale_caches(folders, b"two") == [str(cache / ours[0])]


def test_every_cache_folder_of_the_package_carries_the_current_stamp():
    """Importing ase_spin has stamped each folder numba caches its kernels in."""
    from ase_spin._jit import cache as compilation

    folders = compilation.cache_folders()
    assert len(folders) >= 3  # ase_spin, ase_spin/md, ase_spin/terms, ...
    for cache in folders:
        with open(os.path.join(cache, compilation.STAMP)) as f:
            assert f.read().strip() == compilation.source_digest().hex()
    from ase_spin.md import kernels
    from ase_spin.neighbors import max_displacement

    assert compilation.cache_dir(kernels.kick.parallel) in folders
    assert compilation.cache_dir(max_displacement) in folders


EDIT = r"""
import sys
from ase_spin.scenes import fcc_cobalt
atoms = fcc_cobalt(2)
print(atoms.get_potential_energy())
"""


@pytest.mark.slow
def test_an_edit_of_an_inlined_helper_reaches_the_kernels_that_inline_it(tmp_path):
    """End to end, in a copy of the package: a kernel cached on disk, then an
    edit of a helper it inlines from another module (``separation`` in
    neighbors/checks.py, inlined by the Lennard-Jones kernel): the next process gives
    the edited result, not the cached machine code's."""
    import shutil

    shutil.copytree(ROOT / "ase_spin", tmp_path / "ase_spin",
                    ignore=shutil.ignore_patterns("__pycache__"))
    env = {**os.environ, "PYTHONPATH": str(tmp_path), "ASE_SPIN_QUIET_COMPILE": "1"}
    env.pop("NUMBA_CACHE_DIR", None)

    def energy():
        done = subprocess.run([sys.executable, "-c", EDIT], capture_output=True, text=True,
                              env=env, timeout=600, cwd=tmp_path)
        assert done.returncode == 0, done.stderr
        return float(done.stdout.strip().splitlines()[-1])

    before = energy()
    assert energy() == before  # from the cache
    neighbors = tmp_path / "ase_spin" / "neighbors" / "checks.py"
    text = neighbors.read_text()
    old = "    return dx, dy, dz, dx * dx + dy * dy + dz * dz\n"
    assert text.count(old) == 1
    neighbors.write_text(text.replace(old, "    return dx, dy, dz, 1.01 * (dx * dx + dy * dy + dz * dz)\n"))
    assert energy() != before
