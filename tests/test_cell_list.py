"""The compiled cell-list search against vesin and ASE: the same pairs (i, j, S)
on random, triclinic, small periodic, open and mixed cells, atoms outside the
cell, and the half list and its sub-lists consistent with the full list."""

import numpy as np
import pytest
import vesin
from ase import Atoms
from ase.neighborlist import neighbor_list

from ase_spin.neighbors import NeighborCache, sweep_pairs, wrap_positions

from conftest import structures


def triples(i, j, s):
    return sorted(zip(np.asarray(i).tolist(), np.asarray(j).tolist(),
                      map(tuple, np.asarray(s).tolist())))


def random_cell(rng, n, pbc, triclinic, size):
    cell = np.diag(rng.uniform(0.8, 1.2, 3) * size)
    if triclinic:
        cell += rng.uniform(-0.3, 0.3, (3, 3)) * size * (1 - np.eye(3))
    scaled = rng.uniform(0.0, 1.0, (n, 3))
    atoms = Atoms(f"Co{n}", cell=cell, scaled_positions=scaled, pbc=pbc)
    return atoms


CASES = [
    # (n atoms, pbc, triclinic, cell size Å, cutoff Å)
    (300, True, False, 14.0, 4.1),
    (300, True, True, 14.0, 4.1),
    (40, True, True, 5.0, 4.7),       # cell smaller than twice the cutoff
    (3, True, True, 2.6, 5.0),         # atoms see many images of each other and themselves
    (200, False, False, 15.0, 3.7),
    (200, [True, False, True], True, 13.0, 4.4),
    (120, [False, True, False], True, 9.0, 5.3),
]


@pytest.mark.parametrize("case", range(len(CASES)))
def test_cell_list_matches_vesin_and_ase(case):
    n, pbc, triclinic, size, cutoff = CASES[case]
    rng = np.random.default_rng(case)
    atoms = random_cell(rng, n, pbc, triclinic, size)
    pos, cell, pbc = atoms.positions, atoms.cell.array, atoms.pbc
    cache = NeighborCache(cutoff - 0.3, skin=0.3)
    got = triples(*cache._search(pos, cell, pbc))
    assert len(got) > 0
    i, j, s = vesin.NeighborList(cutoff=cutoff, full_list=True).compute(
        pos, cell, pbc, "ijS")
    assert got == triples(i, j, s)
    i, j, s = neighbor_list("ijS", atoms, cutoff)
    assert got == triples(i, j, s)


def test_atoms_outside_the_cell_get_shifted_images():
    """Atoms a few and very many cells outside: the pairs of the wrapped atoms,
    with the shifts corrected by each atom's whole-cell offset."""
    rng = np.random.default_rng(5)
    atoms = random_cell(rng, 60, True, True, 9.0)
    pos = atoms.positions.copy()
    offsets = rng.integers(-3, 4, (60, 3))
    offsets[::7] = rng.integers(-10**6, 10**6, (len(offsets[::7]), 3))
    moved = pos + offsets @ atoms.cell.array
    cache = NeighborCache(4.5, skin=0.3)
    i, j, s = cache._search(moved, atoms.cell.array, atoms.pbc)
    i0, j0, s0 = cache._search(pos, atoms.cell.array, atoms.pbc)
    assert triples(i, j, s + offsets[j] - offsets[i]) == triples(i0, j0, s0)


@pytest.mark.parametrize("name", ["fcc", "triclinic", "tiny", "tiny2", "open", "slab"])
def test_cell_list_matches_the_sweep(name):
    atoms = structures()[name]
    pos, cell, pbc = atoms.positions, atoms.cell.array, atoms.pbc
    got = NeighborCache(4.7, 0.3)._search(pos, cell, pbc)
    wrapped, shift = wrap_positions(pos, cell, pbc)
    i, j, s = sweep_pairs(wrapped, cell, pbc, 5.0)
    assert triples(*got) == triples(i, j, s + shift[i] - shift[j])


def test_half_list_and_sublists_agree_with_the_full_list():
    """The kept half list is the full list's pairs with i < j (or j = i and a
    positive shift), rows sorted by (j, S); sub-lists (half and full, shorter
    cutoff, masked) are the full list filtered at their cutoff + the fine skin,
    in the same order."""
    rng = np.random.default_rng(11)
    atoms = random_cell(rng, 250, True, True, 13.0)
    cache = NeighborCache(4.6, skin=0.4)
    cache.update(atoms.positions, atoms.cell.array, atoms.pbc)
    full = cache.pairs
    i, j, s = full.i, full.j, cache._ints[full.image]
    # rows sorted by (j, S) lexicographically
    keys = np.column_stack([i, j, s])
    assert (np.lexsort(keys.T[::-1]) == np.arange(len(i))).all()
    positive = (s[:, 0] > 0) | ((s[:, 0] == 0) & ((s[:, 1] > 0) | ((s[:, 1] == 0) & (s[:, 2] > 0))))
    first = (j > i) | ((j == i) & positive)
    half = cache.half
    assert (half.i == i[first]).all() and (half.j == j[first]).all()
    assert (half.image == full.image[first]).all()
    assert cache.sublist(4.6, half=True) is half
    d = np.linalg.norm(atoms.positions[j] + full.shift - atoms.positions[i], axis=1)
    mask = rng.uniform(size=len(atoms)) < 0.7
    for half_list in (False, True):
        for m in (None, mask):
            sub = cache.sublist(3.5, m, half=half_list)
            keep = d < 3.5 + cache.fine_skin
            if half_list:
                keep &= first
            if m is not None:
                keep &= m[i] & m[j]
            assert sub.half == half_list
            assert (sub.i == i[keep]).all() and (sub.j == j[keep]).all()
            assert (sub.image == full.image[keep]).all()
            assert sub is cache.sublist(3.5, m, half=half_list)


