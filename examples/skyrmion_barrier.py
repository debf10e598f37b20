"""The collapse barrier of an isolated skyrmion: relax it, then GNEB to the ferromagnet.

A square monolayer (ase_spin.scenes.dmi_film: nearest-neighbour exchange
J = 10 meV, interfacial DMI D = 3 meV, anisotropy K = 1 meV and a field of
2 T along z) holds an isolated Néel skyrmion as a metastable state above the
ferromagnetic ground state. The script

1. relaxes a skyrmion profile to the skyrmion (SpinLBFGS: LBFGS with
   orthogonal spin optimisation) and prints its energy above the ferromagnet
   and its topological charge Q;
2. spans a band of images from the skyrmion to the ferromagnet along
   geodesics and relaxes it with the geodesic nudged elastic band (GNEB),
   the highest image climbing to the saddle point: the collapse, Q jumping
   from −1 to 0 at the saddle;
3. prints the barrier (the highest point of the cubic Hermite interpolation
   of the images' energies) and draws the energy along the path with the
   interpolation, and the saddle-point texture.

With ``--lattice`` the same on a film whose atoms may move: a triangular
monolayer held by a Lennard-Jones potential (ε = 0.1 eV, its minimum at
a = 2.5 Å, the atoms kept in the plane by FixCartesian) whose exchange
depends on the distance (Bethe–Slater, J(a) = 10 meV, dJ/dr ≠ 0 at a:
magnetostriction). The band is relaxed twice: on the frozen lattice of the
ferromagnet, and with the positions free along the path (``GNEB(...,
lattice=True)``, its ends relaxed with ``LBFGS(SpinLatticeFilter(atoms))``);
the script prints both barriers and how far the atoms move at the saddle.

    python examples/skyrmion_barrier.py [--size 16] [--images 9] [--fmax 1e-5]
                                        [--lattice] [--full] [--out skyrmion_barrier.png]

The default is a short run (a 16 × 16 film, 9 images, converged to a
largest GNEB force of 1e-5 eV: seconds), whose skyrmion still feels its
periodic images; ``--full`` takes a 28 × 28 film, 15 images and 1e-7 eV: the
barrier of an isolated skyrmion (``--lattice --full``: 20 × 20, 1e-6 eV).
Writes skyrmion_barrier.png in the current folder (--out NAME.png, or --out
DIR for DIR/skyrmion_barrier.png).
"""

import argparse
import time
from pathlib import Path

import numpy as np
from ase import Atoms
from ase.constraints import FixCartesian
from ase.optimize import LBFGS

import ase_spin
from ase_spin import (DMI, BetheSlater, Exchange, LennardJones, SpinLatticeCalculator,
                      SpinLatticeFilter, UniaxialAnisotropy, Zeeman)
from ase_spin.optimize import GNEB, SpinLBFGS
from ase_spin.optimize.gneb import LATTICE_STIFFNESS
from ase_spin.analysis import LayerTriangulation
from ase_spin.scenes import dmi_film, neel_skyrmion

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--size", type=int, default=16, help="lattice sites along each side")
parser.add_argument("--images", type=int, default=9, help="images of the band, ends included")
parser.add_argument("--fmax", type=float, default=1e-5,
                    help="largest GNEB force (torque, eV) at convergence")
parser.add_argument("--lattice", action="store_true",
                    help="a triangular film whose atoms move: the barrier with the lattice "
                         "frozen and free")
parser.add_argument("--full", action="store_true",
                    help="the full run: --size 28 --images 15 --fmax 1e-7 "
                         "(with --lattice: --size 20 --fmax 1e-6)")
parser.add_argument("--out", default="skyrmion_barrier.png", type=Path,
                    help="the picture (needs matplotlib): NAME.png, or a folder for "
                         "skyrmion_barrier.png (default: skyrmion_barrier.png here)")
args = parser.parse_args()
if args.full:
    args.size, args.images, args.fmax = (20, 15, 1e-6) if args.lattice else (28, 15, 1e-7)
out = args.out if args.out.suffix.lower() == ".png" else args.out / "skyrmion_barrier.png"
n = args.size
a = 2.5  # Å


