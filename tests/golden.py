"""The golden record: sha256 of the raw bytes of q, p and s after a fixed
number of steps of each reference scene, with the thread count fixed.

The record (tests/data/golden.json) was taken on main before the package was
reorganised; a refactoring that changes no number leaves every hash as it is.
Numba compiles for the host CPU, whose vector width may change the last bits
of a vectorised sum, so the hashes are kept per CPU (llvmlite's host name and
features); on a CPU not in the record the test checks a rounded fingerprint
(10 significant digits of sums of the arrays) instead.

``python tests/golden.py --record`` adds this CPU's hashes to the record.

``python tests/golden.py --cpu znver4 [--record]`` runs the scenes as numba
compiles them for another CPU of the record (its name and features given to
numba: ``NUMBA_CPU_NAME``, ``NUMBA_CPU_FEATURES``, in a process of its own with
a cache folder of its own), says which hashes match, and with ``--record``
records them under that CPU: a change of the last bits can then be recorded
for a CPU one does not have, on a host that runs all of its instructions (an
Intel Xeon with AVX-512, emeraldrapids, reproduced all 15 znver4 hashes).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from ase import units
from ase.build import bulk

import ase_spin
from ase_spin import scenes

RECORD = Path(__file__).with_name("data") / "golden.json"
#: Active threads of the runs: one. The threaded kernels split their work into
#: NUMBA_NUM_THREADS chunks whatever the active count (the same bits: the
#: record was taken with two), and one thread does not wait at every parallel
#: region for a core the other test runner holds.
THREADS = 1


def _all_spin_terms():
    """Every spin term together on a small rattled fcc Co crystal (with LJ)."""
    atoms = bulk("Co", "fcc", a=3.54, cubic=True).repeat(3)
    atoms.rattle(0.02, seed=3)
    atoms.set_masses(np.full(len(atoms), 58.93))
    rng = np.random.default_rng(5)
    ase_spin.set_spins(atoms, scenes.cone(len(atoms), rng, 40.0), magnitudes=1.72)
    atoms.set_momenta(rng.normal(size=(len(atoms), 3)) * 0.05)
    atoms.calc = ase_spin.SpinLatticeCalculator([
        ase_spin.LennardJones(epsilon=0.4, sigma=2.2742, rc=4.7, cutoff="shift"),
        ase_spin.Exchange(ase_spin.BetheSlater(J1=0.0446928, J2=0.003496, J3=1.4885), rc=4.0),
        ase_spin.Zeeman(5.0, [0.1, 0.2, 1.0], g=2.0, mu_B=ase_spin.MU_B),
        ase_spin.UniaxialAnisotropy(0.01, [1.0, 0.0, 0.0]),
        ase_spin.CubicAnisotropy(0.002, 0.001),
        ase_spin.DMI(0.003, [0.0, 0.0, 1.0], rc=2.6),
        ase_spin.BiquadraticExchange(ase_spin.BetheSlater(0.01, 0.001, 1.5),
                                     ase_spin.BetheSlater(0.002, 0.0005, 1.5), rc=2.6),
        ase_spin.ShellExchange([(2.503, 0.02), (3.54, 0.004)], tol=0.2),
    ])
    return atoms


def _chain(dyn_kwargs, steps=200):
    return lambda: (scenes.paper_chain(30),
                    dict(timestep=0.01, hbar=1.0, precession="spin", **dyn_kwargs), steps)


def _co(n, steps, dt_fs=0.1, **kw):
    return lambda: (scenes.fcc_cobalt(n), dict(timestep=dt_fs * units.fs, **kw), steps)


#: name -> (make: () -> (atoms, integrator keywords, steps), integrator)
SCENES = {
    "paper_chain": (_chain({}), "CollectivePRK"),
    "paper_chain_order4": (_chain(dict(order=4), 100), "CollectivePRK"),
    "fcc_co_108": (_co(3, 100), "CollectivePRK"),
    "fcc_co_500_order4": (_co(5, 20, 0.5, order=4), "CollectivePRK"),
    "fcc_co_500_order6": (_co(5, 10, 0.5, order=6), "CollectivePRK"),
    "fcc_co_500_frozen": (_co(5, 50, 0.5, lattice="frozen"), "CollectivePRK"),
    "fcc_co_2048": (_co(8, 10), "CollectivePRK"),
    "fcc_co_2048_frozen_order4": (_co(8, 5, 0.5, lattice="frozen", order=4), "CollectivePRK"),
    "all_spin_terms": (lambda: (_all_spin_terms(), dict(timestep=0.2 * units.fs), 40),
                       "CollectivePRK"),
    "all_spin_terms_order4": (lambda: (_all_spin_terms(), dict(timestep=0.3 * units.fs,
                                                               order=4), 10), "CollectivePRK"),
    "fcc_co_108_fused": (_co(3, 100), "CollectivePRK"),
    "paper_chain_fused": (_chain({}), "CollectivePRK"),
    "suzuki_trotter_108": (_co(3, 50), "SuzukiTrotter"),
    "suzuki_trotter_500_order4": (_co(5, 10, 0.5, order=4), "SuzukiTrotter"),
    "langevin_108": (lambda: (scenes.fcc_cobalt(3),
                              dict(timestep=0.2 * units.fs, temperature_K=300.0,
                                   spin_damping=0.05, friction=0.01 / units.fs,
                                   rng=np.random.default_rng(42)), 50), "Langevin"),
}


def general_path(name, setattr):
    """The scenes with a ``*_fused`` twin take the general path, neither the
    compiled small-system step nor blocks of them (md/fused.py), which every
    other scene takes where it applies, as a user's run does: the record holds
    both paths of the same scene. ``setattr``: a monkeypatch's, to put it back."""
    from ase_spin.md import fused

    if f"{name}_fused" in SCENES:
        setattr(fused, "collective_step", lambda *args: None)
        setattr(fused, "collective_block", lambda *args: (0, 0, 0, 0))


