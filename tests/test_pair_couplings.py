"""Pair-resolved couplings (PairCouplings), bulk DMI, the Néel term in use,
and the readers of pair-resolved files (TB2J, the text pair format).

The Néel term and bulk DMI are also in tests/test_term_contract.py (their
derivatives, invariances, operators); PairCouplings needs its reference
structure, so its contract checks are here, on supercells of references."""

import json
import warnings

import numpy as np
import pytest
from ase import Atoms, units
from ase.build import bulk, make_supercell
from scipy.optimize import minimize_scalar
from scipy.spatial.transform import Rotation

import ase_spin
from ase_spin import (DMI, BetheSlater, CollectivePRK, Exchange, Hamiltonian, Langevin, Neel,
                      PairCouplings, SpinLatticeCalculator, SuzukiTrotter, Want, read_pairs,
                      read_tb2j, read_tb2j_pairs, relax_spins, write_lammps, write_pairs)
from ase_spin.terms.pair_couplings import coupling_matrices, pairs_within

from conftest import CO_BS, random_spins
from test_calculator import fd_forces, fd_magnetic_forces, fd_stress
from test_term_contract import _laplacian_on_spheres

EVERYTHING = Want(energy=True, energies=True, forces=True, magnetic_forces=True, virial=True)


def _bound(term, atoms):
    moments = np.linalg.norm(atoms.get_initial_magnetic_moments(), axis=1)
    return Hamiltonian([term]).bind(atoms.numbers, atoms.cell.array, atoms.pbc, moments)


def _two_site_reference():
    """A triclinic cell of two species (Fe, Co) with unequal sites."""
    cell = np.array([[2.6, 0.0, 0.0], [0.4, 2.8, 0.0], [0.3, -0.2, 3.0]])
    return Atoms("FeCo", cell=cell, scaled_positions=[[0, 0, 0], [0.45, 0.55, 0.5]], pbc=True)


def _full_couplings(reference, rc=3.6, seed=3, R=np.eye(3), **kw):
    """Every pair within rc with random J, D and symmetric traceless Γ (eV),
    all rotated by R (reference, D → R D, Γ → R Γ Rᵀ)."""
    i, j, Rv, r = pairs_within(reference, rc)
    rng = np.random.default_rng(seed)
    n = len(i)
    J = rng.uniform(-0.01, 0.03, n)
    D = rng.normal(scale=0.004, size=(n, 3)) @ R.T
    G = rng.normal(scale=0.002, size=(n, 3, 3))
    G = 0.5 * (G + np.swapaxes(G, 1, 2))
    G -= np.trace(G, axis1=1, axis2=2)[:, None, None] / 3.0 * np.eye(3)
    G = R @ G @ R.T
    ref = reference.copy()
    ref.set_cell(reference.cell.array @ R.T)
    ref.positions = reference.positions @ R.T
    return PairCouplings(ref, i, j, Rv, J, D, G, **kw), ref


def _spun(atoms, seed=5):
    atoms = atoms.copy()
    rng = np.random.default_rng(seed)
    ase_spin.set_spins(atoms, random_spins(len(atoms), rng), rng.uniform(0.8, 2.5, len(atoms)))
    return atoms


def _unit(atoms):
    m = atoms.get_initial_magnetic_moments()
    return m / np.linalg.norm(m, axis=1)[:, None]


def test_isotropic_pairs_reproduce_exchange_to_round_off():
    """J_ij = J(r⁰) per pair with shape=J: the same energy, forces, magnetic
    forces and virial as Exchange(J) on a rattled, sheared supercell."""
    ref = bulk("Co", "fcc", a=3.54)
    bs = BetheSlater(*CO_BS)
    i, j, R, r = pairs_within(ref, 4.0)
    term = PairCouplings(ref, i, j, R, bs(r), shape=bs, rc=4.0)
    sup = make_supercell(ref, [[2, 1, 0], [0, 3, 0], [0, 0, 3]])
    sup.set_cell(sup.cell.array @ (np.eye(3) + 0.01 * np.array([[1, 2, 0], [0, -1, 1], [0, 0, 1]])),
                 scale_atoms=True)
    sup.rattle(0.05, seed=1)
    sup = _spun(sup)
    s = _unit(sup)
    a = _bound(term, sup).evaluate(sup.positions, s, EVERYTHING)
    b = _bound(Exchange(bs, rc=4.0), sup).evaluate(sup.positions, s, EVERYTHING)
    assert abs(a.energy - b.energy) < 1e-13 * abs(b.energy)
    for part in ("forces", "magnetic_forces", "virial", "energies"):
        x, y = getattr(a, part), getattr(b, part)
        assert np.abs(x - y).max() < 1e-12 * np.abs(y).max(), part


