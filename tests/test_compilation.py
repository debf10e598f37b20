"""What numba compiles: one specialisation per kernel for a scene."""

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

SCRIPT = r"""
import gc, json
from ase import units
from numba.core.registry import CPUDispatcher
import ase_spin
from ase_spin.scenes import fcc_cobalt, field_anisotropy_terms

for n in (3, 8):  # 108 atoms (serial kernels), 2048 (threaded)
    for extra in ((), field_anisotropy_terms()):
        atoms = fcc_cobalt(n, extra=extra)
        atoms.rattle(0.02, seed=1)
        atoms.get_potential_energy(); atoms.get_stress(); atoms.calc.get_magnetic_forces(atoms)
        ase_spin.CollectivePRK(atoms, 0.1 * units.fs).run(3)
        ase_spin.CollectivePRK(atoms, 0.1 * units.fs, order=4).run(2)
        ase_spin.SuzukiTrotter(atoms, 0.1 * units.fs).run(2)
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


def test_each_kernel_is_compiled_for_one_set_of_argument_types():
    """Small and large systems, with and without single-site terms, through the
    calculator and three integrators: every kernel but ``same`` is specialised
    once (arguments normalised where they enter: contiguous arrays, float and
    int64 scalars), so a scene compiles each kernel once."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "ASE_SPIN_QUIET_COMPILE": "1"}
    done = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True,
                          env=env, timeout=1200)
    assert done.returncode == 0, done.stderr
    signatures = json.loads(done.stdout.strip().splitlines()[-1])
    assert len(signatures) > 20, signatures  # the scan saw the kernels
    several = {k: v for k, v in signatures.items() if len(v) > 1 and k not in SEVERAL}
    assert not several, json.dumps(several, indent=1)


def test_compile_with_names_a_skeleton_after_the_package_source(monkeypatch):
    """A skeleton compiled with bound functions is cached under a name carrying
    a hash of the whole package's source: an edit of any helper it runs (in
    any module) gives a new cache entry instead of the stale machine code."""
    from ase_spin.md import fused, kernels
    from ase_spin.terms import base

    def name():
        fn = base.compile_with(fused._run_frozen, {"solve": kernels.midpoint_solve.serial,
                                                   "extrapolate": kernels._extrapolate.serial,
                                                   "best_order": kernels._best_order}, "x")
        return fn.py_func.__qualname__

    assert base._source_digest() and name() == name()
    first = name()
    monkeypatch.setattr(base, "_package_digest", b"another source")
    assert name() != first
