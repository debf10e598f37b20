"""The Bethe–Slater couplings' exp(−x) (exchange_geometry.exp_minus) and the
passes that take it a block of pairs at a time: within one ulp of the exact
exponential, and the same bits in the single-species pass (its exponential
fused into one loop with J and J'/r: exchange_geometry._bethe_slater_block,
serial or threaded) as from exp_minus and the formula pair by pair, NaN kept."""

import numba as nb
import numpy as np
import pytest

from ase_spin.neighbors import NeighborCache, separation
from ase_spin.scenes import fcc_cobalt
from ase_spin.terms import couplings
from ase_spin.terms import exchange_geometry as geometry

EXTENDED = np.finfo(np.longdouble).nmant >= 63  # x86's 80-bit long double


@nb.njit(cache=True)
def _exp_minus_all(x, out):
    geometry.exp_minus(x, out, np.empty(len(x), dtype=np.int64))


@nb.njit(cache=True)
def _one_pair_at_a_time(pos, row, nbr, image, images, rc2, p0, p1, p2, J, g, D):
    """J, J'/r and d of every pair: exp_minus over all of them, then the
    Bethe–Slater formula pair by pair."""
    x = np.empty(len(J))
    for i in range(len(row) - 1):
        for k in range(row[i], row[i + 1]):
            dx, dy, dz, r2 = separation(pos, images, i, nbr[k], image[k])
            D[k, 0] = dx
            D[k, 1] = dy
            D[k, 2] = dz
            x[k] = r2 * p2
    e = np.empty(len(J))
    geometry.exp_minus(x, e, np.empty(len(J), dtype=np.int64))
    for k in range(len(J)):
        r2 = D[k, 0] * D[k, 0] + D[k, 1] * D[k, 1] + D[k, 2] * D[k, 2]
        if r2 >= rc2:
            J[k] = 0.0
            g[k] = 0.0
        else:
            J[k], g[k] = geometry._bethe_slater(p0, p1, p2, x[k], e[k])


def test_exp_minus_is_within_one_ulp_of_the_exact_value():
    rng = np.random.default_rng(3)
    x = np.concatenate([rng.random(200_000) * 8.0, rng.random(50_000) * 700.0,
                        rng.random(10_000) * 1e-6, np.linspace(0.0, 700.0, 20_001)])
    got = np.empty_like(x)
    _exp_minus_all(x, got)
    if EXTENDED:
        exact = np.exp(-x.astype(np.longdouble))
        ulps = np.abs(got - exact) / np.spacing(exact.astype(float))
    else:  # no wider type here: against the C library's exp (itself within 0.51)
        ulps = np.abs(got - np.exp(-x)) / np.spacing(np.exp(-x))
    bound = 1.0 if EXTENDED else 1.6
    assert ulps.max() <= bound, ulps.max()
    # and it is not the library's exp in disguise (a test that could not fail)
    assert np.mean(got != np.exp(-x)) < 0.2


def test_exp_minus_at_the_edges():
    x = np.array([0.0, 708.0, 708.5, 1e4, np.inf, np.nan])
    got = np.empty_like(x)
    _exp_minus_all(x, got)
    assert got[0] == 1.0
    assert got[1] == pytest.approx(np.exp(-708.0), rel=1e-15)
    assert np.all(got[2:5] == 0.0)  # below 2^-1021: flushed to zero
    assert np.isnan(got[5])  # a NaN distance stays NaN (no silent NaN)


