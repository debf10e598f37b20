"""A thin bcc Fe(001) film turns its magnetisation into the plane: dipolar shape anisotropy.

The film: ``--layers`` (001) planes of bcc Fe (a = 2.87 Å, 2.2 μB per atom),
periodic in the plane and open along the normal z (pbc = True, True, False),
with Bethe–Slater exchange (the Fe of examples/metals.py), the magnetic
dipole–dipole interaction of the point moments (``Dipolar``, the Ewald sum of
a slab with the Yeh–Berkowitz correction, docs/terms.md "Dipolar") and a
perpendicular uniaxial anisotropy −K_u Σ s_z² (an interface's, say: K_u per
atom, ``--ku``, one run per value). The lattice is frozen.

1. The statics, the example's check of its physics: for uniform states the
   dipolar energy of the film is E(θ) = E∥ + (E⊥ − E∥) cos²θ, and E⊥ − E∥
   per atom is the shape anisotropy. The continuum's is μ0Ms²/2 times the
   volume of an atom (Ms = μ μB/V_atom); the lattice's differs at the
   surfaces. Printed against the number of planes n: the monolayer against
   the exact square-lattice sum 3ζ(3/2)β(3/2) μ0μB²μ²/4πa³, each added plane
   against the continuum μ0Ms²/2·V_atom, and the surfaces' share δ per
   column, E⊥ − E∥ = μ0Ms²/2·V_atom·n + δ μ0μB²μ²/4πa³ (per column of n
   atoms, one per plane).
2. The dynamics: from a uniform state tilted by ``--tilt`` from the normal,
   damped precession (``Langevin`` at T = 0, spin damping λ = 1: the fastest
   relaxation). A film whose K_u is below its shape anisotropy falls into the
   plane; above it, it returns to the normal. The energy each run releases is
   checked against the statics: (E⊥ − E∥ − K_u)·cos²θ0 per atom into the
   plane, (K_u − E⊥ + E∥)·sin²θ0 back to the normal.

The dipolar method: ``"ewald"`` (the default) for such small cells — exact
to its accuracy, and its cost O(N·K), K ∝ the cell's volume, is the smaller
one up to ~10³ atoms; ``--method pme`` (particle-mesh Ewald, the same sum with
its reciprocal part on a mesh, O(N log N)) for films of thousands of atoms
(a domain pattern, say): docs/terms.md, "Which method". The integrator must
be one of the collective ones (Langevin, CollectivePRK): SuzukiTrotter's
spin-by-spin sweeps refuse both long-range methods.

A uniform start stays uniform in each plane (every site of a plane sees the
same field), so the in-plane cell's size does not change the motion: the
default is the smallest cell, one atom per plane (``--size L`` takes L × L
atoms per plane and gives the same curves to round-off, at a higher cost).

    python examples/dipolar_film.py [--layers 3] [--ku 0 0.2] [--time 35]
                                    [--method ewald] [--out dipolar_film.png]

The default run takes about half a minute. Writes dipolar_film.png in the
current folder (--out NAME.png, or --out DIR for DIR/dipolar_film.png; the
docs' figure: --out docs/figures/dipolar_film).
"""

import argparse
import math
import time
from pathlib import Path

import numpy as np
from ase import units
from ase.build import bcc100
from scipy.special import zeta

from ase_spin import (DIPOLAR_CODATA, BetheSlater, Dipolar, Exchange, Langevin,
                      SpinLatticeCalculator, UniaxialAnisotropy, get_spins, set_spins)
from ase_spin.constants import MU_B

A = 2.87        # Å, the bcc lattice constant
MOMENT = 2.2    # μB per atom
VACUUM = 5.0    # Å of vacuum on each side of the film in the cell
SLAB = 3.0      # the Ewald sum's cell height / the cell's (LAMMPS kspace_modify slab)
RC = 6.0        # Å, the Ewald sum's real-space cutoff
SETTLED = 2.0   # degrees: a run ends in-plane (perpendicular) within this of the plane (normal)

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--layers", type=int, default=3, help="(001) planes of the film")
parser.add_argument("--size", type=int, default=1,
                    help="atoms along each in-plane side of the cell (the motion of a "
                         "uniform start does not depend on it)")
