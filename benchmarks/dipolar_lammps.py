"""The long-range dipolar term against LAMMPS: one k-space evaluation of ours
(``Dipolar(method="ewald")``, ``"pme"``) and of LAMMPS's ``ewald/dipole/spin``
and ``pppm/dipole/spin``, at the same splitting α, cutoff and accuracy.

    python benchmarks/dipolar_lammps.py [--pme-sizes 6 10 16] [--ewald-sizes 4 6]
                                        [--rc 6] [--accuracy 1e-4] [--steps 10]

fcc Co (4n³ atoms, spins in a 30° cone), ``Dipolar(rc, method, accuracy)``.
LAMMPS runs write_lammps's deck of that term (pppm: order 7, LAMMPS's highest,
on the mesh ours chooses for order 7 at that accuracy; ewald: kmax/ewald from
the same k_c) for --steps steps without an integrator, on 1 and 2 MPI ranks: a step is
one pair + one k-space computation (forces, fields; the energy on thermo
steps). Its timer breakdown gives the Kspace seconds a step (setup, where P3M builds its influence function, is
outside the loop) and the loop's. Ours, in a fresh process on 1 and 2 numba
threads, best of three: the k-space part alone (``recip.add``: energy, forces
and field, as LAMMPS's Kspace), one field from the prepared operator (real
space + k-space: a midpoint iteration), and a whole evaluation (E, F, B). The
ratios are LAMMPS's Kspace time over our k-space time, rank for thread; for
the mesh also ours at order 7 on LAMMPS's mesh ("pme7": the same sum).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
TESTS = os.path.join(HERE, os.pardir, "tests")
sys.path.insert(0, HERE)
sys.path.insert(0, TESTS)

from machine import best_time, describe  # noqa: E402


def ours(n, method, rc, accuracy):
    """Our timings (s) in this process: k-space part, a field, an evaluation."""
    from ase_spin import Dipolar, Hamiltonian, Want, get_spins
    from ase_spin.scenes import fcc_cobalt

    atoms = fcc_cobalt(n)
    s = get_spins(atoms)
    N = len(atoms)
    mu = np.full(N, 1.72)
    # "pme7": LAMMPS's order 7, on the very mesh its deck gets
    term = (Dipolar(rc, "pme", accuracy=accuracy, order=7) if method == "pme7"
            else Dipolar(rc, method, accuracy=accuracy))
    ev = Hamiltonian([term]).bind(atoms.numbers, atoms.cell.array, atoms.pbc, mu)
    q = atoms.positions

    def best(f, reps=3):
        return best_time(f, N, reps)

    op = ev.spin_operators(q, half=True)[0]
    m = mu[:, None] * s

    def kspace():
        H, F = np.zeros_like(m), np.zeros_like(m)
        op.recip.add(m, H, F, True, True, False)

    B = np.zeros_like(s)
    return {"kspace": best(kspace), "field": best(lambda: op.field(s, B)),
            "evaluate": best(lambda: ev.evaluate(q, s, Want(energy=True, forces=True,
                                                             magnetic_forces=True)), 2),
            "mesh": term.mesh_size(atoms.cell.array) if term.method == "pme" else None,
            "order": term.spline_order if term.method == "pme" else None}


def lammps_deck(folder, n, method, rc, accuracy, steps):
    """write_lammps's deck of the term, its output cut to one thermo line; the
    kspace lines."""
    from ase import units

    from ase_spin import DIPOLAR_LAMMPS, Dipolar, write_lammps
    from ase_spin.scenes import fcc_cobalt

    atoms = fcc_cobalt(n, temperature_K=0.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # order 8 or 10 exported as 7 (the warning says so)
        files = write_lammps(folder, atoms, hamiltonian=[Dipolar(rc, method, accuracy=accuracy,
                                                                 prefactor=DIPOLAR_LAMMPS)],
                             timestep=0.1 * units.fs, lattice="frozen", steps=steps,
                             dump_interval=steps, thermo_interval=steps)
    # no integrator: each step computes the pair and k-space parts once, the
    # atoms and spins left where they are (fix nve/spin's sectors would ask
    # for subdomains of twice the cutoff on 2 ranks)
    lines = [line for line in files.input.read_text().splitlines()
             if not line.startswith(("dump", "fix energies", "fix integrate"))]
    files.input.write_text("\n".join(lines) + "\n")
    return [line for line in lines if line.startswith("kspace_modify")]


def lammps_run(folder, ranks, steps):
    """(Kspace s a step, Pair s a step, loop s a step) from the log's timer breakdown."""
    from lammps_peer import DECK_SCRIPT, mpiexec_path

    env = dict(os.environ, PYTHONPATH=os.pathsep.join([TESTS, os.environ.get("PYTHONPATH", "")]),
               OMP_NUM_THREADS="1")
    launch = [mpiexec_path(), "-n", str(ranks)] if ranks > 1 else []
    done = subprocess.run([*launch, sys.executable, "-c", DECK_SCRIPT], cwd=folder, env=env,
                          capture_output=True, text=True, timeout=3600)
    log = (Path(folder) / "log.lammps").read_text() if (Path(folder) / "log.lammps").exists() else ""
    if done.returncode:
        raise RuntimeError(f"LAMMPS failed: {done.stderr[-1500:]}\n{log[-1500:]}")
    loop = float(re.search(r"Loop time of ([0-9.eE+-]+) on", log).group(1))

    def section(name):
        m = re.search(rf"^{name}\s*\|\s*\S+\s*\|\s*(\S+)", log, re.M)
        return float(m.group(1)) if m else float("nan")

    return section("Kspace") / steps, section("Pair") / steps, loop / steps


