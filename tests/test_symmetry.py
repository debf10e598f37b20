"""Symmetry-aware set-up: neighbour shells by space group, tabulated and
per-shell exchange, TB2J's exchange.out, magnetic space groups."""

import os
import re
import warnings

import numpy as np
import pytest
import spglib
from ase import Atoms
from ase.build import bulk
from ase.neighborlist import primitive_neighbor_list

from ase_spin import (Exchange, SpinLatticeCalculator, ShellExchange, Tabulated,
                      magnetic_symmetry, neighbor_shells, read_tb2j, set_spins)
from ase_spin.interop.symmetry import NeighborShells

from conftest import random_spins

TB2J_DIR = os.path.join(os.path.dirname(__file__), "data", "tb2j_bcc_Fe")


# ---------------------------------------------------------------- shells

A_FCC, A_BCC, A_HCP = 3.54, 2.87, 2.5


@pytest.mark.parametrize("name, atoms, rmax, distances, counts", [
    ("fcc", bulk("Co", "fcc", a=A_FCC), 5.1,
     A_FCC * np.sqrt([0.5, 1.0, 1.5, 2.0]), [12, 6, 24, 12]),
    ("fcc-cubic", bulk("Co", "fcc", a=A_FCC, cubic=True), 5.1,
     A_FCC * np.sqrt([0.5, 1.0, 1.5, 2.0]), [12, 6, 24, 12]),
    ("bcc", bulk("Fe", "bcc", a=A_BCC), 4.8,
     A_BCC * np.sqrt([0.75, 1.0, 2.0, 11 / 4]), [8, 6, 12, 24]),
    ("hcp-ideal", bulk("Co", "hcp", a=A_HCP, c=A_HCP * np.sqrt(8 / 3)), 4.5,
     A_HCP * np.sqrt([1.0, 2.0, 8 / 3, 3.0]), [12, 6, 2, 18]),
])
def test_shells_of_simple_crystals(name, atoms, rmax, distances, counts):
    shells = neighbor_shells(atoms, rmax)
    assert len(shells.sites) == 1  # one inequivalent site in each
    np.testing.assert_allclose(shells.distances(), distances, rtol=1e-9)
    assert shells.multiplicities() == counts
    for s in shells:
        # every listed pair is a neighbour of the site at the shell's distance
        i, j, n = s.pairs[:, 0], s.pairs[:, 1], s.pairs[:, 2:]
        assert (i == s.site).all()
        d = np.linalg.norm(atoms.positions[j] + n @ atoms.cell.array - atoms.positions[i],
                           axis=1)
        np.testing.assert_allclose(d, s.distance, rtol=1e-9)
        assert len({tuple(p) for p in s.pairs}) == s.multiplicity
    text = str(shells)
    assert "space group" in text and str(counts[0]) in text


def test_hcp_splits_shells_the_space_group_does_not_relate():
    """Ideal hcp: the 12 nearest neighbours are 6 in-plane and 6 out-of-plane,
    at one distance but not related by P6_3/mmc; the 18 of the fourth shell
    split 12 + 6 the same way."""
    atoms = bulk("Co", "hcp", a=A_HCP, c=A_HCP * np.sqrt(8 / 3))
    shells = neighbor_shells(atoms, 4.5)
    assert "P6_3/mmc" in shells.spacegroup
    first = [s for s in shells if s.index == 1]
    assert sorted(s.multiplicity for s in first) == [6, 6]
    cell = atoms.cell.array
    for s in first:
        dz = (atoms.positions[s.pairs[:, 1]] + s.pairs[:, 2:] @ cell
              - atoms.positions[s.pairs[:, 0]])[:, 2]
        # one class all in-plane, the other all out of it
        assert np.allclose(dz, 0.0) or (np.abs(dz) > 1.0).all()
    assert sorted(s.multiplicity for s in shells if s.index == 4) == [6, 12]
    assert {s.label for s in first} == {"1a", "1b"}


