"""Stress tests of CollectivePRK: where it stops working, and how it says so.

    python benchmarks/stress.py [--n 5] [--steps 2000] [--solver auto]

For fcc Co (peers.md scene unless stated), each case runs `--steps` steps and
reports how it ended: "ok" with the energy error and spin-length error, or the
error raised (its class and first line). Cases:

- dt sweep at 100 K, up to and past failure: which limit is hit first, the
  spin iteration (SpinConvergenceError) or the lattice (UnstableStepError)?
  (``--solver jacobi``: the midpoint solver before the locally exact and
  Anderson-accelerated ones.)
- hot lattices: 1000, 2000 and 4000 K at 0.5 fs;
- random spins (a paramagnet) at 0.5 fs;
- strong compression: the lattice constant scaled by 0.9 and 0.85;
- two atoms pushed towards each other at 1, 10 and 100 eV of relative kinetic energy.

Nothing here may end in NaN: every case ends in a finite state or a named error.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np
from ase import units

sys.path.insert(0, os.path.dirname(__file__))

import ase_spin  # noqa: E402
from ase_spin import CollectivePRK  # noqa: E402
from ase_spin.scenes import cone, fcc_cobalt  # noqa: E402
from machine import describe  # noqa: E402


SOLVER = "auto"


def run_case(name, atoms, dt_fs, steps):
    dyn = CollectivePRK(atoms, dt_fs * units.fs, solver=SOLVER)
    t0 = time.perf_counter()
    try:
        e0 = dyn.get_total_energy()
        dyn.run(steps)
    except Exception as exc:  # report every way a run can end
        finite = bool(np.isfinite(atoms.positions).all()
                      and np.isfinite(atoms.get_initial_magnetic_moments()).all())
        first = str(exc).split(". ")[0][:110]
        print(f"{name:38s} dt {dt_fs:5.2f} fs  {type(exc).__name__} at step {dyn.nsteps}"
              f" (atoms finite: {finite}): {first}")
        return
    wall = time.perf_counter() - t0
    de = abs(dyn.get_total_energy() - e0) / len(atoms)
    s = dyn._state.s[dyn.ev.magnetic]
    ds = float(np.abs(np.sqrt((s * s).sum(axis=1)) - 1).max()) if len(s) else 0.0
    print(f"{name:38s} dt {dt_fs:5.2f} fs  ok: |ΔE|/N {de:.2e} eV, | |s|-1 | {ds:.1e}, "
          f"{dyn.mean_iterations:5.1f} sweeps/step, T {dyn.get_temperature():7.1f} K, "
          f"{wall:.1f} s")


def main(argv=None):
    parser = argparse.ArgumentParser()
    parser.add_argument("--n", type=int, default=5)
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--solver", default="auto")
    args = parser.parse_args(argv)
    global SOLVER
    SOLVER = args.solver
    n, steps = args.n, args.steps
    print(describe())
    print(f"# fcc Co, {4 * n**3} atoms, {steps} steps per case, solver {SOLVER!r}, "
          f"load {os.getloadavg()[0]:.2f}")
    for dt in (0.5, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0, 12.0):
        run_case("dt sweep, 100 K", fcc_cobalt(n), dt, steps)
    for frozen_dt in (4.0, 6.0, 8.0):
        atoms = fcc_cobalt(n)
        dyn = CollectivePRK(atoms, frozen_dt * units.fs, lattice="frozen", solver=SOLVER)
        try:
            dyn.run(steps)
            print(f"{'dt sweep, frozen lattice':38s} dt {frozen_dt:5.2f} fs  ok "
                  f"({dyn.mean_iterations:.1f} sweeps/step)")
        except Exception as exc:
            print(f"{'dt sweep, frozen lattice':38s} dt {frozen_dt:5.2f} fs  "
                  f"{type(exc).__name__} at step {dyn.nsteps}")
    for temperature in (1000, 2000, 4000):
        run_case(f"hot lattice {temperature} K", fcc_cobalt(n, temperature_K=temperature),
                 0.5, steps)
    para = fcc_cobalt(n)
    ase_spin.set_spins(para, cone(len(para), np.random.default_rng(1), 180.0),
                       magnitudes=1.72)
    run_case("random spins (paramagnet)", para, 0.5, steps)
    for scale in (0.9, 0.85):
        atoms = fcc_cobalt(n)
        atoms.set_cell(atoms.cell * scale, scale_atoms=True)
        run_case(f"compressed, a × {scale}", atoms, 0.5, steps)
    for energy in (1.0, 10.0, 100.0):
        atoms = fcc_cobalt(n, temperature_K=0)
        m = atoms.get_masses()[0]
        v = np.sqrt(energy / m)  # each of the two atoms carries energy/2
        momenta = np.zeros((len(atoms), 3))
        neighbour = int(np.argmin(np.linalg.norm(atoms.positions[1:] - atoms.positions[0],
                                                 axis=1))) + 1
        d = atoms.positions[neighbour] - atoms.positions[0]
        d /= np.linalg.norm(d)
        momenta[0] = m * v * d
        momenta[neighbour] = -m * v * d
        atoms.set_momenta(momenta)
        run_case(f"head-on pair, {energy:g} eV", atoms, 0.5, 400)


if __name__ == "__main__":
    main()