parser.add_argument("--ku", type=float, nargs="+", default=[0.0, 0.2],
                    help="perpendicular anisotropy K_u per atom (meV), one run each")
parser.add_argument("--tilt", type=float, default=15.0,
                    help="the start's angle from the film normal (degrees)")
parser.add_argument("--time", type=float, default=35.0, help="length of each run (ps)")
parser.add_argument("--timestep", type=float, default=2.0, help="timestep (fs)")
parser.add_argument("--method", choices=["ewald", "pme"], default="ewald",
                    help="the dipolar sum of the runs (the statics use ewald)")
parser.add_argument("--accuracy", type=float, default=1e-5,
                    help="the dipolar sum's relative accuracy in the runs")
parser.add_argument("--out", default="dipolar_film.png", type=Path,
                    help="the picture (needs matplotlib): NAME.png, or a folder for "
                         "dipolar_film.png (default: dipolar_film.png here)")
args = parser.parse_args()
if args.layers < 1 or args.size < 1:
    parser.error("--layers and --size must be at least 1")
if not 0.0 < args.tilt < 90.0:
    parser.error("--tilt must lie between 0 and 90 degrees")
out = args.out if args.out.suffix.lower() == ".png" else args.out / "dipolar_film.png"
started = time.perf_counter()


def film(layers, size=1):
    """``layers`` bcc (001) planes, ``size`` × ``size`` atoms each, pbc (T, T, F)."""
    return bcc100("Fe", size=(size, size, layers), a=A, vacuum=VACUUM)


def direction(theta):
    """The unit vector θ from the normal z, in the xz plane."""
    return [math.sin(theta), 0.0, math.cos(theta)]


def shape_anisotropy(layers):
    """E⊥ − E∥ per atom (eV) of a uniform film: the dipolar energy alone, Ewald
    sum to 1e-10 (the reference: the statics are cheap)."""
    atoms = film(layers)
    atoms.calc = SpinLatticeCalculator([Dipolar(RC, "ewald", accuracy=1e-10, slab=SLAB)])
    energy = []
    for theta in (0.0, math.pi / 2):
        set_spins(atoms, direction(theta), MOMENT)
        energy.append(atoms.get_potential_energy())
    return (energy[0] - energy[1]) / len(atoms)


# --- 1. statics: the lattice's shape anisotropy against the continuum's
v_atom = A**3 / 2.0                                    # Å³, two atoms per cubic cell
unit = DIPOLAR_CODATA * MOMENT**2 / A**3               # μ0μB²μ²/4πa³ (eV)
continuum = 2.0 * math.pi * DIPOLAR_CODATA * MOMENT**2 / v_atom   # μ0Ms²/2·V_atom (eV)
ms = MOMENT * MU_B * units._e / (v_atom * 1e-30)       # A/m (MU_B in eV/T)
print(f"bcc Fe, a = {A} Å, {MOMENT} μB per atom: Ms = {ms / 1e6:.3f} MA/m, "
      f"μ0Ms²/2 = {units._mu0 * ms**2 / 2 / 1e6:.3f} MJ/m³ = {continuum * 1e3:.4f} meV "
      "per atom (the continuum's shape anisotropy)")
planes = np.arange(1, max(6, args.layers) + 1)
k_film = np.array([shape_anisotropy(n) for n in planes])       # eV per atom
per_column = k_film * planes
beta = (zeta(1.5, 0.25) - zeta(1.5, 0.75)) / 4**1.5            # Dirichlet β(3/2)
monolayer = 3.0 * zeta(1.5) * beta * unit
print(f"E⊥ − E∥ per atom of the film, uniform states (Ewald sum, slab {SLAB:g}):")
print("  planes  meV/atom   / continuum   added by the last plane / continuum")
for n, k, column in zip(planes, k_film, per_column):
    added = column - (per_column[n - 2] if n > 1 else 0.0)
    print(f"  {n:6d}  {k * 1e3:8.5f}   {k / continuum:10.5f}   {added / continuum:12.8f}")