def test_shells_of_magnetic_sublattice_and_inequivalent_sites():
    """Rock salt with moments on the cations only: the shells are those of
    the fcc cation lattice. Tagging the two atoms of a bcc cell apart (a CsCl
    structure) gives two inequivalent sites, each with its own shells."""
    nio = bulk("NiO", "rocksalt", a=4.17)
    nio.set_initial_magnetic_moments([1.7, 0.0])
    shells = neighbor_shells(nio, 5.5)
    assert {s.species for s in shells} == {("Ni", "Ni")}
    assert shells.multiplicities() == [12, 6, 24]

    cscl = bulk("Fe", "bcc", a=A_BCC, cubic=True)
    cscl.set_tags([0, 1])
    shells = neighbor_shells(cscl, 3.0)
    assert shells.sites == [0, 1]
    for site in (0, 1):
        assert [s.multiplicity for s in shells.of(site)] == [8, 6]
        nn = shells.of(site)[0].pairs
        assert (nn[:, 1] == 1 - site).all()  # nearest neighbours on the other sublattice


def test_shells_refuse_what_is_not_a_crystal():
    atoms = bulk("Fe", "bcc", a=A_BCC)
    open_ = atoms.copy()
    open_.pbc = False
    with pytest.raises(ValueError, match="periodic"):
        neighbor_shells(open_, 3.0)
    with pytest.raises(ValueError, match="rmax"):
        neighbor_shells(atoms, -1.0)
    with pytest.raises(ValueError, match="no pair"):
        neighbor_shells(atoms, 1.0)


@pytest.mark.parametrize("function", [lambda a: neighbor_shells(a, 3.0), magnetic_symmetry],
                         ids=["neighbor_shells", "magnetic_symmetry"])
@pytest.mark.parametrize("edit, match", [
    (lambda a: a.positions.__setitem__((1, 0), np.nan), "position of atom 1 is not finite"),
    (lambda a: a.positions.__setitem__((0, 2), -np.inf), "position of atom 0 is not finite"),
    (lambda a: a.cell.array.__setitem__((0, 0), np.nan), "cell has non-finite"),
    (lambda a: a.cell.array.__setitem__((2, 1), np.inf), "cell has non-finite"),
    (lambda a: a.positions.__setitem__(1, a.positions[1] + 1e18), "atom 1 lies .* wrap"),
    (lambda a: a.positions.__setitem__(0, [3e7, 0, 0]), "atom 0 lies .* wrap"),
])
def test_symmetry_refuses_what_spglib_cannot_take(function, edit, match):
    """NaN/inf used to kill the interpreter inside spglib; an atom 1e18 Å away
    gave a wrong space group (its fractional coordinate is rounding noise)."""
    atoms = bulk("Fe", "bcc", a=A_BCC, cubic=True)
    edit(atoms)
    before = (atoms.positions.copy(), atoms.cell.array.copy())
    with pytest.raises(ValueError, match=match):
        function(atoms)
    np.testing.assert_array_equal(atoms.positions, before[0])
    np.testing.assert_array_equal(atoms.cell.array, before[1])


def test_symmetry_takes_atoms_a_few_cells_away():
    atoms = bulk("Fe", "bcc", a=A_BCC, cubic=True)
    far = atoms.copy()
    far.positions[1] += 1000 * far.cell[0] - 7 * far.cell[2]
    assert magnetic_symmetry(far).bns_number == magnetic_symmetry(atoms).bns_number
    assert neighbor_shells(far, 4.2).multiplicities() == [8, 6, 12]


def test_neighbor_shells_refuses_an_rmax_beyond_its_memory_limit():
    """A huge rmax used to run out of memory after minutes: now refused before
    any pair is listed, from the estimated number of pairs."""
    from ase_spin.interop.symmetry import MAX_PAIR_ROWS

    atoms = bulk("Fe", "bcc", a=A_BCC)
    for rmax in (1e4, 1e300, 70.0):  # 70 Å: 1.2e5 pairs x 49 operations
        with pytest.raises(ValueError, match=re.escape(f"{MAX_PAIR_ROWS:.3g} rows")):
            neighbor_shells(atoms, rmax)


# ---------------------------------------------------------------- Tabulated

R_TAB = [2.3, 2.6, 3.0, 3.5, 4.0, 4.4]
J_TAB = [0.05, 0.03, 0.012, 0.002, -0.001, 0.0]


