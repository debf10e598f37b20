"""Magnons of bcc Fe: S(q, ω) of a spin-dynamics run with linear spin-wave theory over it.

    python examples/magnons.py [--size 6] [--steps 800] [--full] [--out PATH]

bcc Fe (a = 2.87 Å, moments 2.2 μB) with the Bethe–Slater exchange of LAMMPS's
examples/SPIN/iron (rc = 3.4 Å), a 2 T field and a small uniaxial anisotropy along z,
on a frozen lattice: the spins start in a 10° cone about +z (a low temperature) and
precess at constant energy (CollectivePRK, 0.5 fs). The spin Fourier components along
Γ–H–N–Γ–P–H|P–N (the q a size³ repeat of the primitive cell holds) are recorded every
2 steps; S(q, ω) comes from Hann-windowed blocks, and the spin-wave bands of the same
Hamiltonian are drawn over it. Prints, per q, the band and the run's peak, and writes
magnons.png (or --out NAME.png, or --out DIR for DIR/magnons.png).

The default (216 spins, 800 steps) takes seconds; --full (1000 spins, 8000 steps,
blocks of 1024 samples averaged) resolves 4 meV instead of 10 meV.
"""

import argparse
from pathlib import Path

import numpy as np
from ase import units
from ase.build import bulk

import ase_spin
from ase_spin import (BetheSlater, CollectivePRK, Exchange, SpinLatticeCalculator,
                      UniaxialAnisotropy, Zeeman)
from ase_spin.analysis import StructureFactorRecorder, magnon_bands, q_path
from ase_spin.scenes import cone

ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
ap.add_argument("--size", type=int, default=6, help="repeats of the primitive cell per axis")
ap.add_argument("--steps", type=int, default=800)
ap.add_argument("--block", type=int, default=None, help="samples per block (default: all)")
ap.add_argument("--full", action="store_true",
                help="the long run: --size 10 --steps 8000 --block 1024")
ap.add_argument("--out", "--plot", dest="out", default=".", type=Path,
                help="the picture: NAME.png, or a folder for magnons.png (default: here)")
args = ap.parse_args()
if args.full:
    args.size, args.steps, args.block = 10, 8000, 1024
plot = args.out if args.out.suffix.lower() == ".png" else args.out / "magnons.png"

MOMENT = 2.2
terms = [Exchange(BetheSlater(J1=0.02726, J2=0.2171, J3=1.841), rc=3.4),
         Zeeman(2.0, [0, 0, 1]), UniaxialAnisotropy(5e-4, [0, 0, 1])]

# the crystal's cell, in its ground state: the spin waves are computed on it
crystal = bulk("Fe", "bcc", a=2.87)
ase_spin.set_spins(crystal, [0, 0, 1], magnitudes=MOMENT)
crystal.calc = SpinLatticeCalculator(terms)

# the run: a repeat of it, spins in a small cone about the ground state
atoms = crystal.repeat(args.size)
ase_spin.set_spins(atoms, cone(len(atoms), np.random.default_rng(7), 10.0), magnitudes=MOMENT)
atoms.calc = SpinLatticeCalculator(terms)
path = q_path(crystal, supercell=atoms)          # the q this supercell holds

dyn = CollectivePRK(atoms, timestep=0.5 * units.fs, lattice="frozen")
recorder = StructureFactorRecorder(dyn, path)
dyn.attach(recorder, interval=2)
dyn.run(args.steps)
spectrum = recorder.spectrum(block=args.block)

bands = magnon_bands(crystal, path, dynamics=dyn)           # at the run's q
dense = magnon_bands(crystal, q_path(crystal, npoints=200), dynamics=dyn)

peaks = spectrum.peaks()
band = bands.energy_meV[:, 0]
print(f"{len(atoms)} spins, {args.steps} steps, {spectrum.blocks} block(s), "
      f"resolution {spectrum.resolution_meV:.1f} meV")
print("   x (1/Å)   band (meV)   peak (meV)")
for x, b, p in zip(path.x, band, peaks):
    print(f"{x:10.3f} {b:12.1f} {p:12.1f}")
resolved = band > 2 * spectrum.resolution_meV
print(f"largest |peak - band| where resolved: {np.abs(peaks - band)[resolved].max():.1f} meV")

ax = spectrum.plot(bands=dense)
ax.set_title(f"bcc Fe, {len(atoms)} spins, 10° cone, frozen lattice: S(q, E) and spin waves")
plot.parent.mkdir(parents=True, exist_ok=True)
ax.figure.savefig(plot, dpi=130)
print(f"wrote {plot}")