def run(name):
    """(sha256 of the bytes of q, p, s; a rounded fingerprint) of one scene."""
    make, integrator = SCENES[name]
    atoms, kwargs, steps = make()
    # the equations the hashes were recorded with (the defaults before the
    # conventions of a scene set them): rate 1 and CODATA ħ
    kwargs = {"gyromagnetic": "lammps", "hbar": ase_spin.HBAR, **kwargs}
    dyn = getattr(ase_spin, integrator)(atoms, threads=THREADS, **kwargs)
    dyn.run(steps)
    q = np.ascontiguousarray(atoms.get_positions())
    p = np.ascontiguousarray(atoms.get_momenta())
    s = np.ascontiguousarray(ase_spin.get_spins(atoms))
    digest = hashlib.sha256(q.tobytes() + p.tobytes() + s.tobytes()).hexdigest()
    weights = np.linspace(1.0, 2.0, len(atoms))[:, None] * np.array([1.0, np.pi, np.e])
    fingerprint = [float(f"{(weights * a).sum():.10e}") for a in (q, p, s)]
    return digest, fingerprint


def cpu():
    """The host CPU as numba compiles for it."""
    import llvmlite.binding as llvm

    return f"{llvm.get_host_cpu_name()} {llvm.get_host_cpu_features().flatten()}"


def load():
    return json.loads(RECORD.read_text()) if RECORD.exists() else {"hashes": {}, "fingerprints": {}}


#: Set in the process :func:`as_cpu` starts: the record's CPU it compiles for.
AS_CPU = "ASE_SPIN_GOLDEN_CPU"


def recorded_cpu(name):
    """The record's CPU (its key) whose name is ``name``."""
    keys = [k for k in load()["hashes"] if k.split(" ", 1)[0] == name]
    if len(keys) != 1:
        raise SystemExit(f"the record has {len(keys)} CPUs named {name!r}: "
                         f"{sorted(k.split(' ', 1)[0] for k in load()['hashes'])}")
    return keys[0]


def as_cpu(key, argv):
    """Run this script with ``argv`` in a new process that numba compiles
    for the record's CPU ``key`` (a cache folder of its own, kept between
    calls, so that no kernel compiled for one CPU is loaded for another)."""
    name, features = key.split(" ", 1)
    cache = os.path.join(tempfile.gettempdir(), f"ase_spin_golden_{name}")
    env = dict(os.environ, NUMBA_CPU_NAME=name, NUMBA_CPU_FEATURES=features,
               NUMBA_CACHE_DIR=cache, **{AS_CPU: key})
    return subprocess.run([sys.executable, __file__, *argv], env=env, check=False).returncode


def main(argv=None):
    import pytest

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("names", nargs="*", help="scenes (default: all)")
    parser.add_argument("--record", action="store_true", help="record the hashes")
    parser.add_argument("--cpu", help="compile for this CPU of the record (its name)")
    args = parser.parse_args(argv)
    if args.cpu and AS_CPU not in os.environ:
        rest = [*args.names, *(["--record"] if args.record else [])]
        return as_cpu(recorded_cpu(args.cpu), rest)
    key = os.environ.get(AS_CPU) or cpu()
    record = load()
    hashes = record["hashes"].setdefault(key, {})
    differ = 0
    for name in args.names or list(SCENES):
        with pytest.MonkeyPatch.context() as patch:
            general_path(name, patch.setattr)
            digest, fingerprint = run(name)
        same = {None: "not recorded", True: "as recorded", False: "CHANGED"}[
            None if name not in hashes else hashes[name] == digest]
        differ += same == "CHANGED"
        print(f"{name:28s} {digest[:16]}  {same:12s} {fingerprint}")
        if args.record:
            hashes[name] = digest
            record["fingerprints"][name] = fingerprint
    print(f"# {key.split(' ', 1)[0]}: {differ} scenes changed")
    if args.record:
        RECORD.write_text(json.dumps(record, indent=1, sort_keys=True) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