def triangular_film(n):
    """The --lattice scene: n × n sites of a triangular monolayer (site (i, j)
    at i a₁ + j a₂), spins up; J(r) = 4 J1 (r/J3)² e^{−(r/J3)²} with J3 = 0.8 a
    and J(a) = 10 meV, so that dJ/dr = J(a)(2/a − 2a/J3²) ≠ 0 at a."""
    ij = np.array([(i, j) for j in range(n) for i in range(n)], dtype=float)
    a1, a2 = np.array([a, 0.0, 0.0]), np.array([a / 2, a * np.sqrt(3) / 2, 0.0])
    atoms = Atoms(f"Fe{n * n}", positions=ij[:, :1] * a1 + ij[:, 1:] * a2,
                  cell=[n * a1, n * a2, [0.0, 0.0, 10.0]], pbc=True)
    ase_spin.set_spins(atoms, np.tile([0.0, 0.0, 1.0], (n * n, 1)), magnitudes=2.2)
    J3, rc = 0.8 * a, 1.2 * a
    J1 = 0.010 / (4 * (a / J3) ** 2 * np.exp(-((a / J3) ** 2)))
    atoms.calc = SpinLatticeCalculator([
        LennardJones(epsilon=0.1, sigma=a / 2 ** (1 / 6), rc=3.5, cutoff="shift"),
        Exchange(BetheSlater(J1, 0.0, J3), rc=rc), DMI(0.003, [0, 0, 1], rc=rc),
        UniaxialAnisotropy(0.001, [0, 0, 1]), Zeeman(2.0, [0, 0, 1])])
    atoms.set_constraint(FixCartesian(range(n * n), mask=[False, False, True]))
    return atoms


def run_band(first, last, **kwargs):
    band = GNEB([first] + [first.copy() for _ in range(args.images - 2)] + [last], climb=True,
                **kwargs)
    band.interpolate()
    t0 = time.perf_counter()
    converged = band.run(fmax=args.fmax, steps=20000)
    print(f"GNEB{' (lattice free)' if band.lattice else ''} "
          f"{'converged' if converged else 'NOT converged'} in {band.nsteps} steps "
          f"({band.evaluations} evaluations, {time.perf_counter() - t0:.1f} s): largest force "
          f"{band.fmax():.2e}")
    return band


# 1. the two states: the relaxed skyrmion and the ferromagnet
make = triangular_film if args.lattice else dmi_film
ferromagnet = make(n)  # all spins along the field: the ground state
if args.lattice:  # its lattice constant follows from LJ and the exchange
    if not LBFGS(SpinLatticeFilter(ferromagnet), logfile=None).run(fmax=1e-7, steps=2000):
        raise SystemExit("the ferromagnet's lattice did not relax")
