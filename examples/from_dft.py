"""From DFT couplings to a run: a pair file on a reference cell, dynamics on a supercell.

    python examples/from_dft.py [--cells 4] [--steps 200] [--out DIR]

Writes ``pairs.txt`` in the text pair format (one pair a line: i j R1 R2 R3 J Dx Dy
Dz and Γ's nine entries, meV; docs/setup.md, "From DFT to a run") as a DFT code or a
fit would give it, for an fcc Co-like cell: isotropic J on the first two shells,
a DM vector along each nearest-neighbour bond (B20-type, bulk) and a small
anisotropic tensor Γ that differs between bonds of one shell (which a J(r) per
distance cannot hold). Reads it back with ``ase_spin.read_pairs`` onto the
primitive cell, builds a cells³ supercell, and runs CollectivePRK (0.5 fs,
moving lattice with Lennard-Jones; each pair's coupling decays as
e^{−(r − r⁰)/0.5 Å}), printing energy, temperature and |M| and the energy
drift. ``--out DIR`` writes pairs.txt there instead of the current folder.
"""

import argparse
import time
from pathlib import Path

import numpy as np
from ase import units
from ase.build import bulk

import ase_spin
from ase_spin import CollectivePRK, LennardJones, SpinLatticeCalculator, read_pairs
from ase_spin.terms.pair_couplings import pairs_within

ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
ap.add_argument("--cells", type=int, default=4, help="supercell size (cells³ atoms)")
ap.add_argument("--steps", type=int, default=200, help="steps of 0.5 fs")
ap.add_argument("--out", default=".", help="folder for pairs.txt (default: here)")
args = ap.parse_args()

reference = bulk("Co", "fcc", a=3.54)          # the cell the pairs refer to (one site)
i, j, R, r = pairs_within(reference, 3.6)      # 6 + 3 pairs: both shells, each pair once
e = (R @ reference.cell.array) / r[:, None]    # bond directions (one site: d = R·cell)
first = r < 3.0
rng = np.random.default_rng(0)
J = np.where(first, 12.0, 1.5)                                 # meV
D = np.where(first[:, None], 1.2 * e, 0.0)                     # meV, along the bond
G = rng.normal(scale=0.3, size=(len(i), 3, 3))
G = 0.5 * (G + np.swapaxes(G, 1, 2))
G -= np.trace(G, axis1=1, axis2=2)[:, None, None] / 3.0 * np.eye(3)
out = Path(args.out)
out.mkdir(parents=True, exist_ok=True)
path = out / "pairs.txt"
with open(path, "w") as f:
    f.write("# i j R1 R2 R3 J Dx Dy Dz Gxx Gxy Gxz Gyx Gyy Gyz Gzx Gzy Gzz (meV), "
            "E = -sum_{i<j} s_i^T (J + G + [D]) s_j\n")
    for k in range(len(i)):
        f.write(f"{i[k]} {j[k]} {R[k, 0]} {R[k, 1]} {R[k, 2]} {J[k]:.4f} "
                + " ".join(f"{x:.4f}" for x in D[k]) + " "
                + " ".join(f"{x:.4f}" for x in G[k].ravel()) + "\n")
print(f"wrote {path} ({len(i)} pairs)")

couplings = read_pairs(path, reference, unit="meV", decay=0.5)
atoms = reference.repeat(args.cells)
ase_spin.set_spins(atoms, [0.0, 0.0, 1.0], magnitudes=1.72)
ase_spin.set_spins(atoms, ase_spin.get_spins(atoms)
                   + 0.2 * np.random.default_rng(1).normal(size=(len(atoms), 3)), 1.72)
kT = 100 * units.kB                                     # velocities at 100 K
atoms.set_momenta(np.random.default_rng(2).normal(size=(len(atoms), 3))
                  * np.sqrt(atoms.get_masses() * kT)[:, None])
atoms.calc = SpinLatticeCalculator([LennardJones(0.4, 2.2742, 4.7, cutoff="shift"),
                                    couplings])
print(f"{len(atoms)} atoms, {couplings!r}")
e0 = atoms.get_potential_energy() + atoms.get_kinetic_energy()
dyn = CollectivePRK(atoms, 0.5 * units.fs, logfile="-", loginterval=max(1, args.steps // 5))
t0 = time.perf_counter()
dyn.run(args.steps)
e1 = atoms.get_potential_energy() + atoms.get_kinetic_energy()
m = np.linalg.norm(ase_spin.get_spins(atoms).mean(axis=0))
print(f"{args.steps} steps in {time.perf_counter() - t0:.1f} s; |M| = {m:.4f}; "
      f"energy drift {e1 - e0:+.2e} eV")
