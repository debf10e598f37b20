"""Cells and positions at the edges: the neighbour search never kills the
process, never asks for absurd memory, and gives the same pairs however far the
atoms are from the cell or from each other."""

import os
import subprocess
import sys
import tempfile
import textwrap

import numpy as np
import pytest
from ase.build import bulk

import ase_spin
from ase_spin import Exchange, BetheSlater, LennardJones, SpinLatticeCalculator
from ase_spin.neighbors import NeighborCache, separation, sweep_pairs, wrap_positions

from conftest import CO_BS, CO_LJ, PACKAGE_PATH, random_spins, structures

PROPS = ("energy", "forces", "magnetic_forces", "stress")


def calc():
    return SpinLatticeCalculator([LennardJones(**CO_LJ, cutoff="shift"),
                                  Exchange(BetheSlater(*CO_BS), rc=4.0)])


def evaluate(atoms, props=PROPS):
    atoms.calc = calc()
    out = {}
    for p in props:
        if p == "stress" and (atoms.cell.rank < 3):
            continue
        out[p] = np.array(atoms.calc.get_property(p, atoms))
    return out


def crystal(seed=0):
    a = bulk("Co", "fcc", a=3.54, cubic=True).repeat(2)
    a.rattle(0.05, seed=seed)
    ase_spin.set_spins(a, random_spins(len(a), np.random.default_rng(seed)), 1.7)
    return a


def snapshot(a):
    return (a.positions.copy(), a.cell.array.copy(), a.pbc.copy(),
            a.arrays["initial_magmoms"].copy())


def assert_unchanged(a, snap):
    for x, y in zip(snapshot(a), snap):
        assert x.dtype == y.dtype and x.tobytes() == y.tobytes()


CRASH_CASES = {
    # name: (code that edits `a`, expected: "ValueError" or "finite")
    "nan cell": ("c = a.cell.array.copy(); c[0, 0] = np.nan; a.set_cell(c)", "ValueError"),
    "inf cell": ("c = a.cell.array.copy(); c[1, 1] = np.inf; a.set_cell(c)", "ValueError"),
    "open, 5e5 Å apart": ("a.pbc = False; a.positions[0] += [5e5, 0, 0]", "finite"),
    "open, 1e12 Å apart": ("a.pbc = False; a.positions[0] += [1e12, 0, 0]", "finite"),
    "open, 1e300 Å away": ("a.pbc = False; a.positions[0] += [1e300, 0, 0]", "finite"),
    "mixed, 5e5 Å apart": ("a.pbc = [True, True, False]; a.positions[0] += [0, 0, 5e5]",
                           "finite"),
    "periodic 1e8 Å vector": ("c = a.cell.array.copy(); c[0, 0] = 1e8; a.set_cell(c)",
                              "finite"),
    "1e6 cells outside": ("a.positions[0] += 1e6 * a.cell[0]", "finite"),
    "zero cell, pbc": ("a.set_cell(np.zeros((3, 3)))", "ValueError"),
    "2D cell, pbc": ("c = a.cell.array.copy(); c[2] = 0; a.set_cell(c)", "ValueError"),
    "tiny periodic cell": ("a.set_cell(a.cell * 1e-3, scale_atoms=True)", "ValueError"),
}


def test_no_case_kills_the_process():
    """Each case runs in one child process (a SIGFPE there fails this test,
    not the test run); every case ends in a ValueError or finite results, for
    the calculator and for a step of CollectivePRK."""
    lines = ["import numpy as np, ase_spin, sys",
             "sys.path.insert(0, %r)" % str(__import__("pathlib").Path(__file__).parent),
             "from test_robust_geometry import crystal, calc",
             "from ase import units",
             "from ase_spin import CollectivePRK"]
    for name, (edit, _) in CRASH_CASES.items():
        lines.append(textwrap.dedent(f"""
            a = crystal(); {edit}; a.calc = calc()
            try:
                e = a.get_potential_energy(); f = a.get_forces()
                CollectivePRK(a, 0.1 * units.fs).run(1)
                ok = np.isfinite(e) and np.isfinite(f).all() and np.isfinite(a.positions).all()
                print({name!r}, "finite" if ok else "NONFINITE", flush=True)
            except ValueError as err:
                print({name!r}, "ValueError", flush=True)
            """))
    # from a neutral folder, with the copy the tests import ("-c" puts the working
    # folder first on sys.path: the tree's, when run from it, whose kernels this
    # run has not compiled)
    out = subprocess.run([sys.executable, "-c", "\n".join(lines)], capture_output=True,
                         text=True, timeout=600, cwd=tempfile.gettempdir(),
                         env={**os.environ, "PYTHONPATH": PACKAGE_PATH})
    assert out.returncode == 0, (out.returncode, out.stdout, out.stderr[-3000:])
    seen = dict(line.rsplit(" ", 1) for line in out.stdout.strip().splitlines())
    for name, (_, expected) in CRASH_CASES.items():
        assert seen[name] == expected, (name, out.stdout)


