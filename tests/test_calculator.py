import numpy as np
import pytest
from ase import Atoms
from ase.build import bulk
from ase.calculators.calculator import PropertyNotImplementedError
from ase.calculators.lj import LennardJones as AseLJ

import ase_spin
from ase_spin import (BetheSlater, Cubic, Exchange, Hamiltonian, LennardJones,
                      SpinLatticeCalculator, Want, get_spins, set_spins)

from conftest import CO_BS, CO_LJ, random_spins, structures
from reference import reference

STRUCTURES = structures()
MODES = ["plain", "shift", "smooth"]
COUPLINGS = {
    "bethe_slater": (BetheSlater(*CO_BS), 4.0),
    "cubic": (Cubic(0.3, 4.2), None),
}


def make_terms(mode, coupling, offset=False):
    c, rc = COUPLINGS[coupling]
    return [LennardJones(**CO_LJ, cutoff=mode), Exchange(c, rc=rc, offset=offset)]


def energy_at(evaluator, positions, spins):
    return evaluator.evaluate(positions, spins, Want(energy=True)).energy


def fd_forces(evaluator, positions, spins, h=1e-5):
    F = np.zeros_like(positions)
    for a in range(len(positions)):
        for x in range(3):
            p = positions.copy()
            p[a, x] += h
            ep = energy_at(evaluator, p, spins)
            p[a, x] -= 2 * h
            em = energy_at(evaluator, p, spins)
            F[a, x] = -(ep - em) / (2 * h)
    return F


def fd_magnetic_forces(evaluator, positions, spins, h=1e-5):
    """−∂E/∂s_i with s treated as a free vector in R³ (the definition of B)."""
    B = np.zeros_like(spins)
    for a in range(len(spins)):
        for x in range(3):
            s = spins.copy()
            s[a, x] += h
            ep = energy_at(evaluator, positions, s)
            s[a, x] -= 2 * h
            em = energy_at(evaluator, positions, s)
            B[a, x] = -(ep - em) / (2 * h)
    return B


def fd_stress(atoms, h=1e-6):
    """σ_ab = (1/V) ∂E/∂ε_ab for a symmetric strain, Voigt order."""
    cell0 = atoms.cell.array.copy()
    pos0 = atoms.positions.copy()
    V = atoms.get_volume()
    out = np.zeros((3, 3))
    for a in range(3):
        for b in range(3):
            es = []
            for sign in (1, -1):
                eps = np.zeros((3, 3))
                eps[a, b] += 0.5 * sign * h
                eps[b, a] += 0.5 * sign * h
                m = np.eye(3) + eps
                atoms.set_cell(cell0 @ m, scale_atoms=False)
                atoms.positions = pos0 @ m
                es.append(atoms.get_potential_energy())
            out[a, b] = (es[0] - es[1]) / (2 * h) / V
    atoms.set_cell(cell0)
    atoms.positions = pos0
    return out[[0, 1, 2, 1, 0, 0], [0, 1, 2, 2, 2, 1]]


def evaluator_for(atoms, terms):
    spins = get_spins(atoms)
    ev = Hamiltonian(terms).bind(atoms.numbers, atoms.cell.array, atoms.pbc,
                                 np.linalg.norm(spins, axis=1) > 0)
    return ev, spins


@pytest.mark.parametrize("coupling", list(COUPLINGS))
@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("name", list(STRUCTURES))
def test_forces_and_magnetic_forces_match_finite_differences(name, mode, coupling):
    atoms = STRUCTURES[name].copy()
    ev, spins = evaluator_for(atoms, make_terms(mode, coupling, offset=(mode == "shift")))
    res = ev.evaluate(atoms.positions, spins, Want(energy=True, forces=True,
                                                   magnetic_forces=True))
    F = fd_forces(ev, atoms.positions, spins)
    B = fd_magnetic_forces(ev, atoms.positions, spins)
    scale = max(1.0, np.abs(res.forces).max())
    assert np.abs(res.forces - F).max() < 1e-7 * scale
    assert np.abs(res.magnetic_forces - B).max() < 1e-9
    assert np.abs(res.magnetic_forces).max() > 0.01  # the check is not vacuous
    if atoms.pbc.any():
        assert np.abs(res.forces.sum(axis=0)).max() < 1e-11 * scale * len(atoms)


@pytest.mark.parametrize("coupling", list(COUPLINGS))
@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("name", ["fcc", "bcc", "hcp", "triclinic", "tiny", "tiny2"])
def test_stress_matches_finite_differences(name, mode, coupling):
    atoms = STRUCTURES[name].copy()
    atoms.calc = SpinLatticeCalculator(make_terms(mode, coupling))
    stress = atoms.get_stress()
    ref = fd_stress(atoms)
    assert np.abs(stress - ref).max() < 1e-6 * max(1.0, np.abs(stress).max())
    assert np.abs(stress).max() > 1e-4


