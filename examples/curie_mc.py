"""Curie temperature of the classical Heisenberg ferromagnet by Monte Carlo.

Simple cubic lattice, nearest-neighbour exchange J = 10 meV (E = −J Σ_<ij>
s_i·s_j, each pair once: ase_spin's convention and Chen, Ferrenberg and
Landau's, whose T_C = 1.443 J/k_B = 167.4 K), sampled by ase_spin.MonteCarlo
(Metropolis in an adaptive cone plus over-relaxation) at temperatures around
T_C for several sizes L. At each (L, T): ⟨|m|⟩, the susceptibility and the
Binder cumulant U = 1 − ⟨m⁴⟩/(3⟨m²⟩²) with jackknife errors
(ase_spin.analysis.Fluctuations); T_C from where the U_L(T) cross
(ase_spin.analysis.binder_crossing).

    python examples/curie_mc.py            # L = 4, 6, 8, 1500 sweeps: ~1 min
    python examples/curie_mc.py --long     # L = 8, 12, 16, 20000 sweeps (the 1 % figure)

writes curie_mc.png (M(T) and U(T)) in the current folder, or --out NAME.png
or --out DIR (DIR/curie_mc.png; the docs' figure: --out docs/figures).
"""

import argparse
import time
from pathlib import Path

import numpy as np
from ase import units
from ase.build import bulk

import ase_spin
from ase_spin import MonteCarlo, ShellExchange, SpinLatticeCalculator
from ase_spin.analysis import Fluctuations, binder_crossing

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--long", action="store_true", help="larger sizes and longer runs")
parser.add_argument("--sweeps", type=int, default=None, help="sweeps measured per point")
parser.add_argument("--out", default="curie_mc.png", type=Path,
                    help="the picture: NAME.png, or a folder for curie_mc.png")
args = parser.parse_args()
out = args.out if args.out.suffix.lower() == ".png" else args.out / "curie_mc.png"

A, J = 2.5, 0.010                  # Å, eV
TC = J / (0.693035 * units.kB)     # Chen, Ferrenberg and Landau 1993 (K)
if args.long:
    sizes, fractions, sweeps, warmup = (8, 12, 16), np.linspace(0.97, 1.03, 5), 20000, 1000
else:
    sizes, fractions, sweeps, warmup = (4, 6, 8), np.array([0.9, 0.95, 1.0, 1.05, 1.1]), 1500, 200
sweeps = args.sweeps or sweeps
temperatures = TC * fractions

results = {}
for L in sizes:
    rows = []
    for k, T in enumerate(temperatures):
        atoms = bulk("Fe", "sc", a=A).repeat(L)
        ase_spin.set_spins(atoms, [0, 0, 1], magnitudes=2.0)
        atoms.calc = SpinLatticeCalculator([ShellExchange([(A, J)])])
        mc = MonteCarlo(atoms, temperature_K=T, seed=100 * L + k, overrelaxation=2,
                        adapt_sweeps=warmup)
        start = time.perf_counter()
        mc.run(warmup)
        obs = Fluctuations(mc)
        mc.attach(obs, interval=1)
        mc.run(sweeps)
        elapsed = time.perf_counter() - start
        m, chi, u = (obs.magnetisation(discard=1), obs.susceptibility(discard=1),
                     obs.binder_cumulant(discard=1))
        rows.append((m, chi, u))
        print(f"L = {L:2d}  T = {T:6.1f} K  |M| = {m:.4f}  J·χ = {J * chi.value:8.3f} "
              f"± {J * chi.error:.2g}  U = {u:.4f}  ({(warmup + sweeps) / elapsed:.0f} sweeps/s)",
              flush=True)
    results[L] = rows

U = {L: [r[2].value for r in rows] for L, rows in results.items()}
dU = {L: [r[2].error for r in rows] for L, rows in results.items()}
tc, pairs = binder_crossing(temperatures, U, dU)
print(f"T_C from the Binder crossings: {tc:.1f} K = {tc.value / TC:.4f} ± {tc.error / TC:.4f} "
      f"of 1.443 J/k_B ({TC:.1f} K); pairs: {', '.join(f'{p:.1f}' for p in pairs)} K")

try:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
except ImportError:
    print("matplotlib not installed: no picture")
else:
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(9, 3.8), constrained_layout=True)
    for L, rows in results.items():
        for ax, k in ((ax1, 0), (ax2, 2)):
            v = np.array([r[k].value for r in rows])
            e = np.array([r[k].error for r in rows])
            ax.errorbar(temperatures, v, e, marker="o", ms=4, capsize=2, label=f"L = {L}")
    for ax in (ax1, ax2):
        ax.axvline(TC, color="0.6", ls=":", label="1.443 J/k_B")
        ax.set_xlabel("T (K)")
    ax2.axvline(tc.value, color="k", ls="--", lw=0.8, label=f"crossing {tc.value:.1f} K")
    ax1.set_ylabel("⟨|m|⟩")
    ax2.set_ylabel("Binder cumulant U")
    ax1.legend()
    ax2.legend(fontsize=8)
    fig.suptitle("Heisenberg ferromagnet, simple cubic: Monte Carlo")
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")
