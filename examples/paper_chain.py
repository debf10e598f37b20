"""The numerical experiment of Bogfjellmo's paper, with ase_spin.

A periodic chain of 30 atoms (masses 1, at rest at x_k = k, L = 30), nearest-
neighbour Lennard-Jones (U0 = 1, r_m = 1) and the cubic exchange
H_m = Σ J0 (1 − r/rc)³ w_i·w_{i+1} with J0 = 10, rc = 1.5, spins
w_k ∝ (0.8 cos 2πk/n + 0.5 sin 4πk/n, 0.8 sin 2πk/n + 0.5 cos 4πk/n, 1),
in the paper's reduced units (ħ = 1) and spin convention (dw/dt = w × B).
The mapping onto ASE units and this package's sign of J is in
docs/conventions.md; the Atoms come from ase_spin.scenes.paper_chain().

Writes to the folder --out (default: paper_chain_output/ in the current folder; the
docs' figures: --out docs/figures/paper_chain). Units: energies in eV (= the paper's
U0), times in ASE time units (the paper's time; 1 ASE time unit = 10.18 fs):

- energy.png, energy.txt   the paper's Figure 1: T_L, U_L (+35), H_m and H over T = 100
- errors.png, errors.txt   the paper's Figure 2: pseudo-errors at T = 1 for
                           h = 2^-4 ... 2^-19 against h = 2^-20, and the true error
                           against a DOP853 solution of the equations of motion

Run:  python examples/paper_chain.py [--quick] [--out DIR] [--energy-step H]
(--quick stops at h = 2^-10 against 2^-11 and runs Figure 1 at h = 2^-4; the
full run takes a few minutes, most of it the 2^20 reference steps.)
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

import ase_spin
from ase_spin import CollectivePRK
from ase_spin.md.ode import reference_solution
from ase_spin.scenes import paper_chain

PAPER = dict(hbar=1.0, precession="spin")


def final_state(h, t_end=1.0, order=2):
    atoms = paper_chain()
    dyn = CollectivePRK(atoms, h, order=order, **PAPER)
    dyn.run(int(round(t_end / h)))
    return np.concatenate([atoms.positions[:, 0], atoms.get_momenta()[:, 0],
                           ase_spin.get_spins(atoms).ravel()]), dyn


def energies(h, t_end=100.0, every=None):
    atoms = paper_chain()
    dyn = CollectivePRK(atoms, h, **PAPER)
    every = every or max(1, int(round(0.05 / h)))
    rows = []

    def record():
        terms = dyn.get_energy_terms()
        kin = dyn.get_kinetic_energy()
        rows.append((dyn.get_time(), kin, terms["lennard_jones"], terms["exchange"],
                     kin + terms["lennard_jones"] + terms["exchange"]))

    dyn.attach(record, interval=every)
    dyn.run(int(round(t_end / h)))
    return np.array(rows)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true",
                        help="seconds: Figure 2 down to h = 2^-10 against 2^-11, Figure 1 at "
                             "h = 2^-4")
    parser.add_argument("--out", default="paper_chain_output",
                        help="folder for energy.png, errors.png and their tables "
                             "(default: paper_chain_output)")
    parser.add_argument("--energy-step", type=float, default=None,
                        help="h for Figure 1 (default 2^-6; 2^-4 with --quick)")
    args = parser.parse_args()
    out = Path(args.out)
    if out.suffix.lower() == ".png":
        parser.error("--out is a folder: this example writes two pictures and two tables")
    out.mkdir(parents=True, exist_ok=True)
    finest = 11 if args.quick else 20
    exponents = list(range(4, finest))

    # Figure 1 -------------------------------------------------------------
    h_energy = args.energy_step or (2.0**-4 if args.quick else 2.0**-6)
    t0 = time.perf_counter()
    rows = energies(h_energy)
    spent = time.perf_counter() - t0
    drift = rows[:, 4] - rows[0, 4]
    with open(out / "energy.txt", "w") as f:
        f.write(f"# paper chain, h = {h_energy:g}, T = 100 (ASE time units; ħ = 1)\n")
        f.write(f"# max |H(t) - H(0)| = {np.abs(drift).max():.3e}; energy exchanged: "
                f"H_m spans {np.ptp(rows[:, 3]):.3f}, T_L spans {np.ptp(rows[:, 1]):.3f}\n")
        f.write("# t  T_L  U_L  H_m  H\n")
        np.savetxt(f, rows, fmt="%.10g")
    print(f"Figure 1: h = {h_energy:g}, {int(100 / h_energy)} steps in {spent:.1f} s; "
          f"max |H - H(0)| = {np.abs(drift).max():.3e}, H_m spans {np.ptp(rows[:, 3]):.3f}")

    # Figure 2 -------------------------------------------------------------
    reference, _ = final_state(2.0**-finest)
    q, p, s = reference_solution(paper_chain(), 1.0, **PAPER)
    ode = np.concatenate([q[:, 0], p[:, 0], s.ravel()])
    table = []
    for e in exponents:
        h = 2.0**-e
        t0 = time.perf_counter()
        y, dyn = final_state(h)
        spent = time.perf_counter() - t0
        table.append((h, np.linalg.norm(y - reference), np.linalg.norm(y - ode),
                      dyn.mean_iterations, spent))
    table = np.array(table)
    order = np.full(len(table), np.nan)
    order[1:] = np.log2(table[:-1, 1] / table[1:, 1])
    with open(out / "errors.txt", "w") as f:
        f.write(f"# pseudo-error: |y_h - y_(2^-{finest})| (2-norm over q, p, w) at T = 1; "
                "true error: against DOP853 (rtol 1e-13)\n")
        f.write("# h  pseudo_error  observed_order  true_error  sweeps_per_step  seconds\n")
        for row, o in zip(table, order):
            f.write(f"{row[0]:.6e} {row[1]:.4e} {o:6.3f} {row[2]:.4e} {row[3]:6.2f} {row[4]:8.3f}\n")
    print(open(out / "errors.txt").read())

    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib not installed: tables written, no plots")
        return
    fig, (ax, dx) = plt.subplots(2, 1, figsize=(9.5, 6), sharex=True)
    t = rows[:, 0]
    curves = [(rows[:, 3], 0, "r", "$H_m$"), (rows[:, 2], 35, "b", "$U_L + 35$"),
              (rows[:, 1], 0, "g", "$T_L$"), (rows[:, 4], 35, "purple", "$H + 35$")]
    for y, offset, color, label in curves:
        ax.plot(t, y + offset, color=color, lw=0.8, label=label)
        dx.plot(t, y - y[0], color=color, lw=0.8, label=label.replace(" + 35", ""))
    ax.set(ylabel="energy (eV = $U_0$)", xlim=(0, 100),
           title=f"Paper chain, collective PRK, h = {h_energy:g} (as the paper's Figure 1)")
    # legends beside the axes: the curves span the whole time range
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
    dx.set(xlabel="time (ASE units = the paper's; 1 = 10.18 fs)",
           ylabel="change since t = 0 (eV)")
    dx.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "energy.png", dpi=120)
    fig, ax = plt.subplots(figsize=(6, 4.5))
    ax.loglog(table[:, 0], table[:, 1], "o-", color="b", label="pseudo-error (vs $h=2^{-%d}$)" % finest)
    ax.loglog(table[:, 0], table[:, 2], "s", mfc="none", color="k", ms=5,
              label="error vs DOP853")
    hh = np.array([table[-1, 0], table[0, 0]])
    ax.loglog(hh, hh**2, "r--", label="$h^2$")
    ax.set(xlabel="step $h$ (ASE time units)",
           ylabel="error (2-norm over $q$ [Å], $p$, $w$)", title="Pseudo-error at T = 1")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "errors.png", dpi=120)
    print(f"wrote {out}/energy.png, {out}/errors.png and the tables")


if __name__ == "__main__":
    main()