def test_tabulated_passes_through_its_points_and_is_smooth():
    t = Tabulated(R_TAB, J_TAB)
    np.testing.assert_allclose(t(np.array(R_TAB)), J_TAB, atol=1e-15)
    assert t.rc == R_TAB[-1]
    r = np.linspace(1.5, 5.0, 701)
    h = 1e-6
    np.testing.assert_allclose((t(r + h) - t(r - h)) / (2 * h), t.derivative(r), atol=1e-8)
    # continuous J and J' at both ends: zero beyond the last point, linear below the first
    for r0 in (R_TAB[0], R_TAB[-1]):
        for f in (t, t.derivative):
            assert f(np.array([r0 - 1e-9]))[0] == pytest.approx(f(np.array([r0 + 1e-9]))[0],
                                                                abs=1e-7)
    assert not t(np.array([4.41, 6.0])).any() and not t.derivative(np.array([4.41])).any()
    below = np.array([1.0, 2.0])
    np.testing.assert_allclose(t(below), J_TAB[0] + t.derivative(np.array([R_TAB[0]]))[0]
                               * (below - R_TAB[0]))


@pytest.mark.parametrize("r, J, match", [
    ([2.0, 3.0, 4.0], [0.1, 0.05, 0.01], "must be 0 at the last point"),
    ([2.0, 2.0, 4.0], [0.1, 0.05, 0.0], "strictly increasing"),
    ([2.0, 4.0], [0.1, 0.0], "three points"),
    ([2.0, 3.0, 4.0], [0.1, 0.05], "one length"),
    ([2.0, np.nan, 4.0], [0.1, 0.05, 0.0], "finite"),
])
def test_tabulated_refuses_bad_tables(r, J, match):
    with pytest.raises(ValueError, match=match):
        Tabulated(r, J)


def test_tabulated_exchange_energy_of_a_pair_and_reassignment():
    """Two spins at a tabulated distance: E = −J(r) s1·s2 through Exchange;
    reassigning the table is checked and seen by the calculator."""
    atoms = Atoms("Fe2", positions=[[0, 0, 0], [0, 0, R_TAB[2]]], cell=[20, 20, 20])
    set_spins(atoms, [[0, 0, 1], [np.sin(0.4), 0, np.cos(0.4)]], 2.2)
    t = Tabulated(R_TAB, J_TAB)
    atoms.calc = SpinLatticeCalculator([Exchange(t)])
    assert atoms.get_potential_energy() == pytest.approx(-J_TAB[2] * np.cos(0.4), rel=1e-12)
    with pytest.raises(ValueError, match="last point"):
        t.J = [1.0] * len(R_TAB)
    assert t.J[2] == J_TAB[2]
    t.J = np.array(J_TAB) * 2
    assert atoms.get_potential_energy() == pytest.approx(-2 * J_TAB[2] * np.cos(0.4), rel=1e-12)
    with pytest.raises(ValueError):
        t.J[0] = 1.0  # read-only: assign a new table instead


# ---------------------------------------------------------------- ShellExchange

def _hand_energy(atoms, spins, shells, tol):
    """−Σ_{i<j} J_n s_i·s_j over all pairs within each shell's window."""
    i, j, d = primitive_neighbor_list("ijd", atoms.pbc, atoms.cell.array, atoms.positions,
                                      max(s for s, _ in shells) + tol)
    e = 0.0
    for dist, J in shells:
        sel = np.abs(d - dist) <= tol
        e -= 0.5 * J * np.einsum("ij,ij->", spins[i[sel]], spins[j[sel]])
    return e


def test_shell_exchange_equals_a_hand_sum(rng):
    atoms = bulk("Fe", "bcc", a=A_BCC, cubic=True).repeat(3)
    atoms.rattle(0.03, seed=3)
    s = random_spins(len(atoms), rng)
    set_spins(atoms, s, 2.2)
    table = [(A_BCC * np.sqrt(3) / 2, 0.0191), (A_BCC, 0.0108), (A_BCC * np.sqrt(2), -0.0007)]
    atoms.calc = SpinLatticeCalculator([ShellExchange(table, tol=0.15)])
    assert atoms.get_potential_energy() == pytest.approx(_hand_energy(atoms, s, table, 0.15),
                                                         rel=1e-12)
    # a constant per shell: no lattice forces, no stress
    assert not atoms.get_forces().any()
    assert not atoms.get_stress().any()
    # the same from the symmetry table
    shells = neighbor_shells(bulk("Fe", "bcc", a=A_BCC), 4.1)
    term = shells.exchange([J for _, J in table], tol=0.15)
    atoms.calc = SpinLatticeCalculator([term])
    assert atoms.get_potential_energy() == pytest.approx(_hand_energy(atoms, s, table, 0.15),
                                                         rel=1e-12)


