"""Error against wall time: CollectivePRK (orders 2, 4, 6), the SuzukiTrotter
baseline and LAMMPS `fix nve/spin`, all in one run on one machine.

    LD_LIBRARY_PATH=$VIRTUAL_ENV/lib python benchmarks/work_precision.py \
        [--scenes fcc500 chain] [--out docs/figures/work_precision] [--quick] \
        [--min-dt 0.1 --repeats 5]

Scenes: fcc Co (peers.md, N = 4n³: `fcc500`, `fcc4000`; `fcc500-field`: the same
with a 10 T field and uniaxial anisotropy, `scenes.field_anisotropy_terms`; 0.5 ps, moment convention,
LAMMPS's ħ, masses carrying LAMMPS's force-to-acceleration constant so that
every code integrates the same equations) and the paper's chain (T = 1). Every
final state is compared with one DOP853 solution of the equations of motion
(rtol 1e-13): RMS over atoms of |s_i − s_ref,i| (spins) and |r_i − r_ref,i| (Å).
Wall times are medians of --repeats runs (single runs above 20 s). LAMMPS runs
when `lammps` is importable (1 MPI rank, the peers.md input).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np
from ase import units

sys.path.insert(0, os.path.dirname(__file__))
# the drivers of LAMMPS and Spirit (lammps_peer, spirit_peer) live with the tests
sys.path.insert(0, os.path.join(os.path.dirname(__file__), os.pardir, "tests"))

import ase_spin  # noqa: E402
from ase_spin import CollectivePRK, SuzukiTrotter  # noqa: E402
from lammps_peer import LammpsSpin, lammps_available  # noqa: E402
from ase_spin.md.ode import reference_solution  # noqa: E402
from ase_spin.scenes import (FIELD_ANISOTROPY_LAMMPS, fcc_cobalt,  # noqa: E402
                             field_anisotropy_terms, paper_chain)
from machine import describe  # noqa: E402

HBAR_LAMMPS = ase_spin.HBAR_LAMMPS
#: LAMMPS metal units turn force/mass into acceleration with 1/1.0364269e-4
#: (Å/ps² per eV/Å/amu), 5.5e-8 off the CODATA value: masses × this ratio here.
MASS_RATIO = (1000.0 * units.fs) ** 2 * 1.0364269e-4
LJ = (0.4, 2.2742, 4.7, True)
EXCHANGE = (0.0446928, 0.003496, 1.4885, 4.0, False)

# (label, kind, options, steps in fs or in units of the chain's time)
FCC_METHODS = [
    ("CollectivePRK order 2", "prk", {"order": 2}, [0.5, 0.25, 0.15, 0.1, 0.05, 0.025]),
    ("CollectivePRK order 4", "prk", {"order": 4}, [2.0, 1.5, 1.25, 1.0, 0.5, 0.25, 0.125]),
    ("CollectivePRK order 6", "prk", {"order": 6}, [2.0, 1.0, 0.5, 0.25, 0.125]),
    ("SuzukiTrotter (Cayley)", "st", {"rotation": "cayley"}, [0.5, 0.2, 0.1, 0.05, 0.025]),
    ("SuzukiTrotter order 4 (Cayley)", "st", {"rotation": "cayley", "order": 4},
     [4.0, 3.0, 2.0, 1.0, 0.5, 0.25, 0.125]),
    ("LAMMPS fix nve/spin", "lammps", {}, [0.5, 0.2, 0.1, 0.05, 0.025, 0.01, 0.0025]),
]
CHAIN_METHODS = [
    ("CollectivePRK order 2", "prk", {"order": 2}, [2.0**-k for k in range(4, 11)]),
    ("CollectivePRK order 4", "prk", {"order": 4}, [2.0**-k for k in range(3, 8)]),
    ("CollectivePRK order 6", "prk", {"order": 6}, [2.0**-k for k in range(3, 7)]),
    ("SuzukiTrotter (Cayley)", "st", {"rotation": "cayley"}, [2.0**-k for k in range(4, 11)]),
    ("SuzukiTrotter (exact)", "st", {"rotation": "exact"}, [2.0**-k for k in range(4, 11)]),
]


def fcc_scene(n, field=False):
    atoms = fcc_cobalt(n, extra=field_anisotropy_terms() if field else (), conventions="lammps")
    velocities = atoms.get_velocities()
    atoms.set_masses(atoms.get_masses() * MASS_RATIO)
    atoms.set_velocities(velocities)
    return atoms


def warm_up_list_updates(make, kind, options, dt, integrator_kw):
    """Take a method through pair-list rebuilds and filterings (the fine skin,
    docs/calculator.md) before timing: a timed run meets them once atoms have
    moved a quarter of the skin, and the first use in a process of the code
    they need (the list kernels, the single compiled step that follows a
    filtering) is ~60 ms of loading from numba's cache, not a cost of the
    method; the four warm-up steps load the rest. Here a skin of 0.002 Å
    makes them happen within 40 steps of 0.1 fs (at most the method's own
    step: an atom may move half the skin in one)."""
    atoms = make()
    atoms.calc = ase_spin.SpinLatticeCalculator(atoms.calc.hamiltonian.terms, skin=0.002)
    cls = CollectivePRK if kind == "prk" else SuzukiTrotter
    cls(atoms, min(dt, 0.1 * units.fs), **integrator_kw, **options).run(40)


def rms(a, b):
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


def run_ours(make, kind, options, dt, t_end, integrator_kw):
    atoms = make()
    cls = CollectivePRK if kind == "prk" else SuzukiTrotter
    dyn = cls(atoms, dt, **integrator_kw, **options)
    steps = int(round(t_end / dt))
    t0 = time.perf_counter()
    dyn.run(steps)
    wall = time.perf_counter() - t0
    return wall, atoms.positions.copy(), ase_spin.get_spins(atoms), dyn.mean_iterations


def lammps_fixes(field):
    if not field:
        return ()
    return (f"fix 2 all precession/spin {FIELD_ANISOTROPY_LAMMPS}", "fix_modify 2 energy yes")


def run_lammps(n, dt_fs, t_fs, field=False):
    lmp = LammpsSpin(fcc_cobalt(n, conventions="lammps"), LJ, EXCHANGE, timestep_fs=dt_fs, fixes=lammps_fixes(field))
    lmp.run(0)
    t0 = time.perf_counter()
    lmp.run(int(round(t_fs / dt_fs)))
    wall = time.perf_counter() - t0
    x, _, s = lmp.state()
    lmp.close()
    return wall, x, s, float("nan")


def measure(scene, methods, repeats, quick):
    if scene.startswith("fcc"):
        n = {"fcc500": 5, "fcc4000": 10, "fcc500-field": 5}[scene]
        field = scene.endswith("-field")
        t_end = 500.0 * units.fs
        make = lambda: fcc_scene(n, field)  # noqa: E731
        kw = {"hbar": HBAR_LAMMPS}
        unit = units.fs
        t0 = time.perf_counter()
        xr, _, sr = reference_solution(make(), t_end, hbar=HBAR_LAMMPS)
    else:
        t_end = 1.0
        make = paper_chain
        kw = {"hbar": 1.0, "precession": "spin"}
        field = False
        unit = 1.0
        t0 = time.perf_counter()
        xr, _, sr = reference_solution(make(), t_end, **kw)
    print(f"# {scene}: DOP853 reference in {time.perf_counter() - t0:.1f} s", flush=True)
    rows = []
    for label, kind, options, steps in methods:
        if kind == "lammps" and not lammps_available():
            print(f"# {label}: lammps not importable, skipped")
            continue
        if scene == "fcc4000":  # LAMMPS at 0.01 fs and below: 8 and 35 min at this size
            steps = [dt for dt in steps if kind != "lammps" or dt >= 0.025]
        if kind != "lammps":  # load the compiled kernels before timing (four steps:
            # the first alone, then a block of them, fused.collective_block)
            run_ours(make, kind, options, steps[0] * unit, 4 * steps[0] * unit, kw)
            if scene.startswith("fcc"):
                warm_up_list_updates(make, kind, options, steps[0] * unit, kw)
        for dt in steps[:3] if quick else steps:
            walls = []
            for _ in range(repeats):
                if kind == "lammps":
                    wall, x, s, it = run_lammps(n, dt, t_end / units.fs, field)
                else:
                    wall, x, s, it = run_ours(make, kind, options, dt * unit, t_end, kw)
                walls.append(wall)
                if wall > 20.0:
                    break
            row = (label, dt, float(np.median(walls)), rms(s, sr), rms(x, xr), it)
            rows.append(row)
            print(f"{scene:8s} {label:24s} dt {dt:<9.5g} wall {row[2]:9.4f} s  "
                  f"spin RMS {row[3]:.3e}  pos RMS {row[4]:.3e}  sweeps/step {it:6.2f}",
                  flush=True)
    return rows


def time_at_error(rows, label, target, column=3):
    """Wall time ``label`` needs for spin (column 3) or position (4) RMS error
    ``target``, by log-log interpolation between its measured points; None
    outside their range."""
    pts = sorted((r[column], r[2]) for r in rows if r[0] == label)
    for (e0, t0), (e1, t1) in zip(pts, pts[1:]):
        if e0 <= target <= e1 and e0 > 0:
            f = np.log(target / e0) / np.log(e1 / e0) if e1 != e0 else 0.0
            return float(np.exp(np.log(t0) + f * np.log(t1 / t0)))
    return None


def equal_error_table(rows, reference="LAMMPS fix nve/spin"):
    """Lines comparing, at each error the reference code reached, the fastest
    ase_spin method's wall time with the reference's."""
    labels = [label for label in dict.fromkeys(r[0] for r in rows) if label != reference]
    lines = []
    for target in (4e-2, 1e-2, 3e-3, 1e-3, 3e-4, 1e-4, 1e-5, 1.1e-6):
        t_ref = time_at_error(rows, reference, target)
        times = {label: time_at_error(rows, label, target) for label in labels}
        times = {k: v for k, v in times.items() if v is not None}
        if not times:
            continue
        best = min(times, key=times.get)
        ref = f"{t_ref:8.2f} s" if t_ref is not None else "   (n/a)"
        ratio = f"{times[best] / t_ref:5.2f}" if t_ref is not None else "  -  "
        collective = {k: v for k, v in times.items() if k.startswith("CollectivePRK")}
        cbest = min(collective, key=collective.get) if collective else None
        ctext = (f"{cbest} {collective[cbest]:.2f} s" + (
            f" ({collective[cbest] / t_ref:.2f})" if t_ref else "")) if cbest else "-"
        lines.append(f"spin RMS {target:7.0e}: {reference} {ref} | fastest ase_spin: {best} "
                     f"{times[best]:.2f} s, ratio {ratio} | best CollectivePRK: {ctext}")
    return lines


def plot(results, out):
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib not installed: no plot")
        return
    scenes = list(results)
    fig, axes = plt.subplots(len(scenes), 2, figsize=(11, 4.2 * len(scenes)), squeeze=False)
    for (scene, rows), (ax_s, ax_x) in zip(results.items(), axes):
        labels = list(dict.fromkeys(r[0] for r in rows))
        for label in labels:
            sel = [r for r in rows if r[0] == label]
            style = "--" if "LAMMPS" in label else ("-." if "Suzuki" in label else "-")
            for ax, k in ((ax_s, 3), (ax_x, 4)):
                ax.loglog([r[2] for r in sel], [r[k] for r in sel], style, marker="o", ms=4,
                          label=label)
        ax_s.set(xlabel="wall time (s)", ylabel="spin RMS error", title=f"{scene}: spins")
        ax_x.set(xlabel="wall time (s)", ylabel="position RMS error (Å)",
                 title=f"{scene}: positions")
        ax_s.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "work_precision.png", dpi=110)


def main(argv=None):
    parser = argparse.ArgumentParser()
    parser.add_argument("--scenes", nargs="+", default=["fcc500", "chain"],
                        choices=["fcc500", "fcc4000", "fcc500-field", "chain"])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", default="work_precision_output")
    parser.add_argument("--quick", action="store_true", help="three steps per method")
    parser.add_argument("--min-dt", type=float, default=0.0,
                        help="leave out steps below this (fs; the chain: its time unit): "
                             "the loose-accuracy end alone, e.g. with more --repeats")
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    print(describe(), flush=True)
    results = {}
    for scene in args.scenes:
        methods = CHAIN_METHODS if scene == "chain" else FCC_METHODS
        methods = [(label, kind, options, [dt for dt in steps if dt >= args.min_dt])
                   for label, kind, options, steps in methods]
        results[scene] = measure(scene, methods, args.repeats, args.quick)
    with open(out / "work_precision.txt", "w") as f:
        f.write(describe() + "\n")
        f.write("# scene method dt wall_s spin_rms pos_rms sweeps_per_step\n")
        for scene, rows in results.items():
            for label, dt, wall, es, ex, it in rows:
                f.write(f"{scene}\t{label}\t{dt:.6g}\t{wall:.5f}\t{es:.4e}\t{ex:.4e}\t{it:.2f}\n")
        for scene, rows in results.items():
            if any(r[0].startswith("LAMMPS") for r in rows):
                f.write(f"# {scene}: wall time at equal spin RMS error (interpolated)\n")
                for line in equal_error_table(rows):
                    f.write("# " + line + "\n")
                    print(line)
    plot(results, out)
    print(f"wrote {out}/work_precision.txt and .png")


if __name__ == "__main__":
    main()
