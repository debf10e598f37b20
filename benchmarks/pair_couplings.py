"""Cost of a step with pair-resolved couplings against Exchange on the same pairs.

fcc Co (the benchmark scene's lattice, LJ + Bethe–Slater exchange within 4 Å),
spins in a 30° cone: one CollectivePRK run with ``Exchange(BetheSlater)`` and one
with ``PairCouplings`` holding the same pairs, J_ij = J(r⁰) and ``shape`` the same
Bethe–Slater function (so both give the same forces and fields: checked at the
start), timed side by side in this process, medians of ``--repeats`` runs.

    python benchmarks/pair_couplings.py [--n 6] [--steps 50] [--repeats 3]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from ase import units
from ase.build import bulk

import ase_spin
from ase_spin import BetheSlater, CollectivePRK, Exchange, LennardJones, PairCouplings
from ase_spin.terms.pair_couplings import pairs_within

CO_LJ = dict(epsilon=0.4, sigma=2.2742, rc=4.7, cutoff="shift")
CO_BS = (0.0446928, 0.003496, 1.4885)


def scene(n, spin_term):
    atoms = bulk("Co", "fcc", a=3.54, cubic=True).repeat(n)
    rng = np.random.default_rng(1)
    phi = rng.uniform(0, 2 * np.pi, len(atoms))
    theta = np.arccos(rng.uniform(np.cos(np.radians(30)), 1.0, len(atoms)))
    s = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], 1)
    ase_spin.set_spins(atoms, s, 1.72)
    atoms.rattle(0.02, seed=3)
    atoms.calc = ase_spin.SpinLatticeCalculator([LennardJones(**CO_LJ), spin_term])
    return atoms


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=6, help="cubic cells per side (4 n³ atoms)")
    parser.add_argument("--steps", type=int, default=50)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    bs = BetheSlater(*CO_BS)
    ref = bulk("Co", "fcc", a=3.54)
    i, j, R, r = pairs_within(ref, 4.0)
    terms = {"Exchange": lambda: Exchange(bs, rc=4.0),
             "PairCouplings": lambda: PairCouplings(ref, i, j, R, bs(r), shape=bs, rc=4.0)}
    a, b = (scene(args.n, make()) for make in terms.values())
    dF = np.abs(a.get_forces() - b.get_forces()).max()
    dB = np.abs(a.calc.get_magnetic_forces(a) - b.calc.get_magnetic_forces(b)).max()
    print(f"{len(a)} atoms; same scene: max |ΔF| = {dF:.2e} eV/Å, max |ΔB| = {dB:.2e} eV")
    times = {name: [] for name in terms}
    for _ in range(args.repeats):
        for name, make in terms.items():
            atoms = scene(args.n, make())
            dyn = CollectivePRK(atoms, 0.1 * units.fs)
            dyn.run(2)  # compile, first lists
            t0 = time.perf_counter()
            dyn.run(args.steps)
            times[name].append((time.perf_counter() - t0) / args.steps)
    med = {name: float(np.median(t)) for name, t in times.items()}
    for name, t in med.items():
        print(f"{name:14s} {1e3 * t:8.2f} ms/step  ({1e6 * t / len(a):.2f} µs/atom-step)")
    print(f"ratio PairCouplings / Exchange: {med['PairCouplings'] / med['Exchange']:.2f}")


if __name__ == "__main__":
    main()
