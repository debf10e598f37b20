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


def test_sublists_at_the_fine_skin_hold_every_pair_within_their_cutoff_as_atoms_move():
    """Sub-lists are filtered at cutoff + fine skin (half the skin) and filtered
    again once an atom has moved more than half the fine skin: at every step of a
    random walk they hold exactly the pairs ASE finds within their cutoff, with
    fewer pairs than a sub-list at cutoff + skin (fcc Co's third shell, 4.34 Å,
    is inside 4.0 + 0.6, mostly not inside 4.0 + 0.3), and the list is filtered
    again before it is rebuilt."""
    atoms = bulk("Co", "fcc", a=3.54, cubic=True).repeat(3)
    atoms.rattle(0.02, seed=1)
    cache = NeighborCache(4.7, skin=0.6)
    assert cache.fine_skin == 0.3
    cache.update(atoms.positions, atoms.cell.array, atoms.pbc)
    rng = np.random.default_rng(2)
    events = []
    for step in range(60):
        atoms.positions += rng.uniform(-0.03, 0.03, size=atoms.positions.shape)
        refilters, builds = cache.refilters, cache.builds
        changed = cache.update(atoms.positions, atoms.cell.array, atoms.pbc)
        assert changed == (cache.refilters > refilters or cache.builds > builds)
        if changed:
            events.append("build" if cache.builds > builds else "refilter")
        sub = cache.sublist(4.0)
        assert pair_set(sub, atoms.positions, 4.0) == ase_pair_set(atoms, 4.0)
        assert pair_set(cache.pairs, atoms.positions, 4.7) == ase_pair_set(atoms, 4.7)
        full = cache.pairs  # at the filtering positions: within 4.3, not 4.6
        ref = cache.fine_reference
        d = np.linalg.norm(ref[full.j] + full.shift - ref[full.i], axis=1)
        assert len(sub) == np.count_nonzero(d < 4.3) < np.count_nonzero(d < 4.6)
    assert events[:1] == ["refilter"] and "build" in events
    # the list itself still reaches cutoff + skin: the third shell is in it
    assert len(cache.half) > 21 * len(atoms)


def test_a_sublist_filtered_at_the_end_of_a_step_holds_at_its_start():
    """``also``: the sub-lists filtered at a step's end q̃ must hold at its
    start q too (CollectivePRK prepares the operators at q on them). Atom 1
    moves 0.21 Å away from atom 0, which moves 0.15 Å the other way: more than
    half the fine skin (a filtering, not a rebuild); the pair, 3.95 Å apart at
    q, is 4.31 Å apart at q̃, beyond 4.0 + 0.3."""
    # atom 2 is left out of the sub-list 4.31 Å from atom 0: it holds for
    # moves up to 0.155 Å
    q = np.array([[10.0, 10.0, 10.0], [13.95, 10.0, 10.0], [10.0, 14.31, 10.0]])
    qt = q.copy()
    qt[0, 0] -= 0.15
    qt[1, 0] += 0.21
    cell, pbc = np.zeros((3, 3)), np.zeros(3, dtype=bool)
    found = []
    for also in (q, None):
        cache = NeighborCache(4.7, skin=0.6)
        cache.update(q, cell, pbc)
        assert (0, 1) in set(zip(cache.sublist(4.0).i, cache.sublist(4.0).j))
        assert cache.fine_radius == pytest.approx(0.155)
        assert cache.update(qt, cell, pbc, also=also)
        assert cache.builds == 1 and cache.refilters == 1
        sub = cache.sublist(4.0)
        found.append((0, 1) in set(zip(sub.i, sub.j)))
    assert found == [True, False]


def test_update_reports_a_filtering_only_when_a_sublist_was_dropped():
    """Moving past half the fine skin (past the sub-lists' radius, if any)
    moves where sub-lists are filtered; it reports a change (True,
    ``refilters``) only if a sub-list was dropped. A sub-list holds for half
    the gap between its cutoff and the closest pair it left out. The list
    itself is rebuilt at half the skin from its build, wherever the sub-lists
    were filtered."""
    atoms = bulk("Co", "fcc", a=3.54, cubic=True).repeat(2)
    cell, pbc = atoms.cell.array, atoms.pbc
    cache = NeighborCache(4.0, skin=0.4)
    cache.update(atoms.positions, cell, pbc)
    p = atoms.positions.copy()
    p[3, 0] += 0.15  # beyond half the fine skin (0.1)
    assert cache.sublist(4.0, half=True) is cache.half  # the list itself: nothing to filter
    assert not cache.update(p, cell, pbc) and cache.refilters == 0
    assert np.array_equal(cache.fine_reference, p)
    assert np.array_equal(cache.reference, atoms.positions)
    sub = cache.sublist(3.0)
    p[3, 0] += 0.04
    assert not cache.update(p, cell, pbc)  # 0.04 from the filtering, 0.19 from the build
    p[3, 0] += 0.02
    assert cache.update(p, cell, pbc) and cache.builds == 2  # 0.21 from the build
    assert cache.sublist(3.0) is not sub
    full = cache.pairs
    d = np.linalg.norm(p[full.j] + full.shift - p[full.i], axis=1)
    # half the gap between the cutoff and the closest pair left out
    assert cache.fine_radius == pytest.approx(0.5 * (d[d >= 3.2].min() - 3.0))
    nearest = d[d > 3.45].min()  # a sub-list leaving it out by 1 mÅ: 0.1005 Å
    sub = cache.sublist(nearest - 0.201)
    assert cache.fine_radius == pytest.approx(0.1005)
    p[5, 1] -= 0.11
    assert cache.update(p, cell, pbc) and (cache.builds, cache.refilters) == (2, 1)
    assert cache.sublist(nearest - 0.201) is not sub
    assert cache.sublist(4.0, half=True) is cache.half
    with pytest.raises(ValueError, match="fine_skin"):
        NeighborCache(4.0, skin=0.4, fine_skin=0.5)
