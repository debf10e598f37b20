"""Checks for values where they enter the package: numbers, arrays, flags.

Every public entry point (spins, Atoms arrays, term parameters, integrator
settings) turns user input into float64 / bool / int here, so that a string, a
complex number or a NaN is refused with a message naming the input, instead of
being silently converted (``float("1")``, dropped imaginary parts, ``bool("no")``)
or failing deep inside numpy or numba.
"""

from __future__ import annotations

import difflib
import numbers
import os
import sys
import warnings

import numpy as np

__all__ = ["real_array", "real_scalar", "positive_scalar", "length", "flag", "integer",
           "robust_norm", "ImplausibleParameterWarning", "warn_implausible", "REQUIRED",
           "unknown_keywords", "MAX_FIELD_T", "MAX_SITE_ENERGY", "MAX_COUPLING",
           "MIN_DISTANCE"]

#: Lengths (Å) a parameter may take: squares and inverse squares stay finite.
LENGTH_RANGE = (1e-100, 1e100)


def _kind_error(what, value):
    kind = type(value).__name__
    return TypeError(f"{what} must be real numbers, got {kind} {value!r:.60}")


def real_array(value, what, shape=None):
    """``value`` as a C-contiguous float64 array.

    Integer and lower-precision float arrays are converted exactly. Strings,
    bytes, booleans, complex numbers and objects that are not real numbers
    raise TypeError naming ``what``; a wrong ``shape`` raises ValueError.
    Finiteness is the caller's business (it knows which rows to name).
    """
    if isinstance(value, (str, bytes)):
        raise _kind_error(what, value)
    if not isinstance(value, np.ndarray):
        # numpy turns [True, 0.5] or [1, "2"] silently into numbers or strings:
        # look at the elements of Python sequences first
        try:
            elements = np.asarray(value, dtype=object).ravel()
        except (ValueError, TypeError):
            elements = ()
        for v in elements:
            if isinstance(v, (bool, np.bool_, str, bytes, complex)) or v is None:
                raise _kind_error(what, v)
    try:
        arr = np.asarray(value)
    except (ValueError, TypeError) as err:  # ragged nested sequences
        raise ValueError(f"{what} must be a regular array of numbers: {err}") from None
    kind = arr.dtype.kind
    if kind == "O":
        flat = arr.ravel()
        for v in flat:
            if isinstance(v, (bool, np.bool_)) or not isinstance(v, numbers.Real):
                raise _kind_error(what, v)
        arr = np.array([float(v) for v in flat], dtype=np.float64).reshape(arr.shape)
    elif kind not in "iuf":
        raise TypeError(f"{what} must be real numbers, got an array of dtype {arr.dtype}")
    arr = np.asarray(arr, dtype=np.float64, order="C")
    if shape is not None and arr.shape != tuple(shape):
        raise ValueError(f"{what} must have shape {tuple(shape)}, got {arr.shape}")
    return arr


def real_scalar(value, what, finite=True):
    """A real number as float; TypeError for strings, bools, complex, None,
    arrays; ValueError for NaN/inf when ``finite``."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (numbers.Real, np.number)) \
            or isinstance(value, (complex, np.complexfloating)):
        raise TypeError(f"{what} must be a real number, got {type(value).__name__} {value!r:.60}")
    x = float(value)
    if finite and not np.isfinite(x):
        raise ValueError(f"{what} must be finite, got {x}")
    return x


def positive_scalar(value, what):
    """A finite real number > 0."""
    x = real_scalar(value, what)
    if not x > 0.0:
        raise ValueError(f"{what} must be positive, got {x}")
    return x


def length(value, what):
    """A length in Å: finite, positive and within :data:`LENGTH_RANGE` (so that
    r², 1/r² and the like neither overflow nor vanish)."""
    x = positive_scalar(value, what)
    lo, hi = LENGTH_RANGE
    if not lo <= x <= hi:
        raise ValueError(f"{what} must lie between {lo:g} and {hi:g} Å, got {x:g}")
    return x


def flag(value, what):
    """``True`` or ``False`` only: ``bool("False")`` is True, so strings and
    numbers are refused rather than guessed."""
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    raise TypeError(f"{what} must be True or False, got {type(value).__name__} {value!r:.60}")


def integer(value, what, minimum=None):
    """An integer (Python or numpy; not bool, not float) >= ``minimum``."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (numbers.Integral,
                                                                     np.integer)):
        raise TypeError(f"{what} must be an integer, got {type(value).__name__} {value!r:.60}")
    n = int(value)
    if minimum is not None and n < minimum:
        raise ValueError(f"{what} must be at least {minimum}, got {n}")
    return n


def robust_norm(v):
    """Row norms of a finite (n, 3) array without overflow or underflow:
    |v| = m·|v/m| with m = max |v_k| (np.linalg.norm squares first, so 1e200
    becomes inf and 1e-170 becomes 0)."""
    m = np.abs(v).max(axis=1) if len(v) else np.zeros(0)
    safe = np.where(m > 0.0, m, 1.0)
    scaled = v / safe[:, None]
    return m * np.sqrt(np.einsum("ij,ij->i", scaled, scaled))


