"""CollectivePRK and LAMMPS `fix nve/spin` converge to the same trajectory.

The fcc Co scene of peers.md (moment convention, LAMMPS's ħ), run by both codes
with shrinking dt; each final state is compared with a DOP853 solution of the
equations of motion (tight tolerances) and with the other code's.

    LD_LIBRARY_PATH=$VIRTUAL_ENV/lib python benchmarks/lammps_convergence.py [--n 3] [--fs 50]

Prints RMS differences of spins (unit vectors) and positions (Å).
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

import ase_spin  # noqa: E402
from ase_spin import CollectivePRK  # noqa: E402
from lammps_peer import LammpsSpin, lammps_available  # noqa: E402
from ase_spin.md.ode import reference_solution  # noqa: E402
from ase_spin.scenes import fcc_cobalt  # noqa: E402

#: LAMMPS's ħ (eV·ps) in eV·(ASE time)
HBAR_LAMMPS_ASE = ase_spin.HBAR_LAMMPS
LJ = (0.4, 2.2742, 4.7, True)
EXCHANGE = (0.0446928, 0.003496, 1.4885, 4.0, False)


def rms(a, b):
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


def ours(n, t_fs, dt_fs, order=2):
    atoms = fcc_cobalt(n, conventions="lammps")
    dyn = CollectivePRK(atoms, dt_fs * units.fs, hbar=HBAR_LAMMPS_ASE, order=order)
    dyn.run(int(round(t_fs / dt_fs)))
    return atoms.positions.copy(), ase_spin.get_spins(atoms), dyn.mean_iterations


def lammps(n, t_fs, dt_fs):
    atoms = fcc_cobalt(n, conventions="lammps")
    lmp = LammpsSpin(atoms, LJ, EXCHANGE, timestep_fs=dt_fs)
    lmp.run(int(round(t_fs / dt_fs)))
    x, _, s = lmp.state()
    lmp.close()
    return x, s


def main(argv=None):
    parser = argparse.ArgumentParser()
    parser.add_argument("--n", type=int, default=3, help="4n³ atoms (default 108)")
    parser.add_argument("--fs", type=float, default=50.0, help="simulated time, fs")
    parser.add_argument("--dts", default="0.8,0.4,0.2,0.1,0.05")
    args = parser.parse_args(argv)
    if not lammps_available():
        sys.exit("lammps is not importable (see docs: LD_LIBRARY_PATH=$VIRTUAL_ENV/lib)")
    from machine import describe

    print(describe())
    t0 = time.perf_counter()
    xr, _, sr = reference_solution(fcc_cobalt(args.n, conventions="lammps"), args.fs * units.fs, hbar=HBAR_LAMMPS_ASE,
                                   precession="moment")
    print(f"fcc Co, {4 * args.n**3} atoms, T = {args.fs} fs, moment convention, ħ = LAMMPS's; "
          f"DOP853 reference in {time.perf_counter() - t0:.1f} s")
    print(f"{'dt/fs':>6} | {'spins: ours-ref':>15} {'lammps-ref':>11} {'ours-lammps':>12} | "
          f"{'pos: ours-ref':>13} {'lammps-ref':>11} {'ours-lammps':>12} | sweeps/step")
    for dt in (float(x) for x in args.dts.split(",")):
        xo, so, it = ours(args.n, args.fs, dt)
        xl, sl = lammps(args.n, args.fs, dt)
        print(f"{dt:6.3f} | {rms(so, sr):15.3e} {rms(sl, sr):11.3e} {rms(so, sl):12.3e} | "
              f"{rms(xo, xr):13.3e} {rms(xl, xr):11.3e} {rms(xo, xl):12.3e} | {it:6.2f}")


if __name__ == "__main__":
    main()
