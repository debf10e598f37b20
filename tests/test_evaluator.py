"""The fast evaluation interface integrators use."""

import numpy as np
import pytest
from ase.build import bulk

from ase_spin import BetheSlater, Exchange, Hamiltonian, LennardJones, Want, set_spins

from conftest import CO_BS, CO_LJ, random_spins


@pytest.fixture
def system(rng):
    atoms = bulk("Co", "fcc", a=3.54, cubic=True).repeat(3)
    atoms.rattle(0.05, seed=4)
    spins = random_spins(len(atoms), rng)
    set_spins(atoms, spins)
    ham = Hamiltonian([LennardJones(**CO_LJ, cutoff="shift"),
                       Exchange(BetheSlater(*CO_BS), rc=4.0)], skin=0.4)
    ev = ham.bind(atoms.numbers, atoms.cell.array, atoms.pbc, np.ones(len(atoms), bool))
    return atoms, spins, ev


def test_lattice_plus_spin_parts_equal_full_evaluation(system):
    atoms, spins, ev = system
    full = ev.evaluate(atoms.positions, spins, Want(energy=True, forces=True,
                                                    magnetic_forces=True, virial=True))
    lat = ev.lattice(atoms.positions, Want(energy=True, forces=True, virial=True))
    geom = ev.spin_operators(atoms.positions, virial=True)
    sp = ev.spin(geom, spins, Want(energy=True, forces=True, magnetic_forces=True,
                                   virial=True))
    assert lat.energy + sp.energy == pytest.approx(full.energy, rel=1e-14)
    assert np.abs(lat.forces + sp.forces - full.forces).max() < 1e-13
    assert np.abs(sp.magnetic_forces - full.magnetic_forces).max() < 1e-14
    assert np.abs(lat.virial + sp.virial - full.virial).max() < 1e-12
    assert set(lat.energy_terms) == {"lennard_jones"}
    assert set(sp.energy_terms) == {"exchange"}


def test_cached_geometry_serves_new_spins(system, rng):
    atoms, spins, ev = system
    geom = ev.spin_operators(atoms.positions)
    for _ in range(3):
        s = random_spins(len(atoms), rng)
        fast = ev.spin(geom, s, Want(magnetic_forces=True, forces=True))
        full = ev.evaluate(atoms.positions, s, Want(forces=True, magnetic_forces=True))
        lat = ev.lattice(atoms.positions, Want(forces=True))
        assert np.abs(fast.magnetic_forces - full.magnetic_forces).max() < 1e-14
        assert np.abs(fast.forces + lat.forces - full.forces).max() < 1e-13


def test_geometry_out_arrays_are_reused_and_updated(system):
    atoms, spins, ev = system
    g1 = ev.spin_operators(atoms.positions)
    J1 = g1[0].J.copy()
    moved = atoms.positions + 0.01
    moved[0, 0] += 0.05
    g2 = ev.spin_operators(moved, out=g1)
    assert g2[0] is g1[0]
    fresh = ev.spin_operators(moved)
    assert np.array_equal(g2[0].J, fresh[0].J) and not np.array_equal(g2[0].J, J1)


def test_neighbour_list_is_kept_across_calls_within_the_skin(system):
    atoms, spins, ev = system
    ev.lattice(atoms.positions, Want(forces=True))
    builds = ev.neighbors.builds
    p = atoms.positions.copy()
    for step in range(5):
        p[7, 0] += 0.03
        ev.lattice(p, Want(forces=True))
    assert ev.neighbors.builds == builds
    p[7, 0] += 0.1  # now 0.25 > skin/2 = 0.2 from where the list was built
    ev.lattice(p, Want(forces=True))
    assert ev.neighbors.builds == builds + 1


def test_add_into_given_arrays(system):
    atoms, spins, ev = system
    F = np.ones((len(atoms), 3))
    B = np.ones((len(atoms), 3))
    geom = ev.spin_operators(atoms.positions)
    out = ev.spin(geom, spins, Want(forces=True, magnetic_forces=True),
                  magnetic_forces=B, forces=F)
    assert out.forces is F and out.magnetic_forces is B
    ref = ev.spin(geom, spins, Want(forces=True, magnetic_forces=True))
    assert np.abs(F - 1 - ref.forces).max() < 1e-14
    assert np.abs(B - 1 - ref.magnetic_forces).max() < 1e-14
