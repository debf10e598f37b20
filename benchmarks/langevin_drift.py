"""Does a thermostatted run's conserved quantity drift with the default midpoint
tolerance? E_tot − E_bath (per atom) of a `Langevin` run at the default ``tol``
against a run of the same seed at ``tol=1e-12``: the slope of their difference
(a linear fit over the samples), its largest value, and that quantity's own
spread in the tight run, at two temperatures.

    python benchmarks/langevin_drift.py [--steps 40000] [--n 5] [--dt 0.1]

fcc Co (4n³ atoms), spin damping 0.1, friction 0.01/fs, seed 11, a sample every
200 steps (each sample is an output point: the bath there is done in two halves
in both runs).
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np
from ase import units

sys.path.insert(0, os.path.dirname(__file__))
sys.path.insert(0, os.environ.get("ASE_SPIN_TREE") or os.path.join(os.path.dirname(__file__), ".."))

from ase_spin import Langevin  # noqa: E402
from ase_spin.scenes import fcc_cobalt  # noqa: E402
from machine import describe  # noqa: E402

EVERY = 200


def run(n, dt, temperature, steps, tol):
    atoms = fcc_cobalt(n, temperature_K=temperature)
    kw = {} if tol is None else {"tol": tol}
    dyn = Langevin(atoms, dt * units.fs, temperature, spin_damping=0.1,
                   friction=0.01 / units.fs, rng=11, **kw)
    samples = []
    dyn.attach(lambda: samples.append(dyn.get_conserved_energy()), interval=EVERY)
    dyn.run(steps)
    return np.array(samples) / len(atoms), dyn.total_iterations / dyn.total_steps


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--steps", type=int, default=40_000)
    ap.add_argument("--n", type=int, default=5, help="4n³ atoms")
    ap.add_argument("--dt", type=float, default=0.1, help="fs")
    ap.add_argument("--temperatures", type=float, nargs="+", default=[30.0, 300.0])
    args = ap.parse_args(argv)
    print(describe())
    print(f"fcc Co, {4 * args.n**3} atoms, dt = {args.dt} fs, {args.steps} steps")
    for T in args.temperatures:
        loose, sweeps = run(args.n, args.dt, T, args.steps, None)
        tight, tight_sweeps = run(args.n, args.dt, T, args.steps, 1e-12)
        diff = loose - tight
        slope = np.polyfit(np.arange(len(diff)) * EVERY, diff, 1)[0]
        print(f"T = {T:g} K: E_tot − E_bath, default tol minus tol=1e-12: drift {slope:.2e} "
              f"eV/atom per step, largest {np.abs(diff).max():.2e}; its own spread "
              f"{np.ptp(tight):.2e} eV/atom; sweeps a step {sweeps:.2f} (tol=1e-12: "
              f"{tight_sweeps:.2f})")


if __name__ == "__main__":
    main()