@pytest.mark.parametrize("twin", ["serial", "parallel"])
@pytest.mark.parametrize("stored", [False, True])
@pytest.mark.parametrize("mean", [False, True])
@pytest.mark.parametrize("J3", [1.4885, 0.1])  # 0.1 Å: exp(−r²/J3²) underflows inside rc
def test_blocked_geometry_is_the_one_pair_formula_to_the_bit(twin, stored, mean, J3):
    atoms = fcc_cobalt(4)  # 256 atoms: several blocks of the pass
    rng = np.random.default_rng(5)
    pos = atoms.positions + rng.normal(scale=0.15, size=atoms.positions.shape)
    pos[17] = np.nan  # its pairs must come out NaN, not zero
    cache = NeighborCache(4.0, 0.3)
    cache.update(np.nan_to_num(pos), atoms.cell.array, atoms.pbc)
    pairs = cache.sublist(4.3, half=True)  # pairs on both sides of rc = 4
    m = pairs.row[-1]
    bs = couplings.BetheSlater(0.0446928, 0.003496, J3)
    params = (16.0, float(couplings.FORM_BETHE_SLATER), *bs._params)
    J0, g0, D = np.empty(m), np.empty(m), np.empty((m, 3))
    _one_pair_at_a_time(pos, pairs.row, pairs.j, pairs.image, pairs.images, params[0],
                        *params[2:], J0, g0, D)
    other = rng.random(m) if mean else np.zeros(0)
    J = np.full(m, -1.0)
    g = np.full(m, -1.0) if not stored else np.zeros(0)
    G = np.full((m, 3), -1.0) if stored else np.zeros((0, 3))
    Jbar = np.full(m, -1.0) if mean else np.zeros(0)
    kernel = getattr(geometry.geometry_single, twin)
    kernel(pos, pairs.row, pairs.j, pairs.image, pairs.images, *params, J, g, G, other, Jbar)
    same = np.testing.assert_array_equal  # NaN equals NaN here
    same(J, J0)
    if stored:
        same(G, g0[:, None] * D)
    else:
        same(g, g0)
    if mean:
        same(Jbar, 0.5 * (other + J0))
    nan_pairs = (pairs.i == 17) | (pairs.j == 17)
    assert nan_pairs.any() and np.isnan(J[nan_pairs]).all()
    outside = ~nan_pairs & (np.einsum("ij,ij->i", D, D) >= 16.0)
    assert outside.any() and (J[outside] == 0.0).all()
    inside = ~nan_pairs & ~outside
    r = np.sqrt(np.einsum("ij,ij->i", D[inside], D[inside]))
    if J3 > 1.0:
        assert inside.sum() > 1000 and (J[inside] != 0.0).all()
        # the C library's exp gives the same couplings to an ulp or so
        np.testing.assert_allclose(J[inside], bs.values(r)[0], rtol=1e-14)
    else:  # beyond r = 26.6 J3 (x > 708) exp(−x) is flushed to zero
        assert (J[inside][r > 2.67] == 0.0).all() and (J[inside][r > 2.67] == 0.0).sum() > 100


@pytest.mark.parametrize("twin", ["serial"])  # (its threaded twin: the same block function)
def test_species_table_pass_equals_the_one_species_pass_to_the_bit(twin):
    """Two species with one coupling: the table-driven pass (its exponentials
    taken a block at a time, _exp_arguments) gives the one-species bits."""
    atoms = fcc_cobalt(4)
    rng = np.random.default_rng(8)
    pos = atoms.positions + rng.normal(scale=0.1, size=atoms.positions.shape)
    cache = NeighborCache(4.0, 0.3)
    cache.update(pos, atoms.cell.array, atoms.pbc)
    pairs = cache.sublist(4.3, half=True)
    m = pairs.row[-1]
    bs = couplings.BetheSlater(0.0446928, 0.003496, 1.4885)
    params = (16.0, float(couplings.FORM_BETHE_SLATER), *bs._params)
    table = np.zeros((2, 2, 5))
    table[:, :] = params
    table[1, 1, couplings.FORM] = couplings.FORM_OFF  # one species pair switched off: J = 0 there
    types = np.arange(len(pos)) % 2
    J1, g1, J2, g2 = np.empty(m), np.empty(m), np.empty(m), np.empty(m)
    args = (pos, pairs.row, pairs.j, pairs.image, pairs.images)
    none = (np.zeros((0, 3)), np.zeros(0), np.zeros(0))
    getattr(geometry.geometry_single, twin)(*args, *params, J1, g1, *none)
    getattr(geometry.geometry_kernel, twin)(*args, types, table, J2, g2, *none)
    off = (types[pairs.i] == 1) & (types[pairs.j] == 1)
    np.testing.assert_array_equal(J2[~off], J1[~off])
    np.testing.assert_array_equal(g2[~off], g1[~off])
    assert (J2[off] == 0.0).all() and (J1[off] != 0.0).any()
