r"""The energy along a path through a few images, as Spirit and
``ase.mep.NEBTools`` draw it: a piecewise cubic Hermite interpolation of the
images' energies E_ν at their distances R_ν along the path, with the slopes
dE/dR = −F_ν·τ̂_ν (the force along the unit tangent) at the images.

On [R_ν, R_ν+1], with Δ = R_ν+1 − R_ν and t = (R − R_ν)/Δ:

.. math:: E(R) = h_{00}(t)E_ν + h_{10}(t)\Delta E'_ν
    + h_{01}(t)E_{ν+1} + h_{11}(t)\Delta E'_{ν+1},

h₀₀ = 2t³ − 3t² + 1, h₁₀ = t³ − 2t² + t, h₀₁ = −2t³ + 3t², h₁₁ = t³ − t².
"""

from __future__ import annotations

import numpy as np

__all__ = ["hermite_path", "path_maximum"]


def hermite_path(R, E, slopes, points=20):
    """(R, E) of the cubic Hermite interpolation with ``points`` points per
    interval (the images included)."""
    R, E, slopes = (np.asarray(x, dtype=float) for x in (R, E, slopes))
    if not (R.shape == E.shape == slopes.shape and R.ndim == 1 and len(R) >= 2):
        raise ValueError("hermite_path needs R, E and slopes of one length >= 2")
    t = np.linspace(0.0, 1.0, points + 1)[:-1]
    xs, ys = [], []
    for k in range(len(R) - 1):
        d = R[k + 1] - R[k]
        h00, h10 = 2 * t**3 - 3 * t**2 + 1, t**3 - 2 * t**2 + t
        h01, h11 = -2 * t**3 + 3 * t**2, t**3 - t**2
        xs.append(R[k] + t * d)
        ys.append(h00 * E[k] + h10 * d * slopes[k] + h01 * E[k + 1] + h11 * d * slopes[k + 1])
    xs.append(R[-1:])
    ys.append(E[-1:])
    return np.concatenate(xs), np.concatenate(ys)


def path_maximum(R, E, slopes):
    """(R*, E*) of the highest point of the Hermite interpolation: at an image,
    or where the cubic of an interval has a zero slope (solved exactly)."""
    R, E, slopes = (np.asarray(x, dtype=float) for x in (R, E, slopes))
    k = int(np.argmax(E))
    best = (float(R[k]), float(E[k]))
    for k in range(len(R) - 1):
        d = R[k + 1] - R[k]
        if not d > 0.0:
            continue
        # E(t) = a t³ + b t² + c t + e: zeros of 3a t² + 2b t + c in (0, 1)
        a = 2 * E[k] + d * slopes[k] - 2 * E[k + 1] + d * slopes[k + 1]
        b = -3 * E[k] - 2 * d * slopes[k] + 3 * E[k + 1] - d * slopes[k + 1]
        c = d * slopes[k]
        for t in np.roots([3 * a, 2 * b, c]) if (a or b) else ():
            if abs(t.imag) < 1e-12 and 0.0 < t.real < 1.0:
                t = t.real
                value = a * t**3 + b * t**2 + c * t + E[k]
                if value > best[1]:
                    best = (float(R[k] + t * d), float(value))
    return best