def unit_vector(value, what):
    """A direction: three finite real numbers, not all zero, normalised
    (exactly at any scale: scaled by the largest component first)."""
    v = real_array(value, what).reshape(-1)
    if v.shape != (3,):
        raise ValueError(f"{what} must have three components, got {v.size}")
    if not np.isfinite(v).all():
        raise ValueError(f"{what} must be finite, got {v.tolist()}")
    big = np.abs(v).max()
    if big == 0.0:
        raise ValueError(f"{what} must not be the zero vector")
    v = v / big
    v = v / np.sqrt(v @ v)
    v.setflags(write=False)
    return v


# -- values that run but are almost surely not meant --------------------------------

class ImplausibleParameterWarning(UserWarning):
    """A value that is valid but far outside anything physical, most likely a
    slip of units: a field in Oe given as tesla, an energy in meV given as eV,
    positions in other units than Å (docs/errors.md). Raised where the value
    enters (the term's constructor, the first neighbour list of a structure);
    the run goes on."""


#: Zeeman fields (T) above this warn: the strongest laboratory fields are ~100 T
#: (pulsed), and 10⁴ T is a field in Oe or G typed as tesla (1 T = 10⁴ Oe).
MAX_FIELD_T = 1000.0
#: Single-site (anisotropy) energies (eV per atom) above this warn: magnetocrystalline
#: anisotropies are μeV to a few meV per atom.
MAX_SITE_ENERGY = 1.0
#: Pair couplings (exchange J, DMI D; eV per pair) above this warn: exchange is
#: meV to ~0.1 eV per pair.
MAX_COUPLING = 1.0
#: Pairs of atoms closer than this (Å) when a structure is first seen warn.
MIN_DISTANCE = 0.5

_UNIT_SLIPS = {
    "field": "a field in Oe or G given as tesla? 1 T = 10⁴ Oe = 10⁴ G; fields are in tesla",
    "energy": "a value in meV given as eV? ase_spin takes energies in eV",
}


#: The package's folder: frames in it are not the user's (see :func:`warn_user`).
PACKAGE_DIR = os.path.dirname(os.path.abspath(__file__)) + os.sep


def warn_user(warning, category=None):
    """``warnings.warn``, attributed to the first caller outside ase_spin: the
    user's line (``dyn.run(...)``, ``Exchange(...)``), however deep in the
    package the warning is raised, so that the message points at what to
    change and Python's once-per-location filter counts the user's lines."""
    frame, level = sys._getframe(1), 2
    while frame is not None and frame.f_code.co_filename.startswith(PACKAGE_DIR):
        frame, level = frame.f_back, level + 1
    warnings.warn(warning, category, stacklevel=level)


def warn_implausible(value, limit, what, unit, typical, slip):
    """Warn (:class:`ImplausibleParameterWarning`) if |value| > ``limit``:
    ``what = value unit: above limit unit, typical; slip``. ``value`` may be a
    number or a mapping of them (per species or pair: the largest is named).
    ``slip``: a key of the unit-slip hints or a phrase."""
    values = value.values() if hasattr(value, "values") else (value,)
    worst = max((abs(float(v)) for v in values if v is not None), default=0.0)
    if not worst > limit:
        return
    hint = _UNIT_SLIPS.get(slip, slip)
    warn_user(ImplausibleParameterWarning(
        f"{what} = {worst:.4g} {unit}: above {limit:g} {unit}, implausible ({typical}); "
        f"{hint}"))


# -- keywords ---------------------------------------------------------------------

class _Required:
    """The default of a keyword a function needs but checks itself, so that it
    can first refuse unknown keywords (see :func:`unknown_keywords`)."""

    def __repr__(self):
        return "<required>"

    def __reduce__(self):
        return "REQUIRED"


#: Default of a required keyword (a function checks for it itself, after the
#: unknown keywords): shown as ``<required>`` in signatures; the command
#: line's input checks count it as required.
REQUIRED = _Required()


def unknown_keywords(owner, given, accepted, hints=None):
    """TypeError naming the keywords of ``given`` that ``owner`` (a name) does
    not take, or None when all are known (the caller raises it). Each comes
    with the accepted one most likely meant: from ``hints`` (slip -> (keyword
    meant, why, what to say when ``owner`` does not take that keyword either)),
    else the closest accepted name."""
    unknown = [k for k in given if k not in accepted]
    if not unknown:
        return None
    hints = hints or {}
    problems = []
    for k in unknown:
        text = f"unknown keyword {k!r}"
        meant, why, otherwise = hints.get(k, (None, "", ""))
        if meant is not None and meant not in accepted:
            meant, why = None, ""
            if otherwise:
                text += f" ({otherwise})"
        if meant is None and not otherwise:
            close = difflib.get_close_matches(str(k), sorted(accepted), n=1, cutoff=0.6)
            meant = close[0] if close else None
        if meant is not None:
            text += f"; did you mean {meant}?"
            if why:
                text += f" ({why})"
        problems.append(text)
    return TypeError(f"{owner}: {'; '.join(problems)}")