def test_shell_exchange_magnetic_forces_are_the_spin_derivative(rng):
    from ase_spin import Hamiltonian, Want

    from test_calculator import fd_forces, fd_magnetic_forces

    atoms = bulk("Fe", "bcc", a=A_BCC, cubic=True).repeat(2)
    atoms.rattle(0.05, seed=5)
    s = random_spins(len(atoms), rng)
    mu = rng.uniform(0.5, 3.0, len(atoms))
    term = ShellExchange([(A_BCC * np.sqrt(3) / 2, 0.0191), (A_BCC, -0.0108)], tol=0.15)
    ev = Hamiltonian([term]).bind(atoms.numbers, atoms.cell.array, atoms.pbc, mu)
    res = ev.evaluate(atoms.positions, s, Want(energy=True, forces=True, magnetic_forces=True))
    np.testing.assert_allclose(res.magnetic_forces, fd_magnetic_forces(ev, atoms.positions, s),
                               rtol=1e-7, atol=1e-9)
    assert not res.forces.any() and not fd_forces(ev, atoms.positions, s).any()


def test_shell_exchange_per_species_pair(rng):
    """CsCl FeCo: Fe–Co nearest neighbours, Fe–Fe and Co–Co second."""
    atoms = Atoms("FeCo", scaled_positions=[[0, 0, 0], [0.5, 0.5, 0.5]],
                  cell=np.eye(3) * 2.86, pbc=True).repeat(2)
    s = random_spins(len(atoms), rng)
    set_spins(atoms, s, 2.0)
    d1, d2 = 2.86 * np.sqrt(3) / 2, 2.86
    term = ShellExchange({("Fe", "Co"): [(d1, 0.03)], ("Fe", "Fe"): [(d2, 0.01)],
                          "Co-Co": [(d2, -0.004)]}, tol=0.1)
    atoms.calc = SpinLatticeCalculator([term])
    sym = np.array(atoms.get_chemical_symbols())
    i, j, d = primitive_neighbor_list("ijd", atoms.pbc, atoms.cell.array, atoms.positions, 3.0)
    J = np.where(np.abs(d - d1) < 0.1, 0.03,
                 np.where(sym[i] == "Fe", 0.01, -0.004) * (np.abs(d - d2) < 0.1))
    hand = -0.5 * np.sum(J * np.einsum("ij,ij->i", s[i], s[j]))
    assert atoms.get_potential_energy() == pytest.approx(hand, rel=1e-12)


def test_shell_exchange_refuses_a_lattice_that_left_its_shells():
    atoms = bulk("Fe", "bcc", a=A_BCC, cubic=True).repeat(2)
    set_spins(atoms, [0, 0, 1], 2.2)
    atoms.calc = SpinLatticeCalculator([ShellExchange([(A_BCC * np.sqrt(3) / 2, 0.02),
                                                       (A_BCC, 0.01)], tol=0.05)])
    atoms.get_potential_energy()
    atoms.positions[0] += [0.2, 0.1, 0.0]
    before = atoms.positions.copy()
    with pytest.raises(ValueError, match="in no shell"):
        atoms.get_potential_energy()
    np.testing.assert_array_equal(atoms.positions, before)
    with pytest.raises(ValueError, match="overlap"):
        ShellExchange([(2.5, 0.02), (2.6, 0.01)], tol=0.1)
    with pytest.raises(ValueError, match="given twice"):
        ShellExchange([(2.5, 0.02), (2.5, 0.01)])


# ---------------------------------------------------------------- TB2J

J1, J2, J3 = 19.6502, 11.2231, -0.8734  # meV, as written in tests/data/tb2j_bcc_Fe


def test_read_tb2j_converts_to_ase_spin_convention():
    t = read_tb2j(TB2J_DIR)
    assert len(t.atoms) == 2 and t.atoms.get_chemical_symbols() == ["Fe", "Fe"]
    np.testing.assert_allclose(t.atoms.get_initial_magnetic_moments()[:, 2], 2.5763)
    # 26 ordered pairs per atom in the file, both directions: 26 unordered pairs per cell
    assert len(t) == 26
    shells = t.shells()[("Fe", "Fe")]
    assert [n for *_, n in shells] == [8, 6, 12]
    np.testing.assert_allclose([J for _, J, *_ in shells], 2e-3 * np.array([J1, J2, J3]))
    np.testing.assert_allclose([d for d, *_ in shells],
                               2.83 * np.sqrt([0.75, 1.0, 2.0]), rtol=1e-12)