@pytest.mark.parametrize("coupling", list(COUPLINGS))
@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("name", list(STRUCTURES))
def test_kernels_match_numpy_reference(name, mode, coupling):
    atoms = STRUCTURES[name].copy()
    offset = mode == "plain"
    c, rc = COUPLINGS[coupling]
    atoms.calc = SpinLatticeCalculator(make_terms(mode, coupling, offset))
    spins = get_spins(atoms)
    E, F, B, W = reference(atoms, (CO_LJ["epsilon"], CO_LJ["sigma"], CO_LJ["rc"], mode),
                           (c.values, rc or c.rc, offset), spins)
    assert atoms.get_potential_energy() == pytest.approx(E, rel=1e-12, abs=1e-12)
    assert np.abs(atoms.get_forces() - F).max() < 1e-11
    assert np.abs(atoms.calc.get_magnetic_forces(atoms) - B).max() < 1e-12
    terms = atoms.calc.results["energy_terms"]
    assert terms["lennard_jones"] + terms["exchange"] == pytest.approx(E, rel=1e-13, abs=1e-13)
    if atoms.cell.rank == 3:
        W6 = W[[0, 1, 2, 1, 0, 0], [0, 1, 2, 2, 2, 1]]
        assert np.abs(atoms.get_stress() * atoms.get_volume() - W6).max() < 1e-11


def test_energies_sum_to_energy():
    atoms = STRUCTURES["hcp"].copy()
    atoms.calc = SpinLatticeCalculator(make_terms("shift", "bethe_slater", offset=True))
    assert atoms.get_potential_energies().sum() == pytest.approx(
        atoms.get_potential_energy(), rel=1e-13)


@pytest.mark.parametrize("mode", ["shift", "smooth"])
@pytest.mark.parametrize("name", ["fcc", "triclinic", "tiny", "open"])
def test_lj_alone_agrees_with_ase(name, mode):
    atoms = STRUCTURES[name].copy()
    atoms.calc = SpinLatticeCalculator([LennardJones(**CO_LJ, cutoff=mode)])
    mine = (atoms.get_potential_energy(), atoms.get_forces(), atoms.get_potential_energies())
    mine_stress = atoms.get_stress() if atoms.cell.rank == 3 else None
    ase_calc = AseLJ(epsilon=CO_LJ["epsilon"], sigma=CO_LJ["sigma"], rc=CO_LJ["rc"],
                     smooth=(mode == "smooth"))
    atoms.calc = ase_calc
    assert abs(mine[0] - atoms.get_potential_energy()) < 1e-10
    assert np.abs(mine[1] - atoms.get_forces()).max() < 1e-10
    assert np.abs(mine[2] - atoms.get_potential_energies()).max() < 1e-10
    if mine_stress is not None:
        assert np.abs(mine_stress - atoms.get_stress()).max() < 1e-10


def test_invariant_under_translation_and_global_spin_rotation(rng):
    from scipy.spatial.transform import Rotation

    atoms = STRUCTURES["triclinic"].copy()
    atoms.calc = SpinLatticeCalculator(make_terms("smooth", "bethe_slater"))
    e0, f0 = atoms.get_potential_energy(), atoms.get_forces()
    b0 = atoms.calc.get_magnetic_forces(atoms)
    atoms.translate([0.37, -1.3, 2.2])
    assert atoms.get_potential_energy() == pytest.approx(e0, abs=1e-12)
    assert np.abs(atoms.get_forces() - f0).max() < 1e-12
    R = Rotation.random(random_state=3).as_matrix()
    set_spins(atoms, get_spins(atoms) @ R.T)
    assert atoms.get_potential_energy() == pytest.approx(e0, abs=1e-12)
    assert np.abs(atoms.get_forces() - f0).max() < 1e-12
    # B rotates with the spins
    assert np.abs(atoms.calc.get_magnetic_forces(atoms) - b0 @ R.T).max() < 1e-12


