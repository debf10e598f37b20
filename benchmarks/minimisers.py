"""Spin minimisers against damped precession (issue 40): evaluations and wall
time to a torque of ``--fmax`` on a DMI film.

    python benchmarks/minimisers.py [--size 16] [--fmax 1e-6] [--field 1.0] [--seed 0]

Scene: a square monolayer (a = 2.5 Å, ``--size``² sites, periodic in-plane),
nearest-neighbour exchange J = 10 meV, interfacial DMI D = 3 meV, uniaxial
anisotropy K = 0.5 meV along z and a field ``--field`` T along z, μ = 2.2 μB
(tests/test_landscapes.py's ``film``); spins in a 60° cone about +z
(``--seed``). Frozen lattice. An "evaluation" is one pass over the spin terms
(what the fields at one set of spins cost), counted as the calls of the DMI
operator's ``field`` and ``add`` (every pass of either method calls it once).
Printed per method: steps, evaluations, seconds (warm: a first run of each
compiles), final energy and largest torque.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from test_landscapes import film  # noqa: E402

from ase_spin import get_spins, relax_spins  # noqa: E402
from ase_spin.optimize import SpinLBFGS, SpinVP  # noqa: E402
from ase_spin.terms.base import PairOperator  # noqa: E402

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--size", type=int, default=16)
parser.add_argument("--fmax", type=float, default=1e-6)
parser.add_argument("--seed", type=int, default=0)
args = parser.parse_args()

passes = [0]
for name in ("field", "add"):
    original = getattr(PairOperator, name)

    def counted(self, *a, _original=original, **k):
        passes[0] += 1
        return _original(self, *a, **k)

    setattr(PairOperator, name, counted)


def relax(atoms):
    return relax_spins(atoms, fmax=args.fmax, steps=10**6)


def minimise(Opt):
    def run(atoms):
        opt = Opt(atoms)
        assert opt.run(fmax=args.fmax, steps=10**6)
        return opt.nsteps
    return run


print(f"film {args.size}x{args.size}, fmax {args.fmax:g} eV")
print(f"{'method':<12} {'steps':>7} {'evaluations':>12} {'seconds':>8} {'energy (eV)':>18} "
      f"{'torque':>9}")
for name, run in (("relax_spins", relax), ("SpinLBFGS", minimise(SpinLBFGS)),
                  ("SpinVP", minimise(SpinVP))):
    run(film(args.size, args.seed))  # compile
    atoms = film(args.size, args.seed)
    passes[0] = 0
    t = time.perf_counter()
    steps = run(atoms)
    seconds = time.perf_counter() - t
    B = atoms.calc.get_magnetic_forces(atoms)
    tq = np.linalg.norm(np.cross(get_spins(atoms), B), axis=1).max()
    print(f"{name:<12} {steps:7d} {passes[0]:12d} {seconds:8.3f} "
          f"{atoms.get_potential_energy():18.10f} {tq:9.2e}")