@pytest.mark.parametrize("afm", [False, True])
def test_tb2j_energy_matches_tb2j_convention(afm):
    """E per atom of TB2J's model, −Σ_{j≠i} J^TB2J_ij s_i·s_j summed over
    ordered pairs, equals ase_spin's energy with the converted constants —
    ferromagnet and CsCl-type antiferromagnet (nearest neighbours reversed)."""
    t = read_tb2j(os.path.join(TB2J_DIR, "exchange.out"))
    atoms = t.atoms.repeat(2)
    up = np.tile([[0, 0, 1.0], [0, 0, -1.0 if afm else 1.0]], (8, 1))
    set_spins(atoms, up, 2.5763)
    atoms.calc = SpinLatticeCalculator([t.exchange()])
    sign1 = -1.0 if afm else 1.0
    tb2j_per_atom = -(8 * J1 * sign1 + 6 * J2 + 12 * J3) * 1e-3
    assert atoms.get_potential_energy() / len(atoms) == pytest.approx(tb2j_per_atom, rel=1e-12)


def test_read_tb2j_older_labels_and_errors(tmp_path):
    text = open(os.path.join(TB2J_DIR, "exchange.out")).read()
    old = text.replace("   Fe1   ", "   0(Fe1  ) ").replace(" Fe2   (", " 1(Fe2  ) (")
    (tmp_path / "old.out").write_text(old)
    t = read_tb2j(tmp_path / "old.out")
    assert len(t) == 26
    # a collinear calculation: one moment column (w_magmom)
    collinear = text.replace("    0.0000    0.0000    2.5763", "    2.5763")
    (tmp_path / "collinear.out").write_text(collinear)
    t = read_tb2j(tmp_path / "collinear.out")
    np.testing.assert_allclose(t.atoms.get_initial_magnetic_moments(), [2.5763, 2.5763])
    assert len(t) == 26
    bad = text.replace("(-1.415, -1.415, -1.415)", "(-1.415, -1.415, -1.515)", 1)
    assert bad != text
    (tmp_path / "bad.out").write_text(bad)
    with pytest.raises(ValueError, match="line .*vector"):
        read_tb2j(tmp_path / "bad.out")
    (tmp_path / "none.out").write_text("hello\n")
    with pytest.raises(ValueError, match="not a TB2J"):
        read_tb2j(tmp_path / "none.out")
    with pytest.raises(FileNotFoundError):
        read_tb2j(tmp_path)
    # the two directions of a pair disagreeing: a warning, their mean
    lines = text.splitlines()
    k = next(n for n, line in enumerate(lines) if "Fe2   Fe1" in line)
    lines[k] = lines[k].replace(f"{J1:7.4f}", f"{J1 + 1:7.4f}")
    (tmp_path / "asym.out").write_text("\n".join(lines))
    with pytest.warns(UserWarning, match="two directions"):
        t = read_tb2j(tmp_path / "asym.out")
    with pytest.warns(UserWarning, match="not equivalent"):
        t.exchange()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_tb2j(TB2J_DIR).exchange()


def _tb2j_text():
    with open(os.path.join(TB2J_DIR, "exchange.out")) as f:
        return f.read()


def _nth_pair_line(text, n):
    lines = text.splitlines(keepends=True)
    k = [i for i, line in enumerate(lines) if line.startswith("   Fe")][n]
    return lines, k