def test_empty_and_single_atom_lists():
    cache = NeighborCache(3.0, 0.3)
    assert cache.update(np.zeros((1, 3)), np.zeros((3, 3)), False)
    assert len(cache.half) == 0 and len(cache.pairs) == 0
    far = np.array([[0.0, 0, 0], [100.0, 0, 0]])
    assert cache.update(far, np.zeros((3, 3)), False)
    assert len(cache.pairs) == 0


def test_a_rebuild_inside_a_collective_step_changes_nothing():
    """A neighbour list rebuilt inside a CollectivePRK step (the operators at q
    prepared anew on the new list, their old buffers given up) gives the same
    trajectory, bit for bit, as a run without the rebuild: the lists differ
    only by pairs beyond every cutoff, which add exact zeros."""
    from ase import units

    from ase_spin import CollectivePRK
    from ase_spin.scenes import fcc_cobalt

    finals = []
    for rebuild in (False, True):
        atoms = fcc_cobalt(3)
        dyn = CollectivePRK(atoms, 0.1 * units.fs)
        dyn.run(3)
        builds = dyn.ev.neighbors.builds
        if rebuild:
            dyn.ev.neighbors._reference += dyn.ev.neighbors.skin
        dyn.run(3)
        assert dyn.ev.neighbors.builds == builds + rebuild
        finals.append(np.concatenate([atoms.positions, atoms.get_momenta(),
                                      atoms.arrays["initial_magmoms"]]))
    assert finals[0].tobytes() == finals[1].tobytes()


@pytest.mark.parametrize("integrator, skin", [("Langevin", 0.1), ("CollectivePRK", 0.03)])
def test_a_run_does_not_depend_on_the_fine_skin(integrator, skin, monkeypatch):
    """Sub-lists filtered at the fine skin (half the skin, filtered again every
    few steps here: a 0.1 Å skin at 600 K and 1 fs, the exchange cutoff through
    fcc's third shell) hold every pair within the cutoff after every step, and
    differ from sub-lists at the whole skin (as before the fine skin) by pairs
    beyond it, which add exact zeros: the same trajectory to round-off. (Not
    to the bit: the operators at q prepared anew at a filtering have J(q)
    where the one kept from the last step has J at that step's last q̃ but
    one, within 1e-15 Å of it, as after a rebuild.) With a 0.03 Å skin the
    atoms move farther in a step than a quarter of it: the lists filtered at
    a step's end must hold at its start too."""
    from ase import units

    import ase_spin
    from ase_spin.neighbors import cache as neighbor_cache
    from ase_spin.scenes import fcc_cobalt, fcc_cobalt_terms

    lj, exchange = fcc_cobalt_terms()
    exchange = ase_spin.Exchange(exchange.coupling, rc=4.34)
    finals = []
    for fraction in (neighbor_cache.FINE_SKIN, 1.0):
        monkeypatch.setattr(neighbor_cache, "FINE_SKIN", fraction)
        atoms = fcc_cobalt(3, temperature_K=600.0)
        atoms.calc = ase_spin.SpinLatticeCalculator([lj, exchange], skin=skin)
        if integrator == "Langevin":
            dyn = ase_spin.Langevin(atoms, 1 * units.fs, 600.0, spin_damping=0.1,
                                    friction=0.01 / units.fs, rng=5)
        else:
            dyn = ase_spin.CollectivePRK(atoms, 1 * units.fs)
        nbl = None

        def every_pair_is_listed():
            sub = dyn.ev.neighbors.sublist(4.34, half=True)
            listed = set(zip(sub.i, sub.j, sub.image))
            i, j, S = neighbor_list("ijS", atoms, 4.34)
            keys = {tuple(x): k for k, x in enumerate(dyn.ev.neighbors._ints)}
            first = i < j
            assert {(a, b, keys[tuple(s)]) for a, b, s in zip(i[first], j[first], S[first])} <= listed

        dyn.attach(every_pair_is_listed, interval=1)
        dyn.run(40)
        nbl = dyn.ev.neighbors
        assert nbl.fine_skin == pytest.approx(skin * fraction)
        assert (nbl.refilters > 2) == (fraction < 1.0) and nbl.builds > 1
        finals.append((atoms.positions.copy(), atoms.arrays["initial_magmoms"].copy()))
    for a, b in zip(*finals):
        assert np.abs(a - b).max() < 1e-11