def test_published_exchange_numbers():
    J = BetheSlater(*CO_BS)
    assert J(2.503158) == pytest.approx(0.0295991, abs=5e-8)
    assert J(3.54) == pytest.approx(0.0034655, abs=5e-8)
    assert J(4.0) == pytest.approx(0.00091959, abs=5e-9)
    atoms = bulk("Co", "fcc", a=3.54, cubic=True).repeat(3)
    set_spins(atoms, [0, 0, 1])
    atoms.calc = SpinLatticeCalculator([Exchange(J, rc=4.0)])
    assert atoms.get_potential_energy() / len(atoms) == pytest.approx(-0.1879909, abs=5e-8)
    # offset: a ferromagnet has zero exchange energy and zero exchange stress
    atoms.calc = SpinLatticeCalculator([Exchange(J, rc=4.0, offset=True)])
    assert abs(atoms.get_potential_energy()) < 1e-12
    assert np.abs(atoms.get_stress()).max() < 1e-14


def test_derivative_of_couplings_matches_finite_difference():
    r = np.linspace(1.5, 4.5, 31)
    for c in [BetheSlater(*CO_BS), Cubic(-10.0, 1.5 * 3)]:
        J, dJ = c.values(r)
        h = 1e-6
        fd = (c(r + h) - c(r - h)) / (2 * h)
        assert np.abs(dJ - fd).max() < 1e-8


def test_user_coupling_plugs_in():
    class Yukawa(ase_spin.Coupling):
        rc = 4.0

        def values(self, r):
            J = 0.2 * np.exp(-r) / r
            return J, -J * (1 + 1 / r)

    atoms = STRUCTURES["hcp"].copy()
    ev, spins = evaluator_for(atoms, [LennardJones(**CO_LJ, cutoff="shift"),
                                      Exchange(Yukawa())])
    res = ev.evaluate(atoms.positions, spins, Want(energy=True, forces=True,
                                                   magnetic_forces=True, virial=True))
    E, F, B, W = reference(atoms, (0.4, 2.2742, 4.7, "shift"), (Yukawa().values, 4.0, False),
                           spins)
    assert res.energy == pytest.approx(E, rel=1e-12)
    assert np.abs(res.forces - F).max() < 1e-11
    assert np.abs(res.magnetic_forces - B).max() < 1e-12
    assert np.abs(res.forces - fd_forces(ev, atoms.positions, spins)).max() < 1e-7


def test_alloy_parameters_by_species_pair(rng):
    atoms = bulk("Fe", "bcc", a=2.87, cubic=True).repeat(2)
    atoms.symbols[::3] = "Co"
    atoms.rattle(0.05, seed=2)
    set_spins(atoms, random_spins(len(atoms), rng))
    lj = LennardJones(epsilon={("Fe", "Fe"): 0.4, "Co-Fe": 0.3, ("Co", "Co"): 0.5},
                      sigma={("Fe", "Fe"): 2.2, ("Fe", "Co"): 2.25, ("Co", "Co"): 2.3},
                      rc=4.5, cutoff="shift")
    ex = Exchange({("Fe", "Fe"): BetheSlater(*CO_BS), ("Fe", "Co"): Cubic(0.05, 3.5),
                   ("Co", "Co"): None}, rc=4.0)
    ev, spins = evaluator_for(atoms, [lj, ex])
    res = ev.evaluate(atoms.positions, spins, Want(energy=True, forces=True,
                                                   magnetic_forces=True))
    assert np.abs(res.forces - fd_forces(ev, atoms.positions, spins)).max() < 1e-7
    assert np.abs(res.magnetic_forces - fd_magnetic_forces(ev, atoms.positions, spins)).max() < 1e-9
    co = np.flatnonzero(atoms.symbols == "Co")
    assert np.abs(res.magnetic_forces[co]).max() > 0  # Co-Fe pairs do couple
    with pytest.raises(ValueError, match="pair Co-Co"):
        Hamiltonian([LennardJones(epsilon={("Fe", "Fe"): 0.4}, sigma=2.2, rc=4.5)]).bind(
            atoms.numbers, atoms.cell.array, atoms.pbc, np.ones(len(atoms), bool))


def test_energy_forces_and_magnetic_forces_come_from_one_pass():
    """Asking for any of energy, forces and magnetic forces computes all three
    (one pass, as ASE's calculators do): the next two questions cost nothing.
    Per-atom energies and stress only when asked for."""
    atoms = STRUCTURES["fcc"].copy()
    calc = SpinLatticeCalculator(make_terms("shift", "bethe_slater"))
    atoms.calc = calc
    passes = []
    evaluate = calc.bound_evaluator(atoms)[0].evaluate
    calc.bound_evaluator(atoms)[0].evaluate = lambda *a: passes.append(a[2]) or evaluate(*a)
    atoms.get_forces()
    assert {"energy", "free_energy", "energy_terms", "forces",
            "magnetic_forces"} <= set(calc.results)
    assert "stress" not in calc.results and "energies" not in calc.results
    calc.get_magnetic_forces(atoms)
    atoms.get_potential_energy()
    assert len(passes) == 1
    atoms.get_stress()
    assert len(passes) == 2 and passes[1].virial and "stress" in calc.results


