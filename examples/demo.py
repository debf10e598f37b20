"""ase_spin in an ordinary ASE script: fcc Co with classical spins.

Builds the fcc Co scene of the LAMMPS SPIN comparison (Lennard-Jones + Bethe–Slater
exchange), puts spins in a 30° cone on the Atoms, evaluates energy, forces,
stress and magnetic forces through the ASE calculator, and writes a trajectory
that keeps the spins (open it with `ase gui demo.traj`).
"""

import numpy as np
from ase.build import bulk
from ase.io import Trajectory, read

import ase_spin
from ase_spin import BetheSlater, Exchange, LennardJones, SpinLatticeCalculator

rng = np.random.default_rng(0)
atoms = bulk("Co", "fcc", a=3.54, cubic=True).repeat(5)  # 500 atoms
atoms.rattle(0.03, seed=1)
cos_theta = rng.uniform(np.cos(np.radians(30.0)), 1.0, len(atoms))
phi = rng.uniform(0.0, 2.0 * np.pi, len(atoms))
sin_theta = np.sqrt(1.0 - cos_theta**2)
directions = np.column_stack([sin_theta * np.cos(phi), sin_theta * np.sin(phi), cos_theta])
ase_spin.set_spins(atoms, directions, magnitudes=1.72)  # μB, stored as initial_magmoms (N, 3)

atoms.calc = SpinLatticeCalculator([
    LennardJones(epsilon=0.4, sigma=2.2742, rc=4.7, cutoff="shift"),
    Exchange(BetheSlater(J1=0.0446928, J2=0.003496, J3=1.4885), rc=4.0),
])

energy = atoms.get_potential_energy()
print(f"atoms                 {len(atoms)}")
print(f"energy                {energy:.6f} eV")
for name, value in atoms.calc.results["energy_terms"].items():
    print(f"  {name:<19} {value:.6f} eV")
print(f"max |force|           {np.abs(atoms.get_forces()).max():.6f} eV/Å")
print(f"stress (Voigt)        {np.array2string(atoms.get_stress(), precision=5)} eV/Å³")
B = atoms.calc.get_magnetic_forces(atoms)
print(f"mean |B| = |−∂E/∂s|   {np.linalg.norm(B, axis=1).mean():.6f} eV")
m = ase_spin.get_spins(atoms).mean(axis=0)
print(f"mean spin             {np.array2string(m, precision=4)}  |M| = {np.linalg.norm(m):.4f}")

with Trajectory("demo.traj", "w") as traj:
    traj.write(atoms)
back = read("demo.traj")
assert np.array_equal(ase_spin.get_spins(back), ase_spin.get_spins(atoms))
print("wrote demo.traj (spins kept as initial_magmoms; view with `ase gui demo.traj`)")