@pytest.mark.parametrize("form", ["interfacial", "bulk"])
def test_dm_vectors_reproduce_the_dmi_term(form):
    """D_ij = D e⁰_ij × ẑ (interfacial) or D e⁰_ij (bulk) per pair: the energy
    and magnetic forces of DMI(form=...) on the unrelaxed supercell."""
    ref = bulk("Co", "fcc", a=3.54)
    i, j, R, r = pairs_within(ref, 3.0)
    e = (ref.positions[j] + R @ ref.cell.array - ref.positions[i]) / r[:, None]
    D = 0.003 * (np.cross(e, [0.0, 0.0, 1.0]) if form == "interfacial" else e)
    term = PairCouplings(ref, i, j, R, np.zeros(len(i)), D)
    dmi = (DMI(0.003, [0, 0, 1], rc=3.0) if form == "interfacial"
           else DMI(0.003, rc=3.0, form="bulk"))
    sup = _spun(ref.repeat((3, 2, 3)))
    s = _unit(sup)
    a = _bound(term, sup).evaluate(sup.positions, s, EVERYTHING)
    b = _bound(dmi, sup).evaluate(sup.positions, s, EVERYTHING)
    assert abs(a.energy - b.energy) < 1e-13 * np.abs(b.energies).sum()
    assert np.abs(a.magnetic_forces - b.magnetic_forces).max() < 1e-13 * np.abs(
        b.magnetic_forces).max()


SUPERCELLS = {"2x1x2": [[2, 0, 0], [0, 1, 0], [0, 0, 2]],
              "skew": [[1, 1, 0], [0, 1, 0], [0, 1, 2]],
              "reference": np.eye(3, dtype=int)}   # smaller than the range: own images


LAWS = {"fixed": {}, "decay": {"decay": 0.7}, "shape": {"shape": BetheSlater(0.02, 0.3, 1.9)}}


@pytest.mark.parametrize("cell, law", [("2x1x2", "fixed"), ("2x1x2", "decay"),
                                       ("2x1x2", "shape"), ("skew", "decay"),
                                       ("reference", "shape")])