def test_non_magnetic_atoms_take_no_part(rng):
    atoms = STRUCTURES["fcc"].copy()
    spins = random_spins(len(atoms), rng)
    spins[::2] = 0.0
    set_spins(atoms, spins)
    atoms.calc = SpinLatticeCalculator(make_terms("shift", "bethe_slater"))
    B = atoms.calc.get_magnetic_forces(atoms)
    assert np.all(B[::2] == 0.0) and np.abs(B[1::2]).max() > 0
    mag = atoms[1::2]
    # exchange energy only from pairs of magnetic atoms
    Eref = reference(atoms, None, (BetheSlater(*CO_BS).values, 4.0, False), get_spins(atoms))[0]
    atoms.get_potential_energy()
    assert atoms.calc.results["energy_terms"]["exchange"] == pytest.approx(Eref, rel=1e-12)
    assert len(mag) == len(atoms) // 2


def test_empty_one_atom_and_non_magnetic_systems():
    calc = SpinLatticeCalculator(make_terms("shift", "bethe_slater"))
    empty = Atoms(cell=[5, 5, 5], pbc=True)
    empty.calc = calc
    assert empty.get_potential_energy() == 0.0
    assert empty.get_forces().shape == (0, 3)
    assert empty.get_stress().shape == (6,)
    one = Atoms("Co", positions=[[0, 0, 0]])
    set_spins(one, [1, 0, 0])
    one.calc = SpinLatticeCalculator(make_terms("shift", "bethe_slater"))
    assert one.get_potential_energy() == 0.0
    assert np.all(one.calc.get_magnetic_forces(one) == 0.0)
    nonmag = bulk("Co", "fcc", a=3.54, cubic=True).repeat(2)
    nonmag.rattle(0.05, seed=1)
    nonmag.calc = SpinLatticeCalculator(make_terms("shift", "bethe_slater"))
    e = nonmag.get_potential_energy()
    assert nonmag.calc.results["energy_terms"]["exchange"] == 0.0
    assert np.all(nonmag.calc.get_magnetic_forces(nonmag) == 0.0)
    lj_only = nonmag.copy()
    lj_only.calc = SpinLatticeCalculator([LennardJones(**CO_LJ, cutoff="shift")])
    assert lj_only.get_potential_energy() == pytest.approx(e, rel=1e-14)


def test_magmoms_property_and_trajectory_roundtrip(tmp_path):
    from ase.io import Trajectory, read

    atoms = STRUCTURES["fcc"].copy()
    atoms.calc = SpinLatticeCalculator(make_terms("shift", "bethe_slater"))
    m = atoms.get_magnetic_moments()
    assert m.shape == (len(atoms), 3)
    assert np.allclose(m, atoms.get_initial_magnetic_moments())
    atoms.get_potential_energy()
    with Trajectory(tmp_path / "t.traj", "w") as traj:
        traj.write(atoms)
    back = read(tmp_path / "t.traj")
    assert np.array_equal(back.get_initial_magnetic_moments(), atoms.get_initial_magnetic_moments())
    assert np.array_equal(get_spins(back), get_spins(atoms))


def test_stress_needs_a_3d_cell():
    atoms = STRUCTURES["open"].copy()
    atoms.calc = SpinLatticeCalculator(make_terms("shift", "bethe_slater"))
    with pytest.raises(PropertyNotImplementedError):
        atoms.get_stress()


def test_overlapping_atoms_raise_and_leave_atoms_alone():
    atoms = bulk("Co", "fcc", a=3.54, cubic=True)
    set_spins(atoms, [0, 0, 1])
    atoms.positions[1] = atoms.positions[0]
    before = atoms.positions.copy()
    atoms.calc = SpinLatticeCalculator(make_terms("shift", "bethe_slater"))
    with pytest.raises(ase_spin.AtomsTooCloseError, match="atoms 0 and 1|atoms 1 and 0"):
        atoms.get_forces()
    assert np.array_equal(atoms.positions, before)


def test_bad_spins_raise():
    atoms = bulk("Co", "fcc", a=3.54, cubic=True)
    atoms.calc = SpinLatticeCalculator(make_terms("shift", "bethe_slater"))
    atoms.set_initial_magnetic_moments([1.0, 0.0, 2.0, 0.0])
    with pytest.raises(ValueError, match="atoms 0, 2 carry collinear"):
        atoms.get_potential_energy()
    m = np.zeros((4, 3))
    m[:, 2] = 1.0
    m[3, 0] = np.nan
    atoms.set_array("initial_magmoms", None)
    atoms.set_initial_magnetic_moments(m)
    with pytest.raises(ValueError, match="not finite for atom 3"):
        atoms.get_potential_energy()


