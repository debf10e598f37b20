"""The parameters of the heat baths (:class:`~ase_spin.md.langevin.Langevin`):
each checked where it is given or set, with what it is and its typical values
in the message."""

from __future__ import annotations

import numpy as np
from ase import units

from ..validate import REQUIRED, real_scalar

__all__ = ["MAX_BATH_TEMPERATURE_K", "MAX_SPIN_DAMPING", "generator", "temperature_K", "kT",
           "spin_damping", "non_negative", "require"]


def generator(rng):
    if rng is None or isinstance(rng, (int, np.integer)) and not isinstance(rng, bool):
        if rng is not None and rng < 0:
            raise ValueError(f"rng seed must be a non-negative integer, got {rng}")
        return np.random.default_rng(rng)
    if isinstance(rng, np.random.Generator):
        return rng
    raise TypeError("rng must be a numpy Generator (np.random.default_rng(seed)), an "
                    f"integer seed or None, got {type(rng).__name__}")


#: The largest bath temperature (K) and spin damping accepted: far beyond any
#: magnetic or atomic structure (k_B·10⁸ K ≈ 8.6 keV), and below where the
#: noise amplitudes and 1 + λ² overflow.
MAX_BATH_TEMPERATURE_K = 1e8
MAX_SPIN_DAMPING = 1e6


def temperature_K(value, what):
    t = real_scalar(value, what)
    if t < 0.0:
        raise ValueError(f"{what} must be >= 0 K, got {t}")
    if t > MAX_BATH_TEMPERATURE_K:
        raise ValueError(f"{what} = {t:g} K is above {MAX_BATH_TEMPERATURE_K:g} K, where no "
                         "magnetic or atomic structure survives: a value in the wrong unit?")
    return t


def kT(value, what):
    """k_B T (eV) set as an attribute: checked as a temperature in K would be."""
    x = non_negative(value, what, "eV")
    temperature_K(x / units.kB, what + " / k_B")
    return x


def spin_damping(value):
    x = non_negative(value, "spin_damping", "dimensionless")
    if x > MAX_SPIN_DAMPING:
        raise ValueError(f"spin_damping = {x:g} is above {MAX_SPIN_DAMPING:g} (overdamped "
                         "long before: the spins then barely move); typically 0.01 to 0.1")
    return x


#: What each required parameter of Langevin is, with typical values: the
#: message when it is missing (see :func:`require`).
TYPICAL = {
    "temperature_K": "the bath temperature in K",
    "spin_damping": "λ, the spin bath's dimensionless Gilbert damping: typically 0.01 to "
                    "0.1, 0 for no spin bath",
    "friction": "γ, the lattice bath's friction in 1/(ASE time), as ASE's Langevin: "
                "typically 0.001 / units.fs to 0.01 / units.fs, 0 for no lattice bath",
}


def require(**given):
    """TypeError naming the required parameters of Langevin that were not
    given, what each is and its typical values. They have no defaults, as in
    ASE's Langevin (friction) and LAMMPS's fix langevin and langevin/spin:
    the coupling to a bath is part of the physics a run shows (how fast it
    equilibrates, how much the bath disturbs correlations and switching
    rates), a number for the user to choose."""
    missing = [k for k, v in given.items() if v is REQUIRED]
    if missing:
        raise TypeError(
            "Langevin needs " + "; ".join(f"{k} ({TYPICAL[k]})" for k in missing)
            + ". For example: Langevin(atoms, 0.5 * units.fs, temperature_K=300, "
            "spin_damping=0.1, friction=0.01 / units.fs)")


def non_negative(value, what, unit):
    x = real_scalar(value, what)
    if x < 0.0:
        raise ValueError(f"{what} must be >= 0 ({unit}), got {x}")
    return x
