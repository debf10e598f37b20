"""Symmetric compositions of a symmetric second-order step.

Φ_h = Φ_{γ_s h} ∘ … ∘ Φ_{γ_1 h} with Σγ = 1 and γ_k = γ_{s+1−k} raises a
symmetric (time-reversible) second-order method to order 4 or 6 (Hairer, Lubich
& Wanner, Geometric Numerical Integration, II.4 and V.3).
"""

from __future__ import annotations

import numpy as np

__all__ = ["COMPOSITIONS", "composition_coefficients"]


def _triple_jump():
    # Yoshida / Suzuki / Creutz–Gocksch triple jump: order 4, three stages.
    c = 2.0 ** (1.0 / 3.0)
    g = 1.0 / (2.0 - c)
    return (g, -c * g, g)


def _suzuki5():
    # Suzuki's fractal composition: order 4, five stages, much smaller error
    # constant than the triple jump (no stage longer than 0.42 h).
    c = 4.0 ** (1.0 / 3.0)
    g = 1.0 / (4.0 - c)
    return (g, g, -c * g, g, g)


# Kahan & Li (1997), order 6 with nine stages (HLW V.3.2, method p6 s9).
_KAHAN_LI_HALF = (0.39216144400731413928, 0.33259913678935943860,
                  -0.70624617255763935981, 0.08221359629355080023)
_KAHAN_LI_MIDDLE = 0.79854399093482996340


def _kahan_li():
    return _KAHAN_LI_HALF + (_KAHAN_LI_MIDDLE,) + _KAHAN_LI_HALF[::-1]


COMPOSITIONS = {
    "none": (2, (1.0,)),
    "triple_jump": (4, _triple_jump()),
    "suzuki": (4, _suzuki5()),
    "kahan_li": (6, _kahan_li()),
}
DEFAULT_FOR_ORDER = {2: "none", 4: "suzuki", 6: "kahan_li"}


def composition_coefficients(order=2, composition=None):
    """(order, γ coefficients) for ``order`` 2, 4 or 6, or a named
    ``composition`` (one of :data:`COMPOSITIONS`)."""
    if composition is None:
        if order not in DEFAULT_FOR_ORDER:
            raise ValueError(f"order must be 2, 4 or 6, got {order!r}")
        composition = DEFAULT_FOR_ORDER[order]
    if composition not in COMPOSITIONS:
        raise ValueError(f"unknown composition {composition!r}; "
                         f"choose from {sorted(COMPOSITIONS)}")
    got, gammas = COMPOSITIONS[composition]
    if order not in (2, got):  # 2 is the default: a named composition sets the order
        raise ValueError(f"composition {composition!r} has order {got}, not {order}")
    return got, np.array(gammas, dtype=float)