def test_bad_parameters_raise():
    with pytest.raises(ValueError, match="cutoff"):
        LennardJones(1, 1, 3, cutoff="soft")
    with pytest.raises(ValueError, match="needs rc"):
        Exchange(BetheSlater(*CO_BS))
    with pytest.raises(ValueError):
        Cubic(1.0, -1.0)
    with pytest.raises(TypeError):
        Hamiltonian([object()])


def test_calculator_follows_changes_of_cell_spins_and_species(rng):
    atoms = STRUCTURES["fcc"].copy()
    calc = SpinLatticeCalculator(make_terms("shift", "bethe_slater"))
    atoms.calc = calc
    atoms.get_potential_energy()
    for change in ("cell", "spins", "species", "magnetic"):
        if change == "cell":
            atoms.set_cell(atoms.cell * 1.01, scale_atoms=True)
        elif change == "spins":
            set_spins(atoms, random_spins(len(atoms), rng))
        elif change == "species":
            atoms.symbols[0] = "Fe"
        else:
            s = get_spins(atoms)
            s[3] = 0.0
            set_spins(atoms, s)
        e = atoms.get_potential_energy()
        fresh = atoms.copy()
        fresh.calc = SpinLatticeCalculator(make_terms("shift", "bethe_slater"))
        assert e == pytest.approx(fresh.get_potential_energy(), rel=1e-14), change


def test_system_changes_are_ases():
    """The calculator's own comparison of the atoms (exact equality first, then
    ASE's tolerance) gives the list ASE's compare_atoms gives, for changes
    below, at and above the tolerance of each property ASE watches, arrays
    present in one only, non-finite values and ignored properties."""
    from ase.calculators.calculator import compare_atoms

    from ase_spin.calculator import _system_changes

    rng = np.random.default_rng(0)
    base = bulk("Co", "fcc", a=3.54, cubic=True).repeat(2)
    base.set_initial_magnetic_moments(rng.normal(size=(len(base), 3)))

    def changed(k, size):
        b = base.copy()
        if k == 0:
            b.positions[3, 1] += size
        elif k == 1:
            b.cell[0, 0] += size
        elif k == 2:
            b.pbc = [True, False, True]
        elif k == 3:
            b.set_initial_magnetic_moments(None)
        elif k == 4:
            b.set_initial_charges(np.full(len(b), size))
        elif k == 5:
            b.numbers[2] = 26
        elif k == 6:
            b.positions[0, 0] = np.nan
        elif k == 7:
            b.set_momenta(np.ones((len(b), 3)))  # not watched
        elif k == 8:
            b = b[:-1]
        elif k == 9:
            b.arrays["initial_magmoms"][1, 2] += size
        return b

    seen = set()
    for k in range(10):
        for size in (0.0, 1e-16, 1e-15, 2e-15, 1e-3):
            b = changed(k, size)
            for ignored in (set(), {"initial_magmoms"}, {"positions", "cell"}):
                expected = compare_atoms(base, b, 1e-15, ignored)
                assert sorted(_system_changes(base, b, 1e-15, ignored)) == sorted(expected)
                seen.add(tuple(sorted(expected)))
    assert _system_changes(None, base, 1e-15, set()) == compare_atoms(None, base)
    assert len(seen) >= 8  # the cases above do change what they should


def test_results_follow_term_parameters():
    """Assigning a term's parameter, or a coupling's inside it, is seen by the
    next property call (the Hamiltonian's fingerprint is kept between
    assignments only): the energy of a fresh calculator each time."""
    atoms = bulk("Co", "fcc", a=3.54, cubic=True).repeat(2)
    atoms.rattle(0.05, seed=1)
    ase_spin.set_spins(atoms, random_spins(len(atoms), np.random.default_rng(2)), 1.7)
    atoms.calc = SpinLatticeCalculator(make_terms("shift", "bethe_slater"))

    def fresh():
        a = atoms.copy()
        a.calc = SpinLatticeCalculator(list(atoms.calc.hamiltonian.terms))
        return a.get_potential_energy()

    energies = [atoms.get_potential_energy()]
    atoms.calc.hamiltonian.terms[0].epsilon = 0.5
    energies.append(atoms.get_potential_energy())
    assert energies[1] == fresh()
    atoms.calc.hamiltonian.terms[1].coupling.J1 = 0.06
    energies.append(atoms.get_potential_energy())
    assert energies[2] == fresh()
    assert len(set(energies)) == 3