skyrmion = make(n)
skyrmion.set_positions(ferromagnet.positions)
centre = skyrmion.positions[n // 2 + n * (n // 2), :2] + 0.01  # on a site
ase_spin.set_spins(skyrmion, neel_skyrmion(skyrmion.positions, radius=2.5 * a, centre=centre),
                   magnitudes=2.2)
opt = SpinLBFGS(skyrmion)
assert opt.run(fmax=1e-10, steps=5000), "the skyrmion did not relax"
E_sk, E_fm = skyrmion.get_potential_energy(), ferromagnet.get_potential_energy()
layer = LayerTriangulation(skyrmion)
Q = layer.charge(ase_spin.get_spins(skyrmion))
print(f"skyrmion relaxed in {opt.evaluations} evaluations: {1e3 * (E_sk - E_fm):.3f} meV above "
      f"the ferromagnet, Q = {Q:+.4f}")
if abs(Q + 1) > 1e-3:
    raise SystemExit("the skyrmion collapsed while relaxing: take a larger --size")

# 2. the band from the skyrmion to the ferromagnet (on the ferromagnet's lattice)
band = run_band(skyrmion, ferromagnet)
frozen = band
if args.lattice:
    free_skyrmion = skyrmion.copy()
    free_skyrmion.calc = make(n).calc
    if not LBFGS(SpinLatticeFilter(free_skyrmion), logfile=None).run(fmax=1e-7, steps=5000):
        raise SystemExit("the skyrmion with its lattice did not relax")
    # ℓ (Å per rad) weighs a turn against a displacement: chosen so that the
    # stiffest spin (max|B|/ℓ²) and the lattice (LATTICE_STIFFNESS) take
    # steps of one size in the band's velocity projection
    B = free_skyrmion.calc.get_magnetic_forces(free_skyrmion)
    ell = float(np.sqrt(np.linalg.norm(B, axis=1).max() / LATTICE_STIFFNESS))
    band = run_band(free_skyrmion, ferromagnet, lattice=True, spin_length=ell)

# 3. the barrier and the path
ci = band.climbing_image
E0 = band.energies[0]
charges = [layer.charge(s) for s in band.S]
if args.lattice:
    moved = np.linalg.norm(band.Q[ci] - ferromagnet.positions, axis=1).max()
    print(f"collapse barrier: lattice frozen {1e3 * frozen.barrier():.4f} meV, lattice free "
          f"{1e3 * band.barrier():.4f} meV (the skyrmion's own relaxation "
          f"{1e3 * (free_skyrmion.get_potential_energy() - E_sk):+.4f} meV); at the saddle the "
          f"atoms move up to {moved:.2e} Å")
print(f"collapse barrier {1e3 * band.barrier():.3f} meV (climbing image {ci}: "
      f"{1e3 * (band.energies[ci] - E0):.3f} meV), back from the ferromagnet "
      f"{1e3 * band.barrier(reverse=True):.3f} meV")
print("image  R          E − E_sk (meV)     Q")
for k, (r, e, q) in enumerate(zip(band.reaction_coordinate(), band.energies, charges)):
    print(f"{k:5d} {r:8.3f} {1e3 * (e - E0):16.4f} {q:+9.4f}" + ("  climbing" if k == ci else ""))

try:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
except ImportError:
    print("matplotlib not installed: no picture")
else:
    fig, axes = plt.subplots(1, 3, figsize=(13, 4.2), constrained_layout=True,
                             gridspec_kw={"width_ratios": [1.3, 1, 1]})
    ax = axes[0]
    bands = [(frozen, "lattice frozen", "C1")] if args.lattice else []
    bands.append((band, "lattice free" if args.lattice else "", "C0"))
    for b, label, colour in bands:
        L = b.reaction_coordinate()[-1]  # R / L: the metrics of the two bands differ
        R, E = b.path()
        e0 = b.energies[0]
        ax.plot(R / L, 1e3 * (E - e0), "-", color=colour,
                label=f"{label}{', ' if label else ''}cubic Hermite interpolation")
        ax.plot(b.reaction_coordinate() / L, 1e3 * (b.energies - e0), "o", color=colour,
                label=f"images{' (' + label + ')' if label else ''}")
        k = b.climbing_image
        ax.plot([b.reaction_coordinate()[k] / L], [1e3 * (b.energies[k] - e0)], "*",
                color="C3", ms=14)
    ax.plot([], [], "*", color="C3", ms=14, label="climbing image (saddle)")
    ax.set_xlabel("reaction coordinate (fraction of the path length)")
    ax.set_ylabel("E − E(skyrmion) (meV)")
    ax.set_title(f"skyrmion collapse: barrier {1e3 * band.barrier():.2f} meV")
    ax.legend(loc="lower left", fontsize=8)
    for ax, k, title in ((axes[1], 0, "skyrmion (minimum)"),
                         (axes[2], ci, "saddle point (climbing image)")):
        x, y = band.Q[k][:, 0], band.Q[k][:, 1]
        spins = band.S[k]
        im = ax.scatter(x, y, c=spins[:, 2], cmap="RdBu_r", vmin=-1, vmax=1, s=240 / n * 12,
                        marker="h" if args.lattice else "s")
        ax.quiver(x, y, spins[:, 0], spins[:, 1], pivot="middle", scale=n * 1.4, width=0.005)
        ax.set_aspect("equal")
        ax.set_title(title)
        ax.set_xlabel("x (Å)")
    axes[1].set_ylabel("y (Å)")
    fig.colorbar(im, ax=axes[1:], label="$s_z$", shrink=0.8)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")
