"""The counter-based Gaussian numbers of the baths (ase_spin.md.gaussian).

Tolerances are 5 standard errors of each estimator for the sample size (a
false alarm about once in 3·10⁶ runs per check), with fixed keys.
"""

import numba as nb
import numpy as np
import pytest
from scipy import stats

from ase_spin.md.gaussian import new_key, normals

N = 2_000_000


@nb.njit(cache=True)
def fill_normal(key, out, block=768):
    """out[k] = normal(key, k) for every k, drawn ``block`` numbers at a time
    (as the bath kernels draw them, each thread its own blocks)."""
    n = out.shape[0]
    for lo in range(0, n, block):
        normals(key, lo, out[lo:min(n, lo + block)])


@pytest.fixture(scope="module")
def sample():
    x = np.empty(N)
    fill_normal(np.uint64(20261124), x)
    return x


def test_moments(sample):
    """Mean 0, variance 1, fourth moment 3, sixth 15: standard errors
    √(1/N), √(2/N), √(96/N), √(10395 − 225)/√N."""
    x = sample
    assert abs(x.mean()) < 5 * np.sqrt(1 / N)
    assert abs(x.var() - 1) < 5 * np.sqrt(2 / N)
    assert abs((x**4).mean() - 3) < 5 * np.sqrt(96 / N)
    assert abs((x**6).mean() - 15) < 5 * np.sqrt((10395 - 225) / N)


def test_distribution_and_tails(sample):
    """Kolmogorov–Smirnov against the normal CDF (p > 1e-4), and the counts
    beyond 3 and 4 (the ziggurat's wedges and its tail strip, where an error
    in the tables would show): binomial, 5 standard errors."""
    assert stats.kstest(sample, "norm").pvalue > 1e-4
    for t in (1.0, 3.0, 3.6541528853610088, 4.0):
        p = 2 * stats.norm.sf(t)
        count = np.count_nonzero(np.abs(sample) > t)
        assert abs(count - N * p) < 5 * np.sqrt(N * p * (1 - p)), t


def test_no_correlation_between_neighbours_or_keys(sample):
    """Lag-1, lag-2 and cross-key correlations: standard error 1/√n."""
    x = sample
    for lag in (1, 2, 3):
        assert abs(np.corrcoef(x[:-lag], x[lag:])[0, 1]) < 5 / np.sqrt(N)
    y = np.empty(N)
    fill_normal(np.uint64(20261125), y)  # the next key: unrelated streams
    assert abs(np.corrcoef(x, y)[0, 1]) < 5 / np.sqrt(N)


def test_same_numbers_in_any_blocks():
    """Each number depends on (key, index) only: drawn in blocks of any size
    (a thread's share of a kernel), the same bits."""
    a = np.empty(15000)
    fill_normal(np.uint64(7), a)
    for block in (1, 5, 4096, 15000):
        b = np.empty(15000)
        fill_normal(np.uint64(7), b, block)
        assert np.array_equal(a, b), block


def test_keys_follow_the_generator():
    """Restoring the Generator's state gives the same keys (restarts)."""
    rng = np.random.default_rng(3)
    state = rng.bit_generator.state
    keys = [new_key(rng) for _ in range(3)]
    assert len(set(int(k) for k in keys)) == 3
    rng.bit_generator.state = state
    assert [new_key(rng) for _ in range(3)] == keys
