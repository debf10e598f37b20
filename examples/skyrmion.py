"""A Néel skyrmion in a magnetic monolayer: exchange + interfacial DMI + a field.

A square monolayer, periodic in-plane (pbc = True, True, False), with
nearest-neighbour ferromagnetic exchange, DMI whose vector D lies along the
film normal (D_ij = e_ij × D ẑ: the interfacial form of LAMMPS pair
spin/dmi) and a Zeeman field along +z. A skyrmion profile is placed in the
ferromagnetic background with both possible chiralities: DMI lowers the energy
of one and raises that of the other (printed). The favoured one is then
integrated with CollectivePRK on a frozen lattice: without damping the texture
keeps its energy and precesses about the field while spin lengths stay at
round-off. With ``--relax`` it is first relaxed to the nearest energy
minimum by damped precession (ase_spin.relax_spins): the skyrmion's own size.

    python examples/skyrmion.py [--steps 2000] [--relax] [--out skyrmion.png]

writes skyrmion.png in the current folder (--out NAME.png, or --out DIR for
DIR/skyrmion.png; the docs' figure: --out docs/figures/skyrmion.png).
"""

import argparse
from pathlib import Path

import numpy as np
from ase import Atoms, units

import ase_spin
from ase_spin import DMI, CollectivePRK, Cubic, Exchange, SpinLatticeCalculator, Zeeman
from ase_spin.analysis import LayerTriangulation

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--size", type=int, default=30, help="lattice sites along each side")
parser.add_argument("--steps", type=int, default=2000, help="steps of 1 fs")
parser.add_argument("--out", default="skyrmion.png", type=Path,
                    help="the picture (needs matplotlib): NAME.png, or a folder for "
                         "skyrmion.png (default: skyrmion.png here)")
parser.add_argument("--relax", action="store_true",
                    help="relax the texture first (zero-temperature damped precession)")
args = parser.parse_args()
out = args.out if args.out.suffix.lower() == ".png" else args.out / "skyrmion.png"

a = 2.5  # Å
n = args.size
ij = np.array([(i, j) for j in range(n) for i in range(n)], dtype=float)
atoms = Atoms(f"Fe{n * n}", positions=np.column_stack([ij * a, np.zeros(n * n)]),
              cell=[n * a, n * a, 10.0], pbc=[True, True, False])

# J_nn = J0 (1 − a/rc)³ = 10 meV with rc = 3 Å (nearest neighbours only), D = 3 meV, 2 T
J0 = 0.010 / (1.0 - a / 3.0) ** 3
terms = [Exchange(Cubic(J0, 3.0)), DMI(0.003, [0, 0, 1], rc=3.0), Zeeman(2.0, [0, 0, 1])]


def skyrmion(chirality, radius=4.0 * a):
    """Néel profile θ(ρ) = 2 atan(R/ρ) about the cell centre: s_z = −1 at the core,
    +1 far away (along the field), in-plane part radial (±)."""
    centre = np.array([n * a / 2, n * a / 2])
    d = atoms.positions[:, :2] - centre
    rho = np.linalg.norm(d, axis=1)
    theta = 2.0 * np.arctan2(radius, rho)  # π at the core, → 0 far away
    radial = d / np.where(rho > 0, rho, 1.0)[:, None]
    return np.column_stack([chirality * np.sin(theta)[:, None] * radial, np.cos(theta)])


triangulation = LayerTriangulation(atoms)  # Berg–Lüscher: Q = Σ Ω/(4π) over triangles


def topological_charge(spins):
    """Q of the layer: ±1 for one skyrmion (ase_spin.analysis.topology)."""
    return triangulation.charge(spins)


energies = {}
for chirality in (+1, -1):
    ase_spin.set_spins(atoms, skyrmion(chirality), magnitudes=2.2)
    atoms.calc = SpinLatticeCalculator(terms)
    energies[chirality] = (atoms.get_potential_energy(),
                           atoms.calc.results["energy_terms"]["dmi"])
    print(f"chirality {chirality:+d}: energy {energies[chirality][0]:.4f} eV, "
          f"DMI part {energies[chirality][1]:+.4f} eV")
best = min(energies, key=lambda c: energies[c][0])
print(f"DMI favours chirality {best:+d}")
ase_spin.set_spins(atoms, skyrmion(best), magnitudes=2.2)
atoms.calc = SpinLatticeCalculator(terms)
start = ase_spin.get_spins(atoms).copy()

if args.relax:
    e_before = atoms.get_potential_energy()
    steps = ase_spin.relax_spins(atoms, fmax=1e-5)
    print(f"relaxed in {steps} damped steps: energy {e_before:.4f} -> "
          f"{atoms.get_potential_energy():.4f} eV, topological charge "
          f"{topological_charge(ase_spin.get_spins(atoms)):+.4f}")
    start = ase_spin.get_spins(atoms).copy()

dyn = CollectivePRK(atoms, 1.0 * units.fs, lattice="frozen", logfile="-",
                    loginterval=max(1, args.steps // 10))
e0 = dyn.get_total_energy()
dyn.run(args.steps)
s = ase_spin.get_spins(atoms)
print(f"after {args.steps} steps: energy change {dyn.get_total_energy() - e0:+.2e} eV, "
      f"max | |s| − 1 | = {np.abs(np.linalg.norm(s, axis=1) - 1).max():.1e}, "
      f"core s_z = {s[:, 2].min():+.3f}, topological charge {topological_charge(s):+.4f} "
      f"(start {topological_charge(start):+.4f}), {np.sum(s[:, 2] < 0)} sites with s_z < 0 "
      f"(start {np.sum(start[:, 2] < 0)})")

try:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
except ImportError:
    print("matplotlib not installed: no picture")
else:
    fig, axes = plt.subplots(1, 2, figsize=(9, 4.4), constrained_layout=True)
    x, y = atoms.positions[:, 0], atoms.positions[:, 1]
    for ax, spins, title in ((axes[0], start, "start"),
                             (axes[1], s, f"after {args.steps * 1e-3:g} ps")):
        im = ax.scatter(x, y, c=spins[:, 2], cmap="RdBu_r", vmin=-1, vmax=1, s=22,
                        marker="s")
        ax.quiver(x, y, spins[:, 0], spins[:, 1], pivot="middle", scale=40, width=0.003)
        ax.set_aspect("equal")
        ax.set_title(f"Néel skyrmion, {title}")
        ax.set_xlabel("x (Å)")
    axes[0].set_ylabel("y (Å)")
    fig.colorbar(im, ax=axes, label="$s_z$", shrink=0.8)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")
