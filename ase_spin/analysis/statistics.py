r"""Averages of correlated series with honest errors: blocking analysis
(Flyvbjerg and Petersen 1989) for means, block jackknife for quantities
derived from several means (susceptibility, specific heat, Binder cumulant),
and T_C from the crossings of Binder cumulants of two or three sizes.

Successive samples of a Markov chain or a trajectory are correlated: the
naive standard error σ/√n underestimates the error by √(2τ) (τ the
integrated autocorrelation time in samples). Blocking averages neighbouring
pairs again and again; the naive error of the block means grows until the
blocks are longer than τ and then stays on a plateau, which is the error.

The integrated autocorrelation time itself (how many samples make one
independent one) comes from the autocorrelation function with Sokal's
automatic window: :func:`autocorrelation_time`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..validate import real_array, warn_user

__all__ = ["Estimate", "block_average", "blocking_levels", "jackknife", "binder_crossing",
           "autocorrelation_time", "MIN_BLOCKS"]

#: fewest blocks a blocking level or a jackknife may have: the error of an
#: error from b blocks is about 1/√(2b) of it
MIN_BLOCKS = 16


@dataclass(frozen=True)
class Estimate:
    """A value and its standard error (``value ± error``)."""

    value: float
    error: float

    def __iter__(self):
        return iter((self.value, self.error))

    def __format__(self, spec):
        spec = spec or ".6g"
        return f"{self.value:{spec}} ± {self.error:.2g}"

    def __str__(self):
        return format(self)


def _series(x, what="series"):
    x = real_array(x, what)
    if x.ndim == 0 or len(x) < 2:
        raise ValueError(f"{what} needs at least 2 samples, got {x.size}")
    if not np.isfinite(x).all():
        raise ValueError(f"{what} has non-finite samples")
    return x


def blocking_levels(x):
    """The naive standard error of the mean at each blocking level: level k
    averages blocks of 2^k samples, error_k = σ_k/√(n_k − 1) with σ_k the
    standard deviation of the n_k block means, and the error of that error,
    error_k/√(2(n_k − 1)). Returns (block lengths, errors, errors of errors),
    the levels with at least 2 blocks, for a series of shape (n,) or (n, m)
    (each column apart)."""
    x = _series(x)
    blocks = x.copy()
    lengths, errors, spread = [], [], []
    length = 1
    while len(blocks) >= 2:
        n = len(blocks)
        e = blocks.std(axis=0) / np.sqrt(n - 1)
        lengths.append(length)
        errors.append(e)
        spread.append(e / np.sqrt(2.0 * (n - 1)))
        blocks = 0.5 * (blocks[: n // 2 * 2: 2] + blocks[1: n // 2 * 2: 2])
        length *= 2
    return np.array(lengths), np.array(errors), np.array(spread)


def block_average(x):
    """Mean of a correlated series and its standard error by blocking
    (module docstring): the error of the first level from which no later
    level with at least :data:`MIN_BLOCKS` blocks lies above it by more than
    twice its own statistical error (the plateau); a series too short for a
    plateau gives the error of its last level with :data:`MIN_BLOCKS` blocks
    (then an underestimate if τ is not short against it). (n,) gives an
    :class:`Estimate`; (n, m) arrays of values and errors per column."""
    x = _series(x)
    lengths, errors, spread = blocking_levels(x)
    n = len(x)
    usable = np.array([n // length >= MIN_BLOCKS for length in lengths])
    if not usable.any():
        usable[0] = True
    errors, spread = errors[usable], spread[usable]
    flat = errors.reshape(len(errors), -1)
    flat_spread = spread.reshape(len(spread), -1)
    chosen = np.empty(flat.shape[1])
    for c in range(flat.shape[1]):
        e, d = flat[:, c], flat_spread[:, c]
        pick = len(e) - 1
        for k in range(len(e)):
            if np.all(e[k + 1:] <= e[k] + 2.0 * d[k + 1:]):
                pick = k
                break
        chosen[c] = e[pick]
    mean = x.mean(axis=0)
    if x.ndim == 1:
        return Estimate(float(mean), float(chosen[0]))
    return mean, chosen.reshape(mean.shape)


def autocorrelation_time(x, c=5.0):
    r"""The integrated autocorrelation time of a stationary series (n,), in
    samples, with its statistical error (Sokal's automatic windowing: A. D.
    Sokal, *Monte Carlo methods in statistical mechanics*, Cargèse lectures
    1996; Madras and Sokal, J. Stat. Phys. 50, 109 (1988)):

    .. math:: \tau_{\rm int} = \frac12 + \sum_{t=1}^{W} \rho(t),
              \qquad \sigma^2(\tau_{\rm int}) \approx \frac{2(2W+1)}{n}\,\tau_{\rm int}^2,

    ρ(t) = C(t)/C(0) the normalised autocorrelation, C(t) = (1/n) Σ_i
    (x_i − x̄)(x_{i+t} − x̄) (by FFT), and W the smallest window with
    W ≥ c τ_int(W) (``c`` = 5: the window's bias, −τ e^{−W/τ} for an
    exponential decay, is then −0.7 % of τ). In this convention the variance of the mean
    of n samples is 2 τ_int var(x)/n (τ_int = 1/2 for independent samples;
    (1 + φ)/(2(1 − φ)) for an AR(1) series x_t = φ x_{t−1} + noise), so a
    standard error σ of ⟨x⟩ needs n = 2 τ_int var(x)/σ² samples.

    Returns an :class:`Estimate`. Warns (the value then probably an
    underestimate, its error too small) if no window satisfies the condition
    or the series is shorter than 50 τ_int."""
    x = _series(x)
    if x.ndim != 1:
        raise ValueError(f"autocorrelation_time takes a 1D series, got shape {x.shape}")
    if isinstance(c, bool) or not np.isfinite(c) or c <= 0:
        raise ValueError(f"c must be a positive number, got {c!r}")
    n = len(x)
    d = x - x.mean()
    if not np.any(d):
        raise ValueError("the series is constant: no autocorrelation to measure")
    size = 1 << int(2 * n - 1).bit_length()  # zero padding: no wrap-around
    f = np.fft.rfft(d, size)
    acf = np.fft.irfft(f * np.conj(f), size)[:n]
    rho = acf / acf[0]
    taus = np.cumsum(rho) - 0.5  # τ(W) = 1/2 + Σ_{t=1}^{W} ρ(t), W = 0, 1, ...
    windows = np.arange(n)
    ok = windows >= c * taus
    if ok.any():
        W = int(np.argmax(ok))
    else:
        W = n - 1
    tau = float(taus[W])
    if not ok.any() or n < 50 * tau:
        warn_user(f"the series of {n} samples is too short for its autocorrelation time "
                  f"(τ_int ≈ {tau:.3g} samples; at least 50 τ_int needed): τ_int is probably "
                  "underestimated")
    return Estimate(tau, tau * float(np.sqrt(2.0 * (2 * W + 1) / n)))


def jackknife(function, *series, blocks=32):
    """A quantity derived from averages of series sampled together, with its
    block-jackknife error: ``function(*columns)`` takes the samples of each
    series (arrays of the same length) and returns a number (e.g.
    ``lambda e: e.var() / T**2``); the series are cut into ``blocks``
    contiguous blocks (each should be longer than the autocorrelation time:
    :func:`block_average` tells it), and

    .. math:: \\sigma^2 = \\frac{b-1}{b}\\sum_{k=1}^{b}(\\theta_{(k)} - \\bar\\theta)^2,

    θ_(k) the quantity without block k. Returns an :class:`Estimate` of
    ``function`` on the whole series."""
    if not series:
        raise ValueError("jackknife needs at least one series")
    data = [_series(s, "jackknife series") for s in series]
    n = len(data[0])
    if any(len(d) != n for d in data):
        raise ValueError(f"the series must have the same length, got {[len(d) for d in data]}")
    if isinstance(blocks, bool) or not isinstance(blocks, (int, np.integer)) or blocks < 2:
        raise ValueError(f"blocks must be an integer >= 2, got {blocks!r}")
    blocks = int(min(blocks, n))
    edges = np.linspace(0, n, blocks + 1).astype(int)
    keep = np.ones(n, dtype=bool)
    values = np.empty(blocks)
    for k in range(blocks):
        keep[:] = True
        keep[edges[k]:edges[k + 1]] = False
        values[k] = function(*(d[keep] for d in data))
    whole = float(function(*data))
    error = float(np.sqrt((blocks - 1) / blocks * ((values - values.mean()) ** 2).sum()))
    return Estimate(whole, error)


def binder_crossing(temperatures, cumulants, errors=None, degree=None, samples=400, seed=0):
    """T_C from where the Binder cumulants U_L(T) of different sizes cross.

    ``temperatures``: (m,) increasing; ``cumulants``: a mapping size L ->
    U_L at those temperatures (or a list of (m,) arrays), ``errors`` the same
    for their standard errors. For every pair of sizes, U_L1 − U_L2 is fitted
    by a straight line (least squares, weighted by the errors) through the
    temperatures, and its zero taken; the pairs' crossings are averaged. The
    error comes from ``samples`` redraws of every U within its errors (normal
    noise, a numpy Generator seeded with ``seed``): the spread of the mean
    crossing. Returns (:class:`Estimate` of T_C, list of the pairs'
    crossings). ValueError if a pair's difference does not change sign
    within the temperatures given (no crossing there)."""
    T = _series(temperatures, "temperatures")
    if T.ndim != 1 or not np.all(np.diff(T) > 0):
        raise ValueError("temperatures must be a 1D increasing array")
    curves = list(cumulants.values()) if isinstance(cumulants, dict) else list(cumulants)
    if len(curves) < 2:
        raise ValueError("binder_crossing needs the cumulants of at least two sizes")
    U = np.array([real_array(c, "cumulants") for c in curves])
    if U.shape != (len(curves), len(T)):
        raise ValueError(f"each cumulant curve needs {len(T)} values, got shape {U.shape}")
    if errors is None:
        dU = np.full_like(U, 1e-3)
    else:
        errs = list(errors.values()) if isinstance(errors, dict) else list(errors)
        dU = np.array([real_array(e, "errors") for e in errs])
        if dU.shape != U.shape:
            raise ValueError(f"errors must have the shape of the cumulants {U.shape}")
        dU = np.where(dU > 0, dU, 1e-12)
    pairs = [(a, b) for a in range(len(U)) for b in range(a + 1, len(U))]

    if degree is None:
        degree = 2 if len(T) >= 3 else 1
    if isinstance(degree, bool) or degree not in (1, 2) or degree >= len(T):
        raise ValueError(f"degree must be 1 or 2 and below the number of temperatures "
                         f"({len(T)}), got {degree!r}")
    centre, scale = T.mean(), T.max() - T.min()
    x = (T - centre) / scale  # a well-conditioned fit

    def crossings(u):
        out = []
        for a, b in pairs:
            d = u[a] - u[b]
            w = np.sqrt(1.0 / (dU[a] ** 2 + dU[b] ** 2))
            slope, intercept = np.polyfit(x, d, 1, w=w)
            guess = -intercept / slope if slope != 0 else 0.0
            if degree == 2:
                roots = np.roots(np.polyfit(x, d, 2, w=w))
                roots = roots[np.isreal(roots)].real
                roots = roots[(roots >= x[0] - 0.25) & (roots <= x[-1] + 0.25)]
                if len(roots):
                    guess = roots[np.argmin(np.abs(roots - guess))]
            out.append(centre + scale * guess)
        return np.array(out)

    for (a, b), d in zip(pairs, (U[a] - U[b] for a, b in pairs)):
        if np.all(d > 0) or np.all(d < 0):
            raise ValueError(f"the cumulants of curves {a} and {b} do not cross between "
                             f"{T[0]:g} and {T[-1]:g}: widen the temperatures")
    best = crossings(U)
    rng = np.random.default_rng(seed)
    redrawn = np.array([crossings(U + dU * rng.standard_normal(U.shape)).mean()
                        for _ in range(samples)])
    return Estimate(float(best.mean()), float(np.nanstd(redrawn))), best.tolist()