def test_derivatives_operators_and_curvature(cell, law, rng):
    """Forces, magnetic forces and stress are the derivatives of the energy;
    the prepared operators (full and half lists) give the direct evaluation;
    self_curvature completes the Laplacian (pairs of an atom with its own
    image in the reference-sized cell)."""
    law = LAWS[law]
    term, ref = _full_couplings(_two_site_reference(), **law)
    atoms = make_supercell(ref, SUPERCELLS[cell])
    atoms.rattle(0.06, seed=2)
    atoms = _spun(atoms)
    ev = _bound(term, atoms)
    q, s = atoms.positions, _unit(atoms)
    res = ev.evaluate(q, s, EVERYTHING)
    np.testing.assert_allclose(res.forces, fd_forces(ev, q, s), rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(res.magnetic_forces, fd_magnetic_forces(ev, q, s), rtol=1e-6,
                               atol=1e-9)
    if not law:
        assert not res.forces.any() and not res.virial.any()
    a = atoms.copy()
    a.calc = SpinLatticeCalculator([term])
    np.testing.assert_allclose(a.get_stress(), fd_stress(a), rtol=1e-5, atol=1e-9)
    for spins in (s, random_spins(len(atoms), rng)):
        whole = ev.evaluate(q, spins, EVERYTHING)
        for half in (False, True):
            part = ev.spin(ev.spin_operators(q, virial=True, half=half), spins, EVERYTHING)
            assert part.energy == pytest.approx(whole.energy, rel=1e-12, abs=1e-14)
            for name in ("forces", "magnetic_forces", "virial", "energies"):
                np.testing.assert_allclose(getattr(part, name), getattr(whole, name),
                                           rtol=1e-11, atol=1e-14)
    if cell == "reference":
        B = res.magnetic_forces
        expected = _laplacian_on_spheres(ev, q, s)
        for half in (False, True):
            got = 2.0 * np.einsum("ij,ij->", s, B) - sum(
                op.self_curvature(s) for op in ev.spin_operators(q, half=half))
            assert got == pytest.approx(expected, rel=1e-5, abs=1e-8)


def test_invariances_and_atom_order():
    """Energy, forces and fields: unchanged by a translation and by shuffling
    the supercell's atoms (pairs are found by site identity); rotated with a
    rotation of the positions, cell, spins and the couplings' frame (D → R D,
    Γ → R Γ Rᵀ, the reference with them)."""
    want = Want(energy=True, forces=True, magnetic_forces=True)
    term, ref = _full_couplings(_two_site_reference(), decay=0.8)
    atoms = _spun(ref.repeat((2, 2, 1)))
    atoms.rattle(0.05, seed=4)
    s = _unit(atoms)
    base = _bound(term, atoms).evaluate(atoms.positions, s, want)
    moved = _bound(term, atoms).evaluate(atoms.positions + [0.4, -1.3, 2.2], s, want)
    assert moved.energy == pytest.approx(base.energy, rel=1e-12)
    np.testing.assert_allclose(moved.forces, base.forces, atol=1e-12)
    order = np.random.default_rng(0).permutation(len(atoms))
    shuffled = atoms[order]
    sh = _bound(term, shuffled).evaluate(shuffled.positions, s[order], want)
    assert sh.energy == pytest.approx(base.energy, rel=1e-12)
    np.testing.assert_allclose(sh.magnetic_forces, base.magnetic_forces[order], atol=1e-13)
    Rm = Rotation.random(random_state=4).as_matrix()
    rterm, rref = _full_couplings(_two_site_reference(), decay=0.8, R=Rm)
    rot = atoms.copy()
    rot.set_cell(atoms.cell.array @ Rm.T)
    rot.positions = atoms.positions @ Rm.T
    r = _bound(rterm, rot).evaluate(rot.positions, s @ Rm.T, want)
    assert r.energy == pytest.approx(base.energy, rel=1e-11)
    np.testing.assert_allclose(r.forces, base.forces @ Rm.T, atol=1e-11)
    np.testing.assert_allclose(r.magnetic_forces, base.magnetic_forces @ Rm.T, atol=1e-12)


def test_bad_input_is_refused_by_name():
    ref = _two_site_reference()
    i, j, R, r = pairs_within(ref, 3.6)
    J = np.full(len(i), 0.01)
    with pytest.raises(ValueError, match="given twice"):
        PairCouplings(ref, np.r_[i, j[:1]], np.r_[j, i[:1]], np.r_[R, -R[:1]], np.r_[J, 0.01])
    with pytest.raises(ValueError, match="not traceless"):
        PairCouplings(ref, i, j, R, J, Gamma=np.tile(np.eye(3), (len(i), 1, 1)) * 1e-3)
    with pytest.raises(ValueError, match="not sites"):
        PairCouplings(ref, i + 5, j, R, J)
    with pytest.raises(ValueError, match="with itself"):
        PairCouplings(ref, [0], [0], [[0, 0, 0]], [0.01])
    term = PairCouplings(ref, i, j, R, J)
    wrong = _spun(bulk("Fe", "bcc", a=3.9, cubic=True))
    with pytest.raises(ValueError, match="not a supercell"):
        wrong.calc = SpinLatticeCalculator([term])
        wrong.get_potential_energy()
    swapped = _spun(ref.repeat((2, 1, 1)))
    swapped.symbols = "CoFeFeCo"
    swapped.calc = SpinLatticeCalculator([term])
    with pytest.raises(ValueError, match="sits on reference site"):
        swapped.get_potential_energy()
    with pytest.raises(NotImplementedError, match="explicit list of pairs"):
        write_lammps("unused_dir", _spun(ref.repeat(2)), hamiltonian=Hamiltonian([term]),
                     timestep=0.1 * units.fs)


def _chain(n, a=2.5, pbc=False):
    atoms = Atoms(f"Fe{n}", positions=[[a * k, 0.0, 0.0] for k in range(n)],
                  cell=[a * n, 12.0, 12.0], pbc=pbc)
    return atoms


@pytest.mark.parametrize("route", ["dmi-bulk", "pairs"])
def test_bulk_dmi_chain_has_the_helix_pitch_arctan_d_over_j(route):
    """A chain with J and bulk D: the energy of trial helices (spins turning
    by θ per bond in the plane normal to the chain) is lowest at θ =
    arctan(D/J), and relaxing an open chain from a ferromagnet with a little
    noise turns every bond by that angle."""
    J, D = 0.01, 0.004
    if route == "dmi-bulk":
        terms = [Exchange(_Constant(J), rc=3.0), DMI(D, rc=3.0, form="bulk")]
    else:
        cell = Atoms("Fe", cell=[2.5, 12.0, 12.0], pbc=True)
        terms = [PairCouplings(cell, [0], [0], [[1, 0, 0]], [J], [[D, 0.0, 0.0]])]
    n = 24
    atoms = _chain(n, pbc=terms[0].__class__ is PairCouplings)
    ham = Hamiltonian(terms)
    ev = ham.bind(atoms.numbers, atoms.cell.array, atoms.pbc, np.ones(n))

    def energy(theta):
        k = np.arange(n)
        s = np.stack([np.zeros(n), np.cos(k * theta), np.sin(k * theta)], axis=1)
        return ev.evaluate(atoms.positions, s, Want(energy=True)).energy

    if atoms.pbc.all():   # a periodic chain takes commensurate helices: θ = 2π m/n
        thetas = 2 * np.pi * np.arange(n) / n
        best = thetas[np.argmin([energy(t) for t in thetas])]
        assert best == pytest.approx(2 * np.pi / n * round(np.arctan2(D, J) * n / (2 * np.pi)))
        return
    found = minimize_scalar(energy, bounds=(0.0, 1.5), method="bounded",
                            options={"xatol": 1e-10}).x
    assert found == pytest.approx(np.arctan2(D, J), abs=1e-7)


@pytest.mark.slow
def test_relaxed_bulk_dmi_chain_turns_by_arctan_d_over_j():
    """Relaxing an open chain with J and bulk D from a ferromagnet with a
    little noise turns every bond by arctan(D/J)."""
    J, D, n = 0.01, 0.004, 24
    terms = [Exchange(_Constant(J), rc=3.0), DMI(D, rc=3.0, form="bulk")]
    atoms = _chain(n)
    rng = np.random.default_rng(1)
    ase_spin.set_spins(atoms, [1.0, 0.0, 0.0] + 0.3 * rng.normal(size=(n, 3)))
    atoms.calc = SpinLatticeCalculator(terms)
    relax_spins(atoms, fmax=1e-8)
    s = ase_spin.get_spins(atoms)
    turn = np.arctan2(np.einsum("ij,j->i", np.cross(s[:-1], s[1:]), [1.0, 0.0, 0.0]),
                      np.einsum("ij,ij->i", s[:-1], s[1:]))
    np.testing.assert_allclose(turn, np.arctan2(D, J), atol=1e-5)


class _Constant:
    """J(r) = J (the term's rc cuts it off)."""

    rc = None

    def __init__(self, J):
        self.J = J

    def values(self, r):
        return np.full_like(r, self.J), np.zeros_like(r)


def _tb2j_text(atoms, rows, extra_lines=()):
    """An exchange.out in TB2J's layout (TB2J/io_exchange/io_txt.py): cell,
    atoms, and per listed pair its line, J_iso, DMI and J_ani (meV)."""
    labels = [f"{s}{k + 1}" for k, s in enumerate(atoms.get_chemical_symbols())]
    out = ["=" * 90, "Information:", "written by tests/test_pair_couplings.py", "",
           "=" * 90, "Cell (Angstrom):"]
    out += ["{:10.8f}  {:10.8f}  {:10.8f}".format(*c) for c in atoms.cell.array]
    out += ["", "=" * 90, "Atoms:  ", "(Note: charge and magmoms only count the wannier "
            "functions.)", "Atom_number  x  y  z  w_charge  M(x)  M(y)  M(z)"]
    for lab, p in zip(labels, atoms.positions):
        out.append("{:<12s} {:13.8f} {:13.8f} {:13.8f} {:9.4f} {:9.4f} {:9.4f} {:9.4f}".format(
            lab, *p, 8.0, 0.0, 0.0, 2.2))
    out += ["", "=" * 90, "Exchange: ", "    i     j          R         J_iso(meV)  vector  "
            "distance(A)"]
    for i, j, R, J, D, A in rows:
        vec = atoms.positions[j] + np.asarray(R) @ atoms.cell.array - atoms.positions[i]
        out.append("-" * 88)
        out.append("   {:5s} {:5s} ({:3d}, {:3d}, {:3d}) {:7.4f}   ({:6.3f}, {:6.3f}, {:6.3f}) "
                   "{:6.3f} ".format(labels[i], labels[j], *R, J, *vec, np.linalg.norm(vec)))
        out.append(f"J_iso: {J:7.4f} ")
        out.extend(extra_lines)
        out.append("[Testing!] DMI: ({:7.4f} {:7.4f} {:7.4f})".format(*D))
        out.append("[Testing!]J_ani:\n" + np.array_str(A, precision=3, suppress_small=True))
    out.append("=" * 90)
    return "\n".join(out) + "\n"


def test_tb2j_file_round_trips_every_pair(tmp_path):
    """A TB2J exchange.out with isotropic J, DMI and anisotropic exchange, both
    directions of each pair: read_tb2j_pairs keeps every pair, each at
    2·10⁻³ × TB2J's numbers (D_ji = −D_ij, J_ani^ji = J_ani^ijᵀ), to the
    file's printed precision; read_tb2j (per distance) reads it as before."""
    ref = _two_site_reference()
    i, j, R, r = pairs_within(ref, 4.2)
    rng = np.random.default_rng(11)
    n = len(i)
    J = np.round(rng.uniform(-5, 20, n), 4)
    D = np.round(rng.normal(scale=0.5, size=(n, 3)), 4)
    A = rng.normal(scale=0.2, size=(n, 3, 3))
    A = np.round(0.5 * (A + np.swapaxes(A, 1, 2)), 3)   # with a trace: it moves into J
    rows = []
    for k in range(n):
        rows.append((i[k], j[k], R[k].tolist(), J[k], D[k], A[k]))
        rows.append((j[k], i[k], (-R[k]).tolist(), J[k], -D[k], A[k].T))
    path = tmp_path / "exchange.out"
    path.write_text(_tb2j_text(ref, rows))
    with pytest.warns(UserWarning, match="J_ani has a trace"):
        term = read_tb2j_pairs(tmp_path, rc=4.3)
    assert len(term) == n
    key = {(a, b, tuple(c)): k for k, (a, b, c) in enumerate(zip(term.i, term.j, term.R))}
    trace = np.trace(A, axis1=1, axis2=2) / 3.0
    for k in range(n):
        q = key[(i[k], j[k], tuple(R[k]))]
        assert term.J[q] == pytest.approx(2e-3 * (J[k] + trace[k]), abs=1e-12)
        np.testing.assert_allclose(term.D[q], 2e-3 * D[k], atol=1e-12)
        np.testing.assert_allclose(term.Gamma[q], 2e-3 * (A[k] - trace[k] * np.eye(3)),
                                   atol=1e-12)
    assert len(read_tb2j(path)) == n
    # a round trip through the text format is exact
    write_pairs(tmp_path / "pairs.txt", term, unit="meV")
    back = read_pairs(tmp_path / "pairs.txt", ref, unit="meV", rc=4.3)
    for name in ("i", "j", "R"):
        np.testing.assert_array_equal(getattr(back, name), getattr(term, name))
    for name in ("J", "D", "Gamma"):
        np.testing.assert_allclose(getattr(back, name), getattr(term, name), rtol=1e-15,
                                   atol=1e-18)


def test_tb2j_what_cannot_be_mapped_is_said(tmp_path):
    ref = _two_site_reference()
    rows = [(0, 1, [0, 0, 0], 10.0, np.array([0.1, 0.0, 0.0]), np.zeros((3, 3))),
            (1, 0, [0, 0, 0], 10.0, np.array([0.1, 0.0, 0.0]), np.zeros((3, 3)))]
    path = tmp_path / "exchange.out"
    path.write_text(_tb2j_text(ref, rows, extra_lines=["dJ/dx: 0.123"]))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        read_tb2j_pairs(path)
    text = " ".join(str(w.message) for w in caught)
    assert "dJ/dx" in text and "differ" in text   # D_ji must be −D_ij: a slip in the file
    path.write_text(_tb2j_text(ref, rows[:1]))
    with pytest.warns(UserWarning, match="one direction only"):
        read_tb2j_pairs(path)


def test_pair_file_errors(tmp_path):
    ref = _two_site_reference()
    path = tmp_path / "p.txt"
    path.write_text("0 1 0 0 0 0.01 0.0\n")
    with pytest.raises(ValueError, match="line 1: expected 6"):
        read_pairs(path, ref)
    path.write_text("# comment\n0 2 0 0 0 0.01\n")
    with pytest.raises(ValueError, match="line 2: sites"):
        read_pairs(path, ref)
    path.write_text("0 1 0 0 0 0.01 0 0 0.001\n1 0 0 0 0 0.01 0 0 0.001\n")
    with pytest.warns(UserWarning, match="differ"):   # the reverse carries −D
        read_pairs(path, ref)


def test_new_terms_in_every_integrator_and_in_saved_parameters():
    """PairCouplings (moving lattice), Néel and bulk DMI together: CollectivePRK
    conserves energy, SuzukiTrotter and Langevin run, and calc.todict /
    from_dict rebuilds the same Hamiltonian."""
    term, ref = _full_couplings(_two_site_reference(), decay=0.8)
    terms = [ase_spin.LennardJones(0.2, 2.0, rc=3.9, cutoff="smooth"), term,
             Neel(BetheSlater(0.01, 0.2, 1.5), BetheSlater(0.005, -0.3, 1.6), rc=3.6),
             DMI(0.002, rc=3.6, form="bulk")]
    atoms = _spun(ref.repeat((2, 1, 1)))
    atoms.rattle(0.03, seed=8)
    atoms.calc = SpinLatticeCalculator(terms)
    rebuilt = SpinLatticeCalculator.from_dict(json.loads(json.dumps(atoms.calc.todict())))
    b = atoms.copy()
    b.calc = rebuilt
    assert b.get_potential_energy() == pytest.approx(atoms.get_potential_energy(), rel=1e-14)
    start = atoms.copy()
    drift = []
    for dt, steps in ((0.5, 6), (0.25, 12)):
        atoms = start.copy()
        atoms.calc = SpinLatticeCalculator(terms)
        e0 = atoms.get_potential_energy() + atoms.get_kinetic_energy()
        CollectivePRK(atoms, dt * units.fs).run(steps)
        drift.append(atoms.get_potential_energy() + atoms.get_kinetic_energy() - e0)
    # a second-order method's energy error, not an inconsistency of forces and
    # fields (an inconsistent force or field would not scale so)
    assert abs(drift[0]) < 1e-3 and 3.5 < drift[0] / drift[1] < 4.5
    SuzukiTrotter(atoms, 0.5 * units.fs).run(3)
    Langevin(atoms, 0.5 * units.fs, temperature_K=50, spin_damping=0.1, friction=0.01,
             rng=1).run(3)
    assert np.isfinite(atoms.positions).all()


def test_lammps_forms_of_the_new_terms(tmp_path):
    """Néel exports as spin/neel; bulk DMI and explicit pairs are refused
    with the reason."""
    atoms = _spun(bulk("Co", "fcc", a=3.54, cubic=True).repeat(2))
    neel = Neel(BetheSlater(0.0048, 0.234, 1.168), BetheSlater(0.03, 0.705, 0.652), rc=3.0)
    write_lammps(tmp_path / "deck", atoms, hamiltonian=Hamiltonian(
        [Exchange(BetheSlater(*CO_BS), rc=4.0), neel]), timestep=0.1 * units.fs)
    deck = "".join(p.read_text() for p in (tmp_path / "deck").iterdir() if p.suffix != ".data")
    assert "spin/neel 3.0" in deck and "neel 3.0 0.0048 0.234 1.168 0.03 0.705 0.652" in deck
    with pytest.raises(NotImplementedError, match="interfacial form"):
        write_lammps(tmp_path / "d2", atoms, hamiltonian=Hamiltonian(
            [DMI(0.002, rc=3.0, form="bulk")]), timestep=0.1 * units.fs)


def test_coupling_matrices_convention():
    """s_iᵀ[D]s_j = D·(s_i × s_j); from_matrices splits a tensor back."""
    rng = np.random.default_rng(2)
    D = rng.normal(size=(1, 3))
    a, b = rng.normal(size=3), rng.normal(size=3)
    M = coupling_matrices(np.zeros(1), D)[0]
    assert a @ M @ b == pytest.approx(D[0] @ np.cross(a, b))
    ref = _two_site_reference()
    term, _ = _full_couplings(ref)
    again = PairCouplings.from_matrices(ref, term.i, term.j, term.R, term.matrices())
    np.testing.assert_allclose(again.matrices(), term.matrices(), atol=1e-17)
