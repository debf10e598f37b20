import numpy as np
import pytest
from ase.build import bulk
from ase.neighborlist import neighbor_list

from ase_spin.neighbors import NeighborCache


def pair_set(pairs, positions, cutoff):
    i = pairs.i
    d = np.linalg.norm(positions[pairs.j] + pairs.shift - positions[i], axis=1)
    keep = d < cutoff
    return sorted(zip(i[keep], pairs.j[keep], np.round(d[keep], 9)))


def ase_pair_set(atoms, cutoff):
    i, j, d = neighbor_list("ijd", atoms, cutoff)
    return sorted(zip(i, j, np.round(d, 9)))


@pytest.mark.parametrize("pbc", [True, False, [True, False, True]])
def test_pairs_match_ase_within_cutoff_while_atoms_move_inside_the_skin(pbc):
    atoms = bulk("Co", "fcc", a=3.54, cubic=True).repeat(3)
    atoms.pbc = pbc
    cache = NeighborCache(4.7, skin=0.6)
    rng = np.random.default_rng(0)
    assert cache.update(atoms.positions, atoms.cell.array, atoms.pbc)
    for step in range(6):
        # each move stays well inside skin/2 of the reference positions
        moved = atoms.copy()
        moved.positions += rng.uniform(-0.15, 0.15, size=moved.positions.shape) / np.sqrt(3)
        rebuilt = cache.update(moved.positions, moved.cell.array, moved.pbc)
        assert not rebuilt
        assert pair_set(cache.pairs, moved.positions, 4.7) == ase_pair_set(moved, 4.7)
    assert cache.builds == 1


def test_rebuild_when_an_atom_moves_more_than_half_the_skin_or_the_cell_changes():
    atoms = bulk("Co", "fcc", a=3.54, cubic=True).repeat(2)
    cache = NeighborCache(4.0, skin=0.4)
    cache.update(atoms.positions, atoms.cell.array, atoms.pbc)
    p = atoms.positions.copy()
    p[3, 0] += 0.19
    assert not cache.update(p, atoms.cell.array, atoms.pbc)
    p[3, 0] += 0.02
    assert cache.update(p, atoms.cell.array, atoms.pbc)
    assert cache.update(p, atoms.cell.array * 1.001, atoms.pbc)
    assert cache.update(p, atoms.cell.array * 1.001, [True, True, False])
    assert cache.builds == 4


def test_sublist_restricts_cutoff_and_mask():
    atoms = bulk("Co", "fcc", a=3.54, cubic=True).repeat(2)
    atoms.rattle(0.05, seed=3)
    cache = NeighborCache(4.7, skin=0.3)
    cache.update(atoms.positions, atoms.cell.array, atoms.pbc)
    mask = np.arange(len(atoms)) % 3 != 0
    sub = cache.sublist(4.0, mask)
    assert sub is cache.sublist(4.0, mask)
    assert mask[sub.i].all() and mask[sub.j].all()
    ref = [(i, j, d) for i, j, d in ase_pair_set(atoms, 4.0) if mask[i] and mask[j]]
    assert pair_set(sub, atoms.positions, 4.0) == ref
