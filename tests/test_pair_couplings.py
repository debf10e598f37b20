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
                      PairCouplings, SpinLatticeCalculator, SpinLBFGS, SuzukiTrotter, Want,
                      neighbor_shells, read_pairs, read_tb2j, read_tb2j_pairs, relax_spins,
                      write_lammps, write_pairs)
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


# -- hexagonal Co: the easy axis from anisotropic exchange ------------------

#: hcp Co as ase.build.bulk gives it (a = 2.51 Å, c/a = 1.622), and the ideal c/a
CO_A, CO_C = bulk("Co", "hcp").cell.cellpar()[[0, 2]]
IDEAL_CA = np.sqrt(8.0 / 3.0)
#: a cut-off (in units of a) between hcp's nearest neighbours (a, and
#: √(a²/3 + c²/4) ≤ 1.05 a for c/a ≤ 1.75) and the next (√(4a²/3 + c²/4) ≥
#: 1.37 a, c ≥ 1.5 a for c/a ≥ 1.5)
_NEAREST_CUT = 1.2


def _hcp_co(ca, gamma0, J=0.01, out_of_plane=1.0):
    """hcp Co with c = ca·a and, on its 12 nearest neighbours, J and the
    pseudo-dipolar Γ_ij = γ(r)(3ê_ij ê_ijᵀ − 1), γ(r) = γ₀(a/r)³, times
    ``out_of_plane`` on the bonds out of the basal plane. Returns (term,
    reference, the γ of the in-plane and the out-of-plane bonds, d)."""
    ref = bulk("Co", "hcp", a=CO_A, c=ca * CO_A)
    i, j, R, r = pairs_within(ref, _NEAREST_CUT * CO_A)
    assert len(i) == 12   # two sites, 12 neighbours each, each pair once
    e = (ref.positions[j] + R @ ref.cell.array - ref.positions[i]) / r[:, None]
    gamma = gamma0 * (CO_A / r) ** 3 * np.where(np.abs(e[:, 2]) > 1e-9, out_of_plane, 1.0)
    Gamma = gamma[:, None, None] * (3.0 * e[:, :, None] * e[:, None, :] - np.eye(3))
    d = np.sqrt(CO_A**2 / 3 + (ca * CO_A) ** 2 / 4)
    term = PairCouplings(ref, i, j, R, np.full(12, J), Gamma=Gamma)
    return term, ref, gamma0, gamma0 * (CO_A / d) ** 3 * out_of_plane, d


def _uniform(theta, phi, n):
    return np.tile([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)],
                   (n, 1))


@pytest.mark.parametrize("ca, out_of_plane", [(CO_C / CO_A, 1.0), (IDEAL_CA, 1.0),
                                              (IDEAL_CA, 1.5)])