@pytest.mark.parametrize("edit", ["nan", "zero", "2d", "dependent", "tiny"])
def test_bad_cell_is_a_clear_error_and_atoms_unchanged(edit):
    a = crystal()
    c = a.cell.array.copy()
    if edit == "nan":
        c[2, 1] = np.nan
    elif edit == "zero":
        c[:] = 0.0
    elif edit == "2d":
        c[1] = 0.0
    elif edit == "dependent":
        c[2] = c[0] + c[1]
    a.set_cell(c)
    if edit == "tiny":
        a.set_cell(a.cell * 1e-3, scale_atoms=True)
    a.calc = calc()
    snap = snapshot(a)
    with pytest.raises(ValueError, match="cell|pbc"):
        a.get_potential_energy()
    assert_unchanged(a, snap)


def test_open_far_atom_is_isolated():
    """An atom 5e5 or 1e12 Å away from an open cluster interacts with nothing."""
    a = crystal()
    a.pbc = False
    ref = a[1:]
    r = evaluate(ref, ("energy", "forces", "magnetic_forces"))
    for far in (5e5, 1e12):
        b = a.copy()
        b.positions[0] += [far, -far, 0.3 * far]
        got = evaluate(b, ("energy", "forces", "magnetic_forces"))
        assert got["energy"] == pytest.approx(r["energy"], rel=1e-13, abs=1e-13)
        np.testing.assert_allclose(got["forces"][1:], r["forces"], atol=1e-12)
        np.testing.assert_allclose(got["magnetic_forces"][1:], r["magnetic_forces"],
                                   atol=1e-12)
        assert not got["forces"][0].any() and not got["magnetic_forces"][0].any()


def test_huge_periodic_vector_is_like_an_open_direction():
    a = crystal()
    c = a.cell.array.copy()
    c[0, 0] = 1e8
    a.set_cell(c)
    got = evaluate(a.copy(), ("energy", "forces", "magnetic_forces"))
    b = a.copy()
    b.pbc = [False, True, True]
    ref = evaluate(b, ("energy", "forces", "magnetic_forces"))
    for p in ref:
        np.testing.assert_allclose(got[p], ref[p], rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("cells", [3, -1000, 1_000_000])
def test_atoms_outside_the_cell_equal_wrapped(cells):
    a = crystal()
    a.cell[0, 1] = 0.4  # triclinic
    a.positions[::3] += cells * a.cell[0] - 2 * cells * a.cell[2] + cells * a.cell[1]
    got = evaluate(a.copy())
    b = a.copy()
    b.wrap()
    ref = evaluate(b)
    # positions of size |cells|·7 Å carry rounding of that size into distances
    tol = 1e-11 * max(1.0, abs(cells))
    for p in ref:
        np.testing.assert_allclose(got[p], ref[p], rtol=tol, atol=tol)


@pytest.mark.parametrize("name", ["fcc", "bcc", "hcp", "triclinic", "tiny", "tiny2",
                                  "open", "slab"])
def test_sweep_search_finds_vesins_pairs(name):
    """The sweep used for boxes vesin cannot grid returns exactly vesin's pairs."""
    atoms = structures()[name]
    cache = NeighborCache(4.7, 0.3)
    pos = atoms.positions
    cell, pbc = atoms.cell.array, atoms.pbc
    i, j, s = cache._search(pos, cell, pbc)
    wrapped, shift = wrap_positions(pos, cell, pbc)
    i2, j2, s2 = sweep_pairs(wrapped, cell, pbc, 5.0)
    s2 = s2 + shift[i2] - shift[j2]
    key = lambda i, j, s: sorted(zip(i.tolist(), j.tolist(), map(tuple, s.tolist())))  # noqa: E731
    assert key(i, j, s) == key(i2, j2, s2)
    assert len(i) > 0


def test_separation_is_antisymmetric_bitwise():
    """d_ji = −d_ij exactly, so a pair at the cutoff is in both rows or neither."""
    rng = np.random.default_rng(3)
    pos = rng.uniform(-1e3, 1e3, size=(200, 3)) * rng.uniform(1e-3, 1, size=(200, 1))
    images = rng.uniform(-50, 50, size=(5, 3))
    from numba import njit

    @njit
    def both(pos, images, i, j, m):
        a = separation(pos, images, i, j, m)
        images2 = -images
        b = separation(pos, images2, j, i, m)
        return a, b

    for k in range(2000):
        i, j, m = rng.integers(200), rng.integers(200), rng.integers(5)
        a, b = both(pos, images, i, j, m)
        assert a[0] == -b[0] and a[1] == -b[1] and a[2] == -b[2] and a[3] == b[3]


def test_pair_at_the_cutoff_follows_r2_below_rc2():
    """A dimer exactly at the exchange cutoff: r² < rc² is false, no exchange;
    a hair inside, full exchange (LAMMPS's rule, in the calculator and both
    kernels' paths)."""
    from ase import Atoms

    for r, expect in ((4.0, 0.0), (np.nextafter(4.0, 0.0), None)):
        a = Atoms("Co2", positions=[[0, 0, 0], [r, 0, 0]])
        ase_spin.set_spins(a, [0, 0, 1])
        a.calc = SpinLatticeCalculator([Exchange(BetheSlater(*CO_BS), rc=4.0)])
        e = a.get_potential_energy()
        b = a.calc.get_magnetic_forces(a)
        if expect == 0.0:
            assert e == 0.0 and not b.any()
        else:
            assert e < 0.0 and b[0, 2] > 0.0 and b[1, 2] == b[0, 2]