@pytest.mark.parametrize("edit, match", [
    # a pair line cut in the middle (a file cut short): used to be dropped silently
    (lambda t: t[:t.index("(  0,   0,   0) 19.6502") + 20], r"line \d+: a pair line that does"),
    (lambda t: t.replace("(-1.415, -1.415, -1.415)  2.451", "(-1.415, -1.4", 1),
     r"line 25: a pair line that does not read"),
    # cut in the distance, the last line: reads as a pair, but has no newline
    (lambda t: t[:t.index("2.451", t.index("Fe2   Fe1")) + 3], r"line 57: the file ends within this pair line"),
    (lambda t: t.replace("(-1.415, -1.415, -1.415)  2.451", "(-1.415, -1.415, -1.415)  2.1", 1),
     r"line 25: the pair's distance 2.1"),
    (lambda t: t.replace("2.5763", "nan", 1), r"line 17: .* must be finite"),
    (lambda t: t.replace("19.6502   (-1.415", "inf   (-1.415", 1), r"line 25: J, .* finite"),
    (lambda t: t.replace("2.83000000  0.00000000", "nan  0.00000000", 1), r"line 9: the cell"),
    (lambda t: t.replace("Fe1 ", "Xq1 ").replace("Fe1)", "Xq1)"), r"line 17: .*'Xq1' names no"),
    (lambda t: t.replace("( -1,  -1,  -1)", "(-99999999999999999999, -1, -1)", 1),
     r"line 25: the lattice image R = \(-99999999999999999999, -1, -1\) is more than 1000"),
    (lambda t: t.replace("Exchange:", "Exchange:\0\1", 1), r"not a text file"),
    (lambda t: t.replace("Exchange:", "Exchange: \xff", 1).encode("latin-1"), "not a text file"),
])
def test_read_tb2j_refuses_what_it_cannot_read(tmp_path, edit, match):
    bad = edit(_tb2j_text())
    path = tmp_path / "exchange.out"
    if isinstance(bad, bytes):
        path.write_bytes(bad)
    else:
        path.write_text(bad)
    with pytest.raises(ValueError, match="exchange.out: " + match):
        read_tb2j(path)


def test_read_tb2j_counts_pairs_listed_in_one_direction():
    """A file cut at a line boundary: the pairs whose other direction is lost
    are counted in a warning (TB2J lists both)."""
    text = _tb2j_text()
    lines, k = _nth_pair_line(text, 8)  # the first 8 lines: Fe1-Fe2 in one direction
    path = os.path.join(os.environ.get("TMPDIR", "/tmp"), f"tb2j-cut-{os.getpid()}.out")
    with open(path, "w") as f:
        f.write("".join(lines[:k]))
    try:
        with pytest.warns(UserWarning, match="8 of the 8 pairs are listed in one direction"):
            assert len(read_tb2j(path)) == 8
    finally:
        os.remove(path)


# ---------------------------------------------------------------- magnetic symmetry

def _cartesian(R, cell):
    return cell.T @ R @ np.linalg.inv(cell.T)


def _magnetic_operations_by_hand(atoms):
    """The operations of the crystal's space group that map the moments onto
    themselves (m_a' = det(R) R m_a, axial) or onto their reverse (with time
    reversal): the magnetic group derived without spglib's magnetic search."""
    cell = atoms.cell.array
    frac = atoms.get_scaled_positions()
    m = atoms.get_initial_magnetic_moments()
    data = spglib.get_symmetry_dataset((cell, frac, atoms.numbers), symprec=1e-5)
    ops = set()
    for R, t in zip(data.rotations, data.translations):
        moved = frac @ R.T + t
        diff = moved[:, None] - frac[None]
        target = np.argmin(np.linalg.norm(diff - np.rint(diff), axis=2), axis=1)
        Rc = _cartesian(R, cell)
        rotated = np.linalg.det(Rc) * m @ Rc.T
        for theta in (0, 1):
            if np.allclose(rotated * (-1) ** theta, m[target], atol=1e-8):
                ops.add((R.tobytes(), tuple(np.round(t % 1.0, 6) % 1.0), theta))
    return ops


def _spglib_ops(sym):
    R, t, theta = sym.operations
    return {(r.astype(np.intc).tobytes(), tuple(np.round(tt % 1.0, 6) % 1.0), int(th))
            for r, tt, th in zip(R, t, theta)}


def _rutile_mnf2(spins):
    atoms = Atoms("Mn2F4", cell=np.diag([4.87, 4.87, 3.31]), pbc=True,
                  scaled_positions=[[0, 0, 0], [0.5, 0.5, 0.5], [0.305, 0.305, 0],
                                    [0.695, 0.695, 0], [0.195, 0.805, 0.5], [0.805, 0.195, 0.5]])
    set_spins(atoms, [[0, 0, 1], [0, 0, spins]] + [[0, 0, 1]] * 4, [5, 5, 0, 0, 0, 0])
    return atoms


