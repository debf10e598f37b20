"""The contract every Hamiltonian term keeps, checked term by term.

A new term gets every check by being added to TERMS: forces, magnetic forces
and stress are the derivatives of its energy (finite differences); the prepared
operator (cached geometry, then magnetic forces for any spins) gives what a
direct evaluation gives; the lattice and spin parts add up to the whole;
energy is invariant under translation, and under a global rotation of
positions, cell and spins where the term is isotropic.
"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ase_spin import (BetheSlater, Cubic, Exchange, Hamiltonian, LennardJones,
                      SpinLatticeCalculator, Want)

from conftest import CO_BS, CO_LJ, random_spins, structures
from test_calculator import fd_forces, fd_magnetic_forces, fd_stress


class _UserCoupling:
    """A coupling the kernels cannot evaluate: goes through values(r)."""

    rc = 4.1

    def values(self, r):
        x = 1.0 - r / self.rc
        return 0.05 * x**2 * np.cos(r), 0.05 * (-2.0 * x / self.rc * np.cos(r)
                                               - x**2 * np.sin(r))


#: (id, term factory, isotropic in spin space)
TERMS = [
    ("lj-plain", lambda: LennardJones(**CO_LJ, cutoff="plain"), True),
    ("lj-shift", lambda: LennardJones(**CO_LJ, cutoff="shift"), True),
    ("lj-smooth", lambda: LennardJones(**CO_LJ, cutoff="smooth"), True),
    ("exchange-bethe-slater", lambda: Exchange(BetheSlater(*CO_BS), rc=4.0), True),
    ("exchange-offset", lambda: Exchange(BetheSlater(*CO_BS), rc=4.0, offset=True), True),
    ("exchange-cubic", lambda: Exchange(Cubic(0.3, 4.2)), True),
    ("exchange-user", lambda: Exchange(_UserCoupling()), True),
]
IDS = [t[0] for t in TERMS]
STRUCTURES = structures()
SCENES = ["fcc", "triclinic", "tiny2", "open"]
FD_SCENES = ["triclinic", "tiny2", "slab"]  # small: each costs 12 N evaluations


def bound(term, atoms):
    ham = Hamiltonian([term])
    magnetic = np.linalg.norm(atoms.get_initial_magnetic_moments(), axis=1) > 0
    return ham.bind(atoms.numbers, atoms.cell.array, atoms.pbc, magnetic)


def spins_of(atoms):
    m = atoms.get_initial_magnetic_moments()
    return m / np.linalg.norm(m, axis=1)[:, None]


@pytest.mark.parametrize("scene", FD_SCENES)
@pytest.mark.parametrize("make", [t[1] for t in TERMS], ids=IDS)
def test_derivatives(make, scene):
    atoms = STRUCTURES[scene]
    ev = bound(make(), atoms)
    q, s = atoms.positions, spins_of(atoms)
    res = ev.evaluate(q, s, Want(energy=True, forces=True, magnetic_forces=True))
    np.testing.assert_allclose(res.forces, fd_forces(ev, q, s), rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(res.magnetic_forces, fd_magnetic_forces(ev, q, s),
                               rtol=1e-6, atol=1e-8)
    if atoms.pbc.all():
        a = atoms.copy()
        a.calc = SpinLatticeCalculator([make()])
        np.testing.assert_allclose(a.get_stress(), fd_stress(a), rtol=1e-5, atol=1e-8)


@pytest.mark.parametrize("scene", SCENES)
@pytest.mark.parametrize("make", [t[1] for t in TERMS], ids=IDS)
def test_prepared_operator_and_parts_equal_the_whole(make, scene, rng):
    term = make()
    atoms = STRUCTURES[scene]
    ev = bound(term, atoms)
    q = atoms.positions
    everything = Want(energy=True, energies=True, forces=True, magnetic_forces=True,
                      virial=True)
    for s in (spins_of(atoms), random_spins(len(atoms), rng)):
        whole = ev.evaluate(q, s, everything)
        lattice = ev.lattice(q, Want(energy=True, energies=True, forces=True, virial=True))
        geoms = ev.spin_operators(q, virial=True)
        spin = ev.spin(geoms, s, everything)
        assert lattice.energy + spin.energy == pytest.approx(whole.energy, rel=1e-12, abs=1e-12)
        for part in ("forces", "energies", "virial"):
            np.testing.assert_allclose(getattr(lattice, part) + getattr(spin, part),
                                       getattr(whole, part), rtol=1e-11, atol=1e-12)
        np.testing.assert_allclose(spin.magnetic_forces, whole.magnetic_forces,
                                   rtol=1e-12, atol=1e-13)
        if not term.spin_dependent:
            assert spin.energy == 0.0 and not spin.magnetic_forces.any()
        # the half-list geometry the integrators keep gives the same
        half = ev.spin(ev.spin_operators(q, half=True), s, Want(magnetic_forces=True))
        np.testing.assert_allclose(half.magnetic_forces, whole.magnetic_forces,
                                   rtol=1e-12, atol=1e-13)


@pytest.mark.parametrize("make, isotropic", [(t[1], t[2]) for t in TERMS], ids=IDS)
def test_invariances(make, isotropic, rng):
    atoms = STRUCTURES["triclinic"]
    want = Want(energy=True, forces=True, magnetic_forces=True)
    s = spins_of(atoms)
    ref = bound(make(), atoms).evaluate(atoms.positions, s, want)
    moved = bound(make(), atoms).evaluate(atoms.positions + [0.37, -1.2, 2.9], s, want)
    assert moved.energy == pytest.approx(ref.energy, rel=1e-12, abs=1e-12)
    np.testing.assert_allclose(moved.forces, ref.forces, atol=1e-11)
    np.testing.assert_allclose(moved.magnetic_forces, ref.magnetic_forces, atol=1e-12)

    R = Rotation.random(random_state=4).as_matrix()
    rotated = atoms.copy()
    rotated.set_cell(atoms.cell.array @ R.T)
    rotated.positions = atoms.positions @ R.T
    if isotropic:
        s_rot = s @ R.T
        rot = bound(make(), rotated).evaluate(rotated.positions, s_rot, want)
        assert rot.energy == pytest.approx(ref.energy, rel=1e-11, abs=1e-12)
        np.testing.assert_allclose(rot.forces, ref.forces @ R.T, atol=1e-10)
        np.testing.assert_allclose(rot.magnetic_forces, ref.magnetic_forces @ R.T, atol=1e-11)
