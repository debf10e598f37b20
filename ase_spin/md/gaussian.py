"""Gaussian random numbers drawn inside compiled, threaded kernels.

The baths need 5 Gaussian numbers per atom and step. numpy draws them on one
thread, a large share of a thermostatted step once the rest runs on every core
(``benchmarks/bench_langevin.py``; docs/benchmarks.md, "Thermostat (`Langevin`):
cost and sampling"). Here the
k-th number of a draw is a pure function of (key, k): a counter-based
generator (Salmon et al., SC'11, the idea behind Random123, JAX and numpy's own
Philox), so kernels draw the numbers they need where they need them, in any
order, on any number of threads, and get the same bits. Each draw takes a fresh
64-bit key from the integrator's numpy Generator, so a run is reproduced by
restoring that Generator's state.

- Bits: ``u_k = mix(mix(k φ) ⊕ key)``, ``mix`` the SplitMix64 finaliser
  (Steele, Lea & Flood, OOPSLA'14; Stafford's "variant 13" constants), φ the
  64-bit golden ratio: a bijective 64-bit hash applied twice, so distinct
  (key, k) give unrelated words.
- Gaussians: the ziggurat of Marsaglia & Tsang (J. Stat. Softw. 5, 2000) with 256
  layers, as numpy's own ``standard_normal``; its rare rejections take further
  words at counters k + a·2⁴⁰, a = 1, 2, ... (a draw has fewer than 2⁴⁰
  numbers).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np


__all__ = ["normal", "normals", "new_key"]

_LAYERS = 256
#: The ziggurat's base-strip edge and the common area of its layers (256 layers).
_R = 3.6541528853610088
_V = 0.00492867323399


def _tables():
    r"""Layer edges x₀ > x₁ = r > … > x₂₅₅ > x₂₅₆ = 0 with equal areas v:
    x_{i+1} = f⁻¹(v/x_i + f(x_i)), f(x) = e^{−x²/2}, x₀ = v/f(r) the width
    that gives the base strip (with its tail) area v. Layer i spans widths
    [0, x_i] and heights [f(x_i), f(x_{i+1})]. Returned: the quick-accept
    thresholds ⌊2⁵² x_{i+1}/x_i⌋, the scales x_i/2⁵², f(x_i) (257 values)."""
    f = lambda x: math.exp(-0.5 * x * x)  # noqa: E731
    x = np.zeros(_LAYERS + 1)
    x[0] = _V / f(_R)
    x[1] = _R
    for i in range(2, _LAYERS):
        x[i] = math.sqrt(-2.0 * math.log(_V / x[i - 1] + f(x[i - 1])))
    k = np.array([int(x[i + 1] / x[i] * 2.0**52) for i in range(_LAYERS)], dtype=np.uint64)
    w = x[:_LAYERS] / 2.0**52
    fx = np.array([f(v) for v in x])
    return k, w, fx


_K, _W, _F = _tables()
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_UNIT = 1.0 / 9007199254740992.0  # 2⁻⁵³


@nb.njit(cache=True, inline="always")
def _mix(z):
    z = (z ^ (z >> np.uint64(30))) * _M1
    z = (z ^ (z >> np.uint64(27))) * _M2
    return z ^ (z >> np.uint64(31))


@nb.njit(cache=True, inline="always")
def _bits(key, k):
    """The 64-bit word k of stream ``key``: mix(mix(k φ) ⊕ key)."""
    return _mix(_mix(np.uint64(k) * _GOLDEN) ^ key)


@nb.njit(cache=True, inline="always")
def _uniform(key, k):
    """A uniform number in [0, 1) from word k (its top 53 bits)."""
    return (_bits(key, k) >> np.uint64(11)) * _UNIT


@nb.njit(cache=True, inline="always")
def normal(key, k):
    """The standard normal number k of stream ``key`` (uint64): the ziggurat on
    word k; 8 low bits pick the layer, bit 8 the sign, the top 52 the abscissa
    x = u 2⁻⁵² x_layer; accepted at once if below x_{layer+1} (98.8% of words),
    else the tail (layer 0, Marsaglia's exponential method) or the wedge test
    f(x_i) + U (f(x_{i+1}) − f(x_i)) < f(x), with the next words at k + a·2⁴⁰."""
    step = np.int64(1) << 40
    k = np.int64(k)
    while True:
        r = _bits(key, k)
        k += step
        layer = r & np.uint64(0xFF)
        negative = (r >> np.uint64(8)) & np.uint64(1)
        u = r >> np.uint64(12)
        x = u * _W[layer]
        if u < _K[layer]:
            return -x if negative else x
        if layer == 0:
            while True:
                t = -math.log1p(-_uniform(key, k)) / _R
                y = -math.log1p(-_uniform(key, k + step))
                k += 2 * step
                if y + y > t * t:
                    return -(_R + t) if negative else _R + t
        if _F[layer] + _uniform(key, k) * (_F[layer + 1] - _F[layer]) < math.exp(-0.5 * x * x):
            return -x if negative else x
        k += step


@nb.njit(cache=True, inline="always")
def normals(key, k0, out):
    """out[j] = :func:`normal` (key, k0 + j) for every j of the 1-d array ``out``,
    the same bits. The quick-accept case of the ziggurat (98.8% of words) runs
    in a loop without branches, so that it runs on SIMD lanes (a loop calling
    :func:`normal`, with its rejection loop, stays scalar); the words it does
    not accept are marked NaN and redone one by one by :func:`normal`. This
    twin of :func:`normal` exists only for speed (``benchmarks/bench_langevin.py``;
    docs/benchmarks.md, "Why each fast path exists", the bath kernels on SIMD lanes)."""
    m = out.shape[0]
    rejected = 0
    for j in range(m):
        r = _bits(key, k0 + j)
        layer = r & np.uint64(0xFF)
        u = r >> np.uint64(12)
        x = u * _W[layer]
        accept = u < _K[layer]
        rejected += not accept
        x = -x if (r >> np.uint64(8)) & np.uint64(1) else x
        out[j] = x if accept else np.nan
    if rejected:
        for j in range(m):
            if np.isnan(out[j]):
                out[j] = normal(key, k0 + j)


def new_key(rng):
    """A fresh 64-bit stream key from the numpy Generator ``rng``."""
    return np.uint64(rng.bit_generator.random_raw())