# Expected groups (Bilbao MAGNDATA / BNS tables): bcc Fe with M ∥ [001] is
# I4/mm'm' (BNS 139.537); the CsCl-type antiferromagnet with moments along c
# loses the body-centring to time reversal: P_I4/mnc (BNS 128.410), type IV;
# MnF2 (rutile, antiparallel moments along c) is P4_2'/mnm' (BNS 136.499).
@pytest.mark.filterwarnings("ignore:Set OLD_ERROR_HANDLING:DeprecationWarning")
@pytest.mark.parametrize("name, make, bns, kind", [
    ("bcc-FM-z", lambda: _bcc([[0, 0, 1], [0, 0, 1]]), "139.537", 3),
    ("bcc-AFM-z", lambda: _bcc([[0, 0, 1], [0, 0, -1]]), "128.410", 4),
    ("MnF2", lambda: _rutile_mnf2(-1), "136.499", 3),
])
def test_magnetic_space_groups(name, make, bns, kind):
    atoms = make()
    sym = magnetic_symmetry(atoms)
    assert sym.bns_number == bns and sym.type == kind
    # spglib's operations are exactly those derived by hand from the crystal group
    assert _spglib_ops(sym) == _magnetic_operations_by_hand(atoms)
    assert bns in str(sym)


def _bcc(spins):
    atoms = bulk("Fe", "bcc", a=A_BCC, cubic=True)
    set_spins(atoms, spins, 2.2)
    return atoms


def test_magnetic_symmetry_paramagnet_and_errors():
    atoms = bulk("Fe", "bcc", a=A_BCC, cubic=True)
    atoms.set_initial_magnetic_moments(None)
    sym = magnetic_symmetry(atoms)
    assert sym.type == 2 and sym.number == 229  # grey group Im-3m1'
    atoms.pbc = False
    with pytest.raises(ValueError, match="periodic"):
        magnetic_symmetry(atoms)


def test_neighbor_shells_is_what_the_package_exports():
    assert isinstance(neighbor_shells(bulk("Fe", "bcc", a=A_BCC), 3.0), NeighborShells)


# ---------------------------------------------------------------- dynamics

def _energy_errors(atoms, dt_fs, t_fs, **kw):
    from ase import units

    from ase_spin import CollectivePRK

    dyn = CollectivePRK(atoms, dt_fs * units.fs, **kw)
    e0 = dyn.get_total_energy()
    errors = []
    dyn.attach(lambda: errors.append(dyn.get_total_energy() - e0), interval=5)
    dyn.run(int(round(t_fs / dt_fs)))
    return np.abs(errors).max(), dyn


def test_tabulated_exchange_on_a_moving_lattice_conserves_energy():
    """fcc Co at 300 K, Lennard-Jones + Exchange(Tabulated): the energy error
    is the integrator's, O(h²) (smooth J and J' give exact forces)."""
    from ase_spin import LennardJones
    from ase_spin.scenes import fcc_cobalt

    r = np.linspace(2.0, 4.2, 12)
    J = 0.3 * (1 - r / 4.2) ** 3
    worst = {}
    for dt in (0.5, 1.0):
        atoms = fcc_cobalt(2, temperature_K=300)
        atoms.calc = SpinLatticeCalculator([
            LennardJones(epsilon=0.4, sigma=2.2742, rc=4.7, cutoff="shift"),
            Exchange(Tabulated(r, J))])
        worst[dt], dyn = _energy_errors(atoms, dt, 60.0)
    assert worst[0.5] < 5e-4 * dyn.get_kinetic_energy()
    assert 3.0 < worst[1.0] / worst[0.5] < 5.5


def test_shell_exchange_dynamics_frozen_and_vibrating_lattice():
    """ShellExchange: on a frozen lattice the spins precess with the energy
    kept to the integrator's O(h²); on a lattice vibrating well within the
    windows, too (J is constant inside them, so nothing jumps)."""
    from ase_spin import LennardJones
    from ase_spin.scenes import fcc_cobalt

    shells = [(A_FCC / np.sqrt(2), 0.0296), (A_FCC, 0.0035)]
    for lattice, T in (("frozen", 0.0), ("moving", 50.0)):
        worst = {}
        for dt in (0.4, 0.8):
            atoms = fcc_cobalt(2, temperature_K=T, cone_deg=60)
            atoms.calc = SpinLatticeCalculator([
                LennardJones(epsilon=0.4, sigma=2.2742, rc=4.7, cutoff="shift"),
                ShellExchange(shells, tol=0.3)])
            s0 = atoms.get_initial_magnetic_moments().copy()
            worst[dt], dyn = _energy_errors(atoms, dt, 60.0, lattice=lattice)
            assert np.abs(atoms.get_initial_magnetic_moments() - s0).max() > 0.1  # spins moved
        assert worst[0.4] < 1e-4 * len(atoms)
        assert 3.0 < worst[0.8] / worst[0.4] < 5.5, lattice