print(f"monolayer (a square lattice): {k_film[0] * 1e3:.7f} meV, the exact lattice sum "
      f"3ζ(3/2)β(3/2) μ0μB²μ²/4πa³ = {monolayer * 1e3:.7f} meV "
      f"(relative difference {abs(k_film[0] / monolayer - 1):.1e})")
delta = (per_column - continuum * planes) / unit
last = per_column[-1] - per_column[-2]
print(f"plane {planes[-1]} adds the continuum's μ0Ms²/2·V_atom to "
      f"{abs(last / continuum - 1):.1e} (the inner planes' sums reach the bulk's "
      f"exponentially); the surfaces' share per column δ = {delta[-1]:.5f} μ0μB²μ²/4πa³: "
      f"E⊥ − E∥ → {continuum * 1e3:.4f} − {-delta[-1] * unit * 1e3:.4f}/n meV per atom "
      f"for thick films (δ at n = {planes[-2]}: {delta[-2]:.5f})")
k_this = k_film[args.layers - 1]
print(f"this film ({args.layers} planes): E⊥ − E∥ = {k_this * 1e3:.4f} meV per atom: "
      f"in-plane for K_u below it, perpendicular above")


# --- 2. dynamics: damped precession from a tilted perpendicular start
def run(ku):
    """One damped run at K_u = ``ku`` (eV): times (ps), mean spins, energies per atom
    (eV, total and dipolar)."""
    atoms = film(args.layers, args.size)
    set_spins(atoms, direction(math.radians(args.tilt)), MOMENT)
    atoms.calc = SpinLatticeCalculator([
        Exchange(BetheSlater(J1=0.02726, J2=0.2171, J3=1.841), rc=3.4),
        Dipolar(RC, args.method, accuracy=args.accuracy, slab=SLAB),
        UniaxialAnisotropy(ku, [0.0, 0.0, 1.0])])
    dyn = Langevin(atoms, args.timestep * units.fs, 0.0, spin_damping=1.0, friction=0.0,
                   lattice="frozen")
    record = {"t": [], "m": [], "e": [], "dipolar": []}

    def observe():
        terms = dyn.get_energy_terms()
        record["t"].append(dyn.get_time() / (1000 * units.fs))
        record["m"].append(dyn.get_magnetization())
        record["e"].append(sum(terms.values()) / len(atoms))
        record["dipolar"].append(terms["dipolar"] / len(atoms))

    steps = round(args.time * 1000 / args.timestep)
    interval = max(1, steps // 400)
    dyn.attach(observe, interval=interval)
    dyn.run(steps)
    if dyn.nsteps % interval:
        observe()  # the end
    torque = np.linalg.norm(np.cross(get_spins(atoms), dyn.get_magnetic_forces()),
                            axis=1).max()
    return {key: np.array(value) for key, value in record.items()}, torque


runs = {}
cos2 = math.cos(math.radians(args.tilt)) ** 2
for ku_mev in args.ku:
    ku = ku_mev * 1e-3
    record, torque = run(ku)
    m = record["m"][-1]
    theta = math.degrees(math.acos(m[2] / np.linalg.norm(m)))   # from the normal
    expect_plane = ku < k_this
    expected = (k_this - ku) * cos2 if expect_plane else (ku - k_this) * (1.0 - cos2)
    runs[ku_mev] = record, expected
    state = ("in-plane" if abs(theta - 90.0) < SETTLED else "perpendicular"
             if theta < SETTLED else "not settled yet")
    if state == "not settled yet":
        verdict = "a longer --time"
    elif state == ("in-plane" if expect_plane else "perpendicular"):
        verdict = "as expected"
    else:
        verdict = "NOT as expected"
    print(f"K_u = {ku_mev:.4f} meV: after {record['t'][-1]:.1f} ps m = "
          f"({m[0]:+.4f}, {m[1]:+.4f}, {m[2]:+.4f}), m_z = {m[2]:+.4f}, {theta:.2f}° from "
          f"the normal: {state}, {verdict}; largest torque {torque:.1e} eV; energy released "
          f"{(record['e'][0] - record['e'][-1]) * 1e3:.5f} meV per atom, the statics' "
          f"{expected * 1e3:.5f}")
print(f"took {time.perf_counter() - started:.1f} s")

try:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
except ImportError:
    print("matplotlib not installed: no picture")
else:
    from matplotlib.lines import Line2D

    fig, axes = plt.subplots(1, 3, figsize=(13, 4.0), constrained_layout=True)
    styles = ["-", "--", ":", "-."]
    colours = {"x": "tab:blue", "y": "tab:orange", "z": "tab:green"}
    for i, (ku_mev, (record, expected)) in enumerate(runs.items()):
        style = styles[i % len(styles)]
        for c, name in enumerate("xyz"):
            axes[0].plot(record["t"], record["m"][:, c], style, color=colours[name], lw=1.4)
        axes[1].plot(record["t"], (record["e"] - record["e"][0]) * 1e3, style, color="k",
                     lw=1.4)
        axes[1].plot(record["t"], (record["dipolar"] - record["dipolar"][0]) * 1e3, style,
                     color="tab:red", lw=1.4)
        axes[1].axhline(-expected * 1e3, color="tab:gray", lw=0.8, ls=":")
    runs_legend = [Line2D([], [], color="k", ls=styles[i % len(styles)],
                          label=f"$K_u$ = {ku_mev:g} meV") for i, ku_mev in enumerate(runs)]
    components = axes[0].legend(handles=[Line2D([], [], color=colours[n], label=f"$m_{n}$")
                                         for n in "xyz"], loc="upper left", ncol=3, fontsize=8)
    axes[0].add_artist(components)
    axes[0].legend(handles=runs_legend, loc="upper right", fontsize=8)
    axes[0].set_ylim(-1.05, 1.45)
    axes[0].set_xlabel("time (ps)")
    axes[0].set_ylabel("mean spin")
    axes[0].set_title(f"{args.layers} planes of bcc Fe(001), T = 0, damping λ = 1,\n"
                      f"from {args.tilt:g}° off the normal", fontsize=10)
    axes[1].legend(handles=[Line2D([], [], color="k", label="total"),
                            Line2D([], [], color="tab:red", label="dipolar part"),
                            Line2D([], [], color="tab:gray", ls=":",
                                   label="from the statics")] + runs_legend, fontsize=8)
    axes[1].set_xlabel("time (ps)")
    axes[1].set_ylabel("energy − start (meV per atom)")
    axes[1].set_title("energy: the dipolar term turns the film", fontsize=10)
    ax = axes[2]
    ax.plot(planes, k_film * 1e3, "o-", color="k", label="lattice (Ewald sum)")
    ax.plot([args.layers], [k_this * 1e3], "o", ms=11, mfc="none", color="tab:red",
            label="the film run")
    ax.axhline(continuum * 1e3, color="tab:gray", ls="--",
               label=r"continuum $\mu_0M_s^2/2\cdot V_{\rm atom}$")
    ax.plot(planes, (continuum + delta[-1] * unit / planes) * 1e3, ":", color="tab:purple",
            label=r"continuum + surfaces' $\delta/n$")
    for i, ku_mev in enumerate(runs):
        ax.axhline(ku_mev, color="tab:green", ls=styles[i % len(styles)], lw=1)
        ax.annotate(f"$K_u$ = {ku_mev:g} meV", (planes[0], ku_mev), xytext=(0, 3),
                    textcoords="offset points", color="tab:green", fontsize=8)
    ax.plot([], [], color="tab:green", label="$K_u$ of the runs")
    ax.set_xlabel("planes n")
    ax.set_ylabel(r"$E_\perp - E_\parallel$ (meV per atom)")
    ax.set_title("shape anisotropy: a film lies in-plane\nwhere it exceeds $K_u$",
                 fontsize=10)
    ax.legend(fontsize=8, loc="lower right")
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=90)
    print(f"wrote {out}")
