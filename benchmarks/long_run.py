"""Long runs: energy error, its drift, spin lengths and momentum over many steps.

    python benchmarks/long_run.py chain --steps 100000 --dt 0.015625
    python benchmarks/long_run.py fcc --n 5 --steps 100000 --dt 0.1
    python benchmarks/long_run.py fcc-field --steps 1000 --dt 0.1 --method lammps

chain: the paper's experiment (ħ = 1, spin convention, dt in its time units);
fcc: the peers.md fcc Co scene (moment convention, dt in fs); fcc-field: the same
with a 10 T field and uniaxial anisotropy (scenes.field_anisotropy_terms).
--method: collective (CollectivePRK, default), splitting (SuzukiTrotter) or
lammps (fix nve/spin with fix precession/spin; its etotal every sample). Prints the largest
energy error, a straight line fitted to the energy error against time (its
change over the run, beside the error's own spread), the largest | |s_i| − 1 |
(no renormalisation anywhere) and the change of total momentum.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np
from ase import units

sys.path.insert(0, os.path.dirname(__file__))
# the drivers of LAMMPS and Spirit (lammps_peer, spirit_peer) live with the tests
sys.path.insert(0, os.path.join(os.path.dirname(__file__), os.pardir, "tests"))

from ase_spin import HBAR_LAMMPS, CollectivePRK, SuzukiTrotter  # noqa: E402
from ase_spin.scenes import (FIELD_ANISOTROPY_LAMMPS, fcc_cobalt,  # noqa: E402
                             field_anisotropy_terms, paper_chain)
from machine import describe  # noqa: E402


def main(argv=None):
    parser = argparse.ArgumentParser()
    parser.add_argument("scene", choices=["chain", "fcc", "fcc-field"])
    parser.add_argument("--method", choices=["collective", "splitting", "lammps"],
                        default="collective")
    parser.add_argument("--steps", type=int, default=100_000)
    parser.add_argument("--dt", type=float, default=None)
    parser.add_argument("--n", type=int, default=5)
    parser.add_argument("--order", type=int, default=2)
    parser.add_argument("--samples", type=int, default=2000)
    args = parser.parse_args(argv)
    if args.method == "lammps":
        return lammps_run(args)
    integrator = CollectivePRK if args.method == "collective" else SuzukiTrotter
    if args.scene == "chain":
        atoms = paper_chain()
        dt = args.dt or 2.0**-6
        dyn = integrator(atoms, dt, hbar=1.0, precession="spin", order=args.order)
        label = f"paper chain, h = {dt:g}"
    else:
        field = args.scene == "fcc-field"
        atoms = fcc_cobalt(args.n, extra=field_anisotropy_terms() if field else (), conventions="lammps")
        dt = args.dt or 0.1
        dyn = integrator(atoms, dt * units.fs, order=args.order, hbar=HBAR_LAMMPS)
        label = (f"{args.scene} Co N = {len(atoms)}, dt = {dt:g} fs, "
                 f"{integrator.__name__}")
    e0 = dyn.get_total_energy()
    p0 = atoms.get_momenta().sum(axis=0)
    times, errors, lengths = [], [], []

    def record():
        times.append(dyn.get_time())
        errors.append(dyn.get_total_energy() - e0)
        s = dyn._state.s[dyn.ev.magnetic]
        lengths.append(float(np.abs(np.sqrt((s * s).sum(axis=1)) - 1.0).max()))

    dyn.attach(record, interval=max(1, args.steps // args.samples))
    t0 = time.perf_counter()
    dyn.run(args.steps)
    wall = time.perf_counter() - t0
    times, errors = np.array(times), np.array(errors)
    slope, intercept = np.polyfit(times, errors, 1)
    residual = errors - (slope * times + intercept)
    print(f"{label}, order {args.order}, {args.steps} steps in {wall:.1f} s "
          f"({wall / args.steps * 1e6:.1f} µs/step), {dyn.mean_iterations:.2f} sweeps/step")
    print(f"energy error: max |E - E0| = {np.abs(errors).max():.3e} eV, std {errors.std():.3e}, "
          f"final {errors[-1]:+.3e} eV")
    print(f"fitted drift over the run: {slope * times[-1]:.3e} eV "
          f"(residual std {residual.std():.3e})")
    print(f"spin lengths: max | |s| - 1 | = {max(lengths):.2e}")
    print(f"total momentum change: {np.abs(atoms.get_momenta().sum(axis=0) - p0).max():.2e}")
    print(describe())


def lammps_run(args):
    """LAMMPS fix nve/spin on the same scene: its total energy (pe + ke, the
    precession fix's energy included) every sample."""
    from lammps_peer import LammpsSpin

    if args.scene == "chain":
        raise SystemExit("the chain scene has no LAMMPS counterpart here")
    field = args.scene == "fcc-field"
    dt = args.dt or 0.1
    fixes = ((f"fix 2 all precession/spin {FIELD_ANISOTROPY_LAMMPS}", "fix_modify 2 energy yes")
             if field else ())
    lmp = LammpsSpin(fcc_cobalt(args.n, conventions="lammps"), (0.4, 2.2742, 4.7, True),
                     (0.0446928, 0.003496, 1.4885, 4.0, False), timestep_fs=dt, fixes=fixes)
    lmp.run(0)
    e0 = lmp.lmp.get_thermo("etotal")
    every = max(1, args.steps // args.samples)
    times, errors = [], []
    t0 = time.perf_counter()
    for k in range(args.steps // every):
        lmp.run(every)
        times.append((k + 1) * every * dt)
        errors.append(lmp.lmp.get_thermo("etotal") - e0)
    wall = time.perf_counter() - t0
    _, _, s = lmp.state()
    lmp.close()
    times, errors = np.array(times), np.array(errors)
    slope, intercept = np.polyfit(times, errors, 1)
    print(f"{args.scene} Co N = {4 * args.n**3}, dt = {dt:g} fs, LAMMPS fix nve/spin, "
          f"{args.steps} steps in {wall:.1f} s ({wall / args.steps * 1e6:.1f} µs/step)")
    print(f"energy error: max |E - E0| = {np.abs(errors).max():.3e} eV, std {errors.std():.3e}, "
          f"final {errors[-1]:+.3e} eV")
    print(f"fitted drift over the run: {slope * times[-1]:.3e} eV")
    print(f"spin lengths: max | |s| - 1 | = {np.abs(np.linalg.norm(s, axis=1) - 1).max():.2e}")
    print(describe())


if __name__ == "__main__":
    main()
