"""Magnetisation curve of fcc Co heated through its Curie temperature.

The fcc Co scene of ase_spin.scenes (LJ lattice + Bethe–Slater exchange of LAMMPS
examples/SPIN/cobalt_fcc, moments 1.72 μB) in contact with one bath for spins
and lattice (ase_spin.Langevin), heated in steps: at each temperature the run
equilibrates, then records |M| (the mean unit spin's norm), the spin temperature
(LAMMPS compute spin's estimator, Σ|s×B|²/(2k_B Σ s·B) with numerator and
denominator averaged over the run) and the lattice kinetic temperature.

T_C is estimated per independent replica (its own seed and start) as the
inflection point of a logistic fit |M|(T) = a/(1 + exp((T − T_C)/w)) + c, and
reported as the replicas' mean ± their standard error. With a periodic box of
4n³ atoms |M| does not vanish above T_C (finite size: |M| ~ N^(-1/2)); the
inflection point is a rough, size-dependent estimate, not the bulk value.

    python examples/magnetisation_curve.py            # ~1 min: 108 atoms, 3 replicas
    python examples/magnetisation_curve.py --long     # 500 atoms, 5 replicas, longer runs

writes magnetisation_curve.png (the curves) and magnetisation_curve.txt (the
table) in the current folder, or in the folder --out DIR; --out NAME.png writes
NAME.png and NAME.txt. The docs' figure: --out docs/figures/magnetisation_curve.
"""

from __future__ import annotations

import argparse
import pathlib
import time

import numpy as np
from ase import units
from scipy.optimize import curve_fit

from ase_spin import Langevin
from ase_spin.scenes import fcc_cobalt



def heat(n, temperatures, equilibrate, sample, seed, timestep=0.5 * units.fs):
    """One replica: |M|, spin and lattice temperatures averaged at each T."""
    atoms = fcc_cobalt(n, temperature_K=temperatures[0], cone_deg=10.0, seed=seed)
    dyn = Langevin(atoms, timestep, temperatures[0], spin_damping=0.5,
                   friction=0.02 / units.fs, rng=seed)
    rows = []
    for T in temperatures:
        dyn.set_temperature(T)
        dyn.run(equilibrate)
        m, num, den, tl = [], [], [], []

        def record():
            m.append(np.linalg.norm(dyn.get_magnetization()))
            s, B = dyn.atoms.get_initial_magnetic_moments(), dyn.get_magnetic_forces()
            s = s / np.linalg.norm(s, axis=1)[:, None]
            num.append((np.cross(s, B) ** 2).sum())
            den.append(np.einsum("ij,ij->", s, B))
            tl.append(dyn.get_temperature())

        dyn.attach(record, interval=10)
        dyn.run(sample)
        dyn.observers.pop()
        # compute spin's estimator, numerator and denominator averaged apart (the
        # mean of per-sample ratios is dominated by small denominators above T_C)
        ts = np.mean(num) / (2.0 * units.kB * np.mean(den))
        rows.append((T, np.mean(m), ts, np.mean(tl)))
    return np.array(rows)


def logistic(T, a, tc, w, c):
    return a / (1.0 + np.exp(np.clip((T - tc) / w, -50.0, 50.0))) + c


def curie_temperature(T, M):
    """The inflection point of a logistic fit to |M|(T)."""
    p0 = (M.max() - M.min(), T[np.argmin(np.gradient(M, T))], 150.0, M.min())
    p, _ = curve_fit(logistic, T, M, p0=p0, bounds=([0, T[0], 10, 0], [2, T[-1], 2000, 1]))
    return p[1]


def output_paths(out):
    """(picture, table) for --out: a name ending in .png is the picture, with the
    table next to it (.txt); anything else is a folder to write
    magnetisation_curve.png and .txt into."""
    out = pathlib.Path(out)
    if out.suffix.lower() == ".png":
        return out, out.with_suffix(".txt")
    return out / "magnetisation_curve.png", out / "magnetisation_curve.txt"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--long", action="store_true", help="500 atoms, 5 replicas, 4x longer")
    ap.add_argument("--out", type=pathlib.Path, default=pathlib.Path("."),
                    help="folder for magnetisation_curve.png and .txt (default: the current "
                         "folder), or NAME.png: the picture, with the table in NAME.txt")
    args = ap.parse_args()
    png, txt = output_paths(args.out)
    if args.long:
        n, replicas, eq, samp = 5, 5, 2000, 4000
        temperatures = np.arange(200.0, 2401.0, 100.0)
    else:
        n, replicas, eq, samp = 3, 3, 300, 600
        temperatures = np.arange(200.0, 2401.0, 200.0)
    start = time.perf_counter()
    runs = [heat(n, temperatures, eq, samp, seed=s) for s in range(replicas)]
    tcs = np.array([curie_temperature(r[:, 0], r[:, 1]) for r in runs])
    tc, tc_err = tcs.mean(), tcs.std(ddof=1) / np.sqrt(replicas)
    data = np.mean(runs, axis=0)
    spread = np.std([r[:, 1] for r in runs], axis=0, ddof=1) / np.sqrt(replicas)
    elapsed = time.perf_counter() - start
    print(f"fcc Co, {4 * n**3} atoms, {replicas} replicas: T_C ≈ {tc:.0f} ± {tc_err:.0f} K "
          f"(per replica: {', '.join(f'{t:.0f}' for t in tcs)}); {elapsed:.0f} s")

    png.parent.mkdir(parents=True, exist_ok=True)
    header = (f"fcc Co {4 * n**3} atoms, {replicas} replicas, equilibrate {eq} + sample {samp} "
              f"steps of 0.5 fs per T; T_C = {tc:.1f} +- {tc_err:.1f} K\n"
              "T_bath[K] |M| se(|M|) Ts[K] T_lattice[K]")
    np.savetxt(txt,
               np.column_stack([data[:, 0], data[:, 1], spread, data[:, 2], data[:, 3]]),
               header=header, fmt="%.6g")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4))
    ax1.errorbar(data[:, 0], data[:, 1], yerr=spread, fmt="o-", ms=4, label="|M|")
    Tf = np.linspace(temperatures[0], temperatures[-1], 300)
    fit = curve_fit(logistic, data[:, 0], data[:, 1], p0=(0.8, tc, 150.0, 0.1),
                    bounds=([0, Tf[0], 10, 0], [2, Tf[-1], 2000, 1]))[0]
    ax1.plot(Tf, logistic(Tf, *fit), "k--", lw=1, label="logistic fit (mean curve)")
    ax1.axvspan(tc - tc_err, tc + tc_err, color="C3", alpha=0.3,
                label=f"T_C ≈ {tc:.0f} ± {tc_err:.0f} K")
    ax1.set_xlabel("bath temperature (K)")
    ax1.set_ylabel("|M| (mean unit spin)")
    ax1.legend()
    ax2.plot(data[:, 0], data[:, 2], "o-", ms=4, label="spin (compute spin)")
    ax2.plot(data[:, 0], data[:, 3], "s-", ms=4, label="lattice (kinetic)")
    ax2.plot(temperatures, temperatures, "k:", lw=1, label="bath")
    ax2.set_xlabel("bath temperature (K)")
    ax2.set_ylabel("measured temperature (K)")
    ax2.legend()
    fig.suptitle(f"fcc Co, {4 * n**3} atoms, Langevin (λ = 0.5, γ = 0.02/fs)")
    fig.tight_layout()
    fig.savefig(png, dpi=110)
    print(f"wrote {png} and {txt}")


if __name__ == "__main__":
    main()
