"""ase_spin in an ordinary ASE script: spin–lattice dynamics of fcc Co.

The fcc Co scene of the LAMMPS SPIN comparison (Lennard-Jones + Bethe–Slater
exchange, 500 atoms at 100 K, spins in a 30° cone), evaluated through the ASE
calculator, then integrated with the paper's collective symplectic method as an
ASE MolecularDynamics: a log line every 50 steps and a trajectory that keeps
positions, momenta and spins (open it with `ase gui demo.traj`).

    python examples/demo.py [--out demo.traj] [--steps 500]

writes demo.traj in the current folder (or the file --out names).
"""

import argparse
import time

import numpy as np
from ase import units
from ase.build import bulk
from ase.io import Trajectory, read

import ase_spin
from ase_spin import BetheSlater, CollectivePRK, Exchange, LennardJones, SpinLatticeCalculator

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--out", default="demo.traj",
                    help="the trajectory (default demo.traj here; overwritten)")
parser.add_argument("--steps", type=int, default=500,
                    help="steps of 0.1 fs: a multiple of 50 (a frame every 50), at least 100 "
                         "(the first 50 are timed apart, with the compilation); default 500")
args = parser.parse_args()
if args.steps < 100 or args.steps % 50:
    parser.error("--steps must be a multiple of 50, at least 100")

rng = np.random.default_rng(0)
atoms = bulk("Co", "fcc", a=3.54, cubic=True).repeat(5)  # 500 atoms
cos_theta = rng.uniform(np.cos(np.radians(30.0)), 1.0, len(atoms))
phi = rng.uniform(0.0, 2.0 * np.pi, len(atoms))
sin_theta = np.sqrt(1.0 - cos_theta**2)
directions = np.column_stack([sin_theta * np.cos(phi), sin_theta * np.sin(phi), cos_theta])
ase_spin.set_spins(atoms, directions, magnitudes=1.72)  # μB, stored as initial_magmoms (N, 3)
momenta = rng.normal(size=(len(atoms), 3)) * np.sqrt(atoms.get_masses()[:, None] * units.kB * 100)
atoms.set_momenta(momenta - momenta.mean(axis=0))  # 100 K, no drift

atoms.calc = SpinLatticeCalculator([
    LennardJones(epsilon=0.4, sigma=2.2742, rc=4.7, cutoff="shift"),
    Exchange(BetheSlater(J1=0.0446928, J2=0.003496, J3=1.4885), rc=4.0),
])

print(f"atoms                 {len(atoms)}")
print(f"energy                {atoms.get_potential_energy():.6f} eV")
for name, value in atoms.calc.results["energy_terms"].items():
    print(f"  {name:<19} {value:.6f} eV")
print(f"max |force|           {np.abs(atoms.get_forces()).max():.6f} eV/Å")
print(f"stress (Voigt)        {np.array2string(atoms.get_stress(), precision=5)} eV/Å³")
B = atoms.calc.get_magnetic_forces(atoms)
print(f"mean |B| = |−∂E/∂s|   {np.linalg.norm(B, axis=1).mean():.6f} eV")
print()

# Spin–lattice dynamics: 0.1 fs steps, LAMMPS's precession convention (the default).
# Integrators never overwrite a trajectory (FileExistsError; append_trajectory=True continues
# one): this demo opens its own output in write mode to start afresh each time it is run.
trajectory = Trajectory(args.out, "w", atoms)
dyn = CollectivePRK(atoms, timestep=0.1 * units.fs, trajectory=trajectory,
                    logfile="-", loginterval=50)
t0 = time.perf_counter()
dyn.run(50)  # the first call also compiles the kernels (cached on disk afterwards)
t1 = time.perf_counter()
rest = args.steps - 50
dyn.run(rest)
elapsed = time.perf_counter() - t1
print(f"\n{args.steps} steps ({args.steps * 0.1:g} fs): the first 50 in {t1 - t0:.2f} s (with "
      f"compilation), the next {rest} in {elapsed:.2f} s: "
      f"{elapsed / rest / len(atoms) * 1e6:.2f} µs per atom-step, "
      f"{dyn.mean_iterations:.1f} midpoint sweeps per step")

trajectory.close()
spins = ase_spin.get_spins(atoms)
print(f"spin lengths          max | |s| − 1 | = {np.abs(np.linalg.norm(spins, axis=1) - 1).max():.1e}")
back = read(args.out, index=-1)
assert np.array_equal(back.get_initial_magnetic_moments(), atoms.get_initial_magnetic_moments())
print(f"wrote {args.out} ({len(read(args.out, ':'))} frames with positions, momenta and "
      f"spins; view with `ase gui {args.out}`)")
