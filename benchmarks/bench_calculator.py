"""µs per atom for one evaluation of the fcc Co scene of peers.md.

    python benchmarks/bench_calculator.py [--sizes 5 10 20 30 40] [--repeat 7] [--parts]

Columns (medians of --repeat timings, neighbour list already built):
  full       energy + forces + magnetic forces, Evaluator.evaluate (what an
             integrator or the calculator computes)
  calc       the same through atoms.get_potential_energy/get_forces/
             get_magnetic_forces of the ASE calculator (includes ASE's
             Atoms copy and state check)
  B only     magnetic forces alone from cached pair geometry
  geometry   J(r_ij), J'(r_ij) d/r for the exchange pairs
  nl build   one neighbour-list build at rc + skin (the compiled cell list)
ase's own LennardJones (LJ only, energy + forces) for small N, for scale.
With --parts, also where the calculator's time beyond one evaluation goes (µs
per call, not per atom): its comparison of the atoms with those of the last
calculation (check_state, at every property call), binding the evaluator and
splitting the moments (bound_evaluator, at every calculation), ASE's
Atoms.copy() (twice per calculation), and a property call answered from the
results.
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from ase.build import bulk

sys.path.insert(0, str(Path(__file__).parent))
from machine import describe  # noqa: E402

import ase_spin  # noqa: E402
from ase_spin import (BetheSlater, Exchange, LennardJones, SpinLatticeCalculator,  # noqa: E402
                      Want)


def scene(n, seed=0):
    """fcc Co, a = 3.54 Å, 4n³ atoms, spins in a 30° cone about +z, rattled."""
    rng = np.random.default_rng(seed)
    atoms = bulk("Co", "fcc", a=3.54, cubic=True).repeat(n)
    atoms.rattle(0.03, seed=seed)
    N = len(atoms)
    cz = rng.uniform(np.cos(np.radians(30)), 1.0, N)
    phi = rng.uniform(0, 2 * np.pi, N)
    sz = np.sqrt(1 - cz**2)
    ase_spin.set_spins(atoms, np.column_stack([sz * np.cos(phi), sz * np.sin(phi), cz]), 1.72)
    return atoms


def terms():
    return [LennardJones(0.4, 2.2742, 4.7, cutoff="shift"),
            Exchange(BetheSlater(0.0446928, 0.003496, 1.4885), rc=4.0)]


def median_time(fn, repeat):
    fn()
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", type=int, nargs="+", default=[5, 10, 20, 30, 40])
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--parts", action="store_true",
                    help="also time the calculator's parts beyond the evaluation")
    args = ap.parse_args()
    print(describe())
    print(f"# fcc Co, LJ rc 4.7 shift + Bethe-Slater exchange rc 4.0, skin "
          f"{SpinLatticeCalculator(terms()).hamiltonian.skin} Å; µs per atom")
    print(f"{'N':>8} {'full':>8} {'calc':>8} {'B only':>8} {'geometry':>9} {'nl build':>9}"
          f" {'ase LJ':>8}")
    for n in args.sizes:
        atoms = scene(n)
        N = len(atoms)
        calc = SpinLatticeCalculator(terms())
        atoms.calc = calc
        ev, moments = calc.bound_evaluator(atoms)
        spins = ase_spin.get_spins(atoms)
        pos = atoms.positions.copy()
        want = Want(energy=True, forces=True, magnetic_forces=True)
        full = median_time(lambda: ev.evaluate(pos, spins, want), args.repeat)

        def via_calc():
            atoms.calc.results.clear()
            atoms.calc.atoms = None
            atoms.get_potential_energy()
            atoms.get_forces()
            calc.get_magnetic_forces(atoms)
        via = median_time(via_calc, max(3, args.repeat // 2))
        geom = ev.spin_operators(pos)
        bonly = median_time(lambda: ev.spin(geom, spins, Want(magnetic_forces=True)),
                            args.repeat)
        gtime = median_time(lambda: ev.spin_operators(pos, out=geom), args.repeat)

        def build():
            ev.neighbors.invalidate()
            ev.refresh(pos)
        nl = median_time(build, max(3, args.repeat // 2))
        ase_t = float("nan")
        if N <= 500:
            from ase.calculators.lj import LennardJones as AseLJ

            a2 = atoms.copy()
            a2.calc = AseLJ(epsilon=0.4, sigma=2.2742, rc=4.7)

            def ase_eval():
                a2.calc.results.clear()
                a2.calc.atoms = None
                a2.get_forces()
            ase_t = median_time(ase_eval, 3)
        us = 1e6 / N
        print(f"{N:>8} {full * us:8.3f} {via * us:8.3f} {bonly * us:8.4f} {gtime * us:9.4f}"
              f" {nl * us:9.3f} {ase_t * us:8.1f}", flush=True)
        if args.parts:
            reps = max(20, args.repeat)
            atoms.get_potential_energy()
            parts = {
                "check_state": median_time(lambda: calc.check_state(atoms), reps),
                "bound_evaluator": median_time(lambda: calc.bound_evaluator(atoms), reps),
                "Atoms.copy": median_time(atoms.copy, reps),
                "cached get_forces": median_time(atoms.get_forces, reps),
                "evaluate": full,
                "three calls": via,
            }
            print(f"{'':>8} parts, µs per call: "
                  + ", ".join(f"{k} {v * 1e6:.1f}" for k, v in parts.items()), flush=True)
    import numba
    print(f"# numba threading layer used: {numba.threading_layer()}")


if __name__ == "__main__":
    main()