def test_hcp_co_uniform_energy_is_the_lattice_sum(ca, out_of_plane):
    r"""hcp Co with pseudo-dipolar anisotropic exchange on the 12 nearest
    neighbours: the energy of every uniform state is the analytic lattice sum
    E/N = E₀ + K_eff sin²θ (θ from c), whatever the in-plane angle φ.

    Construction (chosen, not derived): Γ_ij = γ(r)(3ê_ij ê_ijᵀ − 1), γ(r) =
    γ₀(a/r)³ — the angular form and distance law of the dipole–dipole
    coupling, the form of van Vleck's pseudo-dipolar exchange — and one J on
    all 12 bonds. Γ is a function of the bond vector alone, so it turns with
    every rotation of the crystal: it is consistent with P6₃/mmc as long as
    γ is one number per symmetry orbit of bonds (checked: neighbor_shells's
    orbits are the 6 in-plane and the 6 out-of-plane bonds). It is one
    tensor hcp allows, not the most general one.

    Physics (the lattice sum): for s = (sinθ cosφ, sinθ sinφ, cosθ) on every
    atom, E/N = −½ Σ_j sᵀ𝒥_0j s over an atom's 12 neighbours: 6 in the plane
    (length a, γ_a; Σ êêᵀ = 3 diag(1, 1, 0)) and 6 out of it (length d =
    √(a²/3 + c²/4), γ_d; Σ êêᵀ = diag(a², a², 3c²/2)/d²), so

        E/N = −6J − ½[γ_a(9 sin²θ − 6) + γ_d(3a² sin²θ/d² + 9c² cos²θ/(2d²) − 6)],
        K_eff = (3/2)[γ_d (3c²/2 − a²)/d² − 3γ_a].

    No φ at all: the energy of a uniform state under bilinear couplings is a
    quadratic form sᵀTs, and the 6-fold axis makes T uniaxial (hcp's in-plane
    anisotropy, sixth order, cannot come from pairs in a uniform state).
    The 12 bonds' Σ êêᵀ has t_zz − t_xx = (3c²/4 − 2a²)/d², zero at c/a =
    √(8/3) only (checked over a range of c/a): there, with γ_d = γ_a (the law
    γ(r) gives it, d = a; symmetry does not: the two orbits stay distinct),
    K_eff = 0; with γ_d = 1.5 γ_a, K_eff = 9(γ_d − γ_a)/2 ≠ 0."""
    gamma0, J = 1e-3, 0.01
    term, ref, ga, gd, d = _hcp_co(ca, gamma0, J, out_of_plane)
    a, c = CO_A, ca * CO_A
    keff = 1.5 * (gd * (1.5 * c**2 - a**2) / d**2 - 3 * ga)
    sup = _spun(ref.repeat((2, 2, 2)))
    ev = _bound(term, sup)
    worst = 0.0
    for theta in np.linspace(0.0, np.pi, 7):
        s2 = np.sin(theta) ** 2
        lattice_sum = -6 * J - 0.5 * (ga * (9 * s2 - 6) + gd * (
            3 * a**2 * s2 / d**2 + 4.5 * c**2 * (1 - s2) / d**2 - 6))
        e0 = -6 * J - 0.5 * (-6 * ga + gd * (4.5 * c**2 / d**2 - 6))
        assert lattice_sum == pytest.approx(e0 + keff * s2, rel=1e-14)
        for phi in (0.0, 0.4, 1.3, 2.9):
            e = ev.evaluate(sup.positions, _uniform(theta, phi, len(sup)),
                            Want(energy=True)).energy / len(sup)
            worst = max(worst, abs(e - lattice_sum))
    assert worst < 1e-14 * 6 * J
    ideal = abs(ca - IDEAL_CA) < 1e-12
    if ideal and out_of_plane == 1.0:
        assert abs(keff) < 1e-18
    else:
        assert abs(keff) > 1e-6
    # what makes the ideal c/a special: the second moment of the 12 bonds
    for x in np.r_[np.linspace(1.5, 1.75, 6), IDEAL_CA]:
        cell = bulk("Co", "hcp", a=CO_A, c=x * CO_A)
        i, j, R, r = pairs_within(cell, _NEAREST_CUT * CO_A)
        e = (cell.positions[j] + R @ cell.cell.array - cell.positions[i]) / r[:, None]
        T = 2.0 / len(cell) * np.einsum("ni,nj->ij", e, e)   # Σ_j êêᵀ of one atom
        dd = CO_A**2 / 3 + (x * CO_A) ** 2 / 4
        assert np.trace(T) == pytest.approx(12.0)
        np.testing.assert_allclose(T - np.diag(np.diag(T)), 0.0, atol=1e-14)
        assert T[2, 2] - T[0, 0] == pytest.approx((0.75 * x**2 - 2) * CO_A**2 / dd, abs=1e-13)
        assert (np.abs(T - 4 * np.eye(3)).max() < 1e-13) == (x == IDEAL_CA)
    # the construction's γ is one number per symmetry orbit of bonds
    ase_spin.set_spins(ref, [0.0, 0.0, 1.0])
    shells = neighbor_shells(ref, _NEAREST_CUT * CO_A)
    for shell in shells:
        n = shell.pairs[:, 2:]
        bond = ref.positions[shell.pairs[:, 1]] + n @ ref.cell.array - ref.positions[shell.site]
        assert len(set(np.abs(bond[:, 2]) > 1e-9)) == 1, shell.label
    assert sorted(s.multiplicity for s in shells) == [6, 6]


def test_hcp_co_anisotropic_exchange_gives_the_easy_axis():
    """With the sign chosen for Co, the relaxed state of hcp Co (its own c/a)
    lies along c; with the other sign, in the basal plane; at the ideal c/a a
    tilted uniform state feels no torque.

    Construction: the couplings of test_hcp_co_uniform_energy_is_the_lattice_sum
    and the sign γ₀ > 0 (bonds prefer moments along them, as the
    dipole–dipole coupling does), chosen because it gives Co's easy axis:
    at c/a = 1.622 < √(8/3) the out-of-plane bonds are flatter (which favours
    the plane) but shorter, so stronger under γ ∝ r⁻³ (which wins), K_eff > 0.
    Co's measured anisotropy comes mostly from single-ion spin–orbit
    coupling; its size and origin here are not Co's. Physics checked: the
    relaxation (SpinLBFGS, J included, from uniform spins 40° off the
    expected minimum with noise on each spin; both starts in the basin where
    E(θ) is convex, |θ − θ_min| < 45°) ends where the sign of K_eff says."""
    rng = np.random.default_rng(7)
    for gamma0, theta0, along_c in ((1e-3, 0.7, True), (-1e-3, np.pi / 2 - 0.7, False)):
        term, ref, *_ = _hcp_co(CO_C / CO_A, gamma0)
        atoms = ref.repeat((2, 2, 2))
        ase_spin.set_spins(atoms, _uniform(theta0, 0.5, len(atoms))
                           + 0.05 * rng.normal(size=(len(atoms), 3)), 1.6)
        atoms.calc = SpinLatticeCalculator([term])
        assert SpinLBFGS(atoms).run(fmax=1e-10, steps=300)
        sz = np.abs(ase_spin.get_spins(atoms)[:, 2])
        np.testing.assert_allclose(sz, 1.0 if along_c else 0.0, atol=1e-8)
    term, ref, *_ = _hcp_co(IDEAL_CA, 1e-3)
    atoms = ref.repeat((2, 2, 2))
    s = _uniform(0.7, 0.5, len(atoms))
    ase_spin.set_spins(atoms, s, 1.6)
    res = _bound(term, atoms).evaluate(atoms.positions, s, Want(magnetic_forces=True))
    assert np.abs(np.cross(s, res.magnetic_forces)).max() < 1e-15
    assert np.abs(res.magnetic_forces).max() > 0.05   # the exchange field, parallel to s