def child(args):
    os.environ.setdefault("NUMBA_NUM_THREADS", "1")
    print(json.dumps(ours(int(args.child[0]), args.child[1], args.rc, args.accuracy)))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--pme-sizes", type=int, nargs="+", default=[6, 10, 16])
    parser.add_argument("--ewald-sizes", type=int, nargs="+", default=[4, 6])
    parser.add_argument("--rc", type=float, default=6.0)
    parser.add_argument("--accuracy", type=float, default=1e-4)
    parser.add_argument("--steps", type=int, default=10)
    parser.add_argument("--child", nargs=2)
    args = parser.parse_args()
    if args.child:
        child(args)
        return

    print(describe())
    print(f"# load: {os.getloadavg()[0]:.2f} (1 min)")
    print(f"rc = {args.rc} Å, accuracy = {args.accuracy:g}; times in ms; ours: k-space E+F+B "
          "(kspace), a field (real + k), an evaluation (eval); LAMMPS: Kspace, Pair and the "
          "step a step")
    print(f"{'N':>6} {'method':>6} {'threads/ranks':>13} {'ours kspace':>11} {'field':>8} "
          f"{'eval':>8} {'LAMMPS Kspace':>13} {'Pair':>8} {'step':>8} {'LAMMPS/ours':>11}")
    with tempfile.TemporaryDirectory() as tmp:
        for method, sizes in (("pme", args.pme_sizes), ("ewald", args.ewald_sizes)):
            for n in sizes:
                folder = Path(tmp) / f"{method}_{n}"
                kspace = lammps_deck(folder, n, method, args.rc, args.accuracy, args.steps)
                for k in (1, 2):
                    mine = {}
                    for variant in ((method, "pme7") if method == "pme" else (method,)):
                        env = dict(os.environ, NUMBA_NUM_THREADS=str(k))
                        out = subprocess.run([sys.executable, __file__, "--child", str(n),
                                              variant, "--rc", str(args.rc), "--accuracy",
                                              str(args.accuracy)], env=env, capture_output=True,
                                             text=True, check=False)
                        if out.returncode:
                            raise RuntimeError(f"{variant} n={n}: ours failed\n"
                                               f"{out.stderr[-2000:]}")
                        mine[variant] = json.loads(out.stdout.strip().splitlines()[-1])
                    ks, pair, step = lammps_run(folder, k, args.steps)
                    for variant, r in mine.items():
                        if k == 1:
                            grid = (f" (ours: mesh {'x'.join(map(str, r['mesh']))} order "
                                    f"{r['order']})" if r["mesh"] else "")
                            print(f"# {4 * n**3} atoms, {variant}: LAMMPS {' '.join(kspace)}{grid}")
                        print(f"{4 * n**3:>6} {variant:>6} {k:>13} {1e3 * r['kspace']:>11.2f} "
                              f"{1e3 * r['field']:>8.2f} {1e3 * r['evaluate']:>8.2f} "
                              f"{1e3 * ks:>13.2f} {1e3 * pair:>8.2f} {1e3 * step:>8.2f} "
                              f"{ks / r['kspace']:>11.2f}", flush=True)
    print(f"# load: {os.getloadavg()[0]:.2f} (1 min)")


if __name__ == "__main__":
    main()
