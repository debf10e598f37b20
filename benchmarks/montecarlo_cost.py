"""Monte Carlo sweeps against Langevin steps, side by side, per atom: the
simple-cubic Heisenberg magnet (J = 10 meV, nearest neighbours) at 0.6 T_C,
MonteCarlo (Metropolis, and with 2 over-relaxation sweeps) and Langevin
(frozen lattice, 2 fs, λ = 0.5), for a few sizes.

    python benchmarks/montecarlo_cost.py [--sizes 4 8 16] [--seconds 3]
"""

import argparse
import time

from ase import units
from ase.build import bulk

import ase_spin
from ase_spin import Langevin, MonteCarlo, ShellExchange, SpinLatticeCalculator

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--sizes", type=int, nargs="+", default=[4, 8, 16])
parser.add_argument("--seconds", type=float, default=3.0, help="time per measurement")
args = parser.parse_args()
T = 0.6 * 0.010 / (0.693035 * units.kB)


def scene(L):
    atoms = bulk("Fe", "sc", a=2.5).repeat(L)
    ase_spin.set_spins(atoms, [0, 0, 1], magnitudes=2.0)
    atoms.calc = SpinLatticeCalculator([ShellExchange([(2.5, 0.010)])])
    return atoms


def rate(run, chunk):
    run(chunk)  # warm-up (compilation, caches)
    n, start = 0, time.perf_counter()
    while time.perf_counter() - start < args.seconds:
        run(chunk)
        n += chunk
    return n / (time.perf_counter() - start)


print(f"{'atoms':>6} {'MC sweeps/s':>12} {'MC+2 OR /s':>11} {'Langevin steps/s':>17}   "
      "ns per atom: MC, MC+2 OR, Langevin")
for L in args.sizes:
    atoms = scene(L)
    n = len(atoms)
    chunk = max(1, 20000 // n)
    mc = rate(MonteCarlo(atoms, temperature_K=T, seed=1).run, chunk)
    mcor = rate(MonteCarlo(scene(L), temperature_K=T, seed=1, overrelaxation=2).run, chunk)
    dyn = Langevin(scene(L), 2.0 * units.fs, temperature_K=T, spin_damping=0.5, friction=0.0,
                   lattice="frozen", rng=1)
    ld = rate(dyn.run, chunk)
    print(f"{n:6d} {mc:12.1f} {mcor:11.1f} {ld:17.1f}   "
          f"{1e9 / (mc * n):.0f}, {1e9 / (mcor * n):.0f}, {1e9 / (ld * n):.0f}", flush=True)
