"""Classical spins on :class:`ase.Atoms`.

The spin of atom i is stored as the vector moment μ_i s_i (μB) in the per-atom
array ``initial_magmoms`` with shape (N, 3): the one array that ASE's calculators
watch for changes and that ``.traj`` files keep. ``s_i`` is a unit direction and
``μ_i >= 0`` its magnitude; an atom whose moment is the zero vector is
non-magnetic and takes no part in exchange or spin motion.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from .validate import real_array

__all__ = ["set_spins", "get_spins", "get_moments", "split_moments", "MOMENT_RANGE"]


def name_atoms(indices, limit=10):
    indices = [int(i) for i in np.atleast_1d(indices)]
    shown = ", ".join(str(i) for i in indices[:limit])
    more = f" and {len(indices) - limit} more" if len(indices) > limit else ""
    return f"atom{'s' if len(indices) > 1 else ''} {shown}{more}"


def _existing_magnitudes(atoms):
    """Magnitudes of the moments already on ``atoms`` (collinear or vector), or None."""
    if not atoms.has("initial_magmoms"):
        return None
    m = real_array(atoms.arrays["initial_magmoms"], "initial_magmoms (magnetic moments)")
    return np.abs(m) if m.ndim == 1 else split_moments(m)[1]


#: Non-zero moment magnitudes (μB) must lie in this range: far outside anything
#: physical, and inside it μ·s keeps every digit of the direction s.
MOMENT_RANGE = (1e-100, 1e100)


#: Relative slack of the range for moments read back from the Atoms: a moment
#: stored as μ·s (set_spins) has |μ·s| within a few ulps of μ, so one set at
#: the range's edge may read back just outside it.
_STORED_SLACK = 4.0 * np.finfo(float).eps


def _check_magnitudes(mu, what, stored=False):
    lo, hi = MOMENT_RANGE
    if stored:
        lo, hi = lo * (1.0 - _STORED_SLACK), hi * (1.0 + _STORED_SLACK)
    bad = np.flatnonzero((mu != 0.0) & ~((mu >= lo) & (mu <= hi)))
    if bad.size:
        raise ValueError(
            f"{what} of {name_atoms(bad)} ({mu[bad[0]]:.3g} μB) outside the supported "
            f"range: non-zero moments must lie between {lo:g} and {hi:g} μB"
        )


def set_spins(atoms, directions, magnitudes=None):
    """Store spins on ``atoms`` as ``initial_magmoms`` (N, 3) = μ_i s_i.

    Parameters
    ----------
    atoms : ase.Atoms
    directions : array_like, shape (N, 3) or (3,)
        Spin directions: any finite real vectors, normalised here exactly at any
        scale (1e300 or denormal components alike). A (3,) vector is used for
        every atom. A zero row makes that atom non-magnetic (magnitude 0).
    magnitudes : float or array_like, shape (N,), optional
        Moment magnitudes μ_i in μB, 0 or within :data:`MOMENT_RANGE`. Default:
        the magnitudes already on the atoms (collinear or vector
        ``initial_magmoms``) where they are non-zero, else 1.

    Raises
    ------
    TypeError
        Strings, booleans, complex numbers or other non-real values.
    ValueError
        Wrong shapes, NaN/inf, negative magnitudes or magnitudes outside
        :data:`MOMENT_RANGE`, or a zero direction given a non-zero magnitude;
        the message names the offending atoms and ``atoms`` is left unchanged.
    """
    n = len(atoms)
    d = real_array(directions, "spin directions")
    if d.shape == (3,):
        d = np.broadcast_to(d, (n, 3))
    if d.shape != (n, 3):
        raise ValueError(
            f"spin directions must have shape ({n}, 3) or (3,), got {np.shape(directions)}"
        )
    bad = np.flatnonzero(~np.isfinite(d).all(axis=1))
    if bad.size:
        raise ValueError(f"spin directions are not finite for {name_atoms(bad)}")
    unit, norms = split_moments(d)
    zero = norms == 0.0

    if magnitudes is None:
        mu = _existing_magnitudes(atoms)
        mu = np.ones(n) if mu is None else np.where(mu > 0.0, mu, 1.0)
        mu = np.where(zero, 0.0, mu)
    else:
        mu = real_array(magnitudes, "spin magnitudes")
        if mu.ndim == 0:
            mu = np.full(n, float(mu))
        if mu.shape != (n,):
            raise ValueError(
                f"spin magnitudes must be a scalar or have shape ({n},), got {mu.shape}"
            )
        bad = np.flatnonzero(~np.isfinite(mu) | (mu < 0.0))
        if bad.size:
            raise ValueError(
                f"spin magnitudes must be finite and >= 0; not so for {name_atoms(bad)}"
            )
        bad = np.flatnonzero(zero & (mu > 0.0))
        if bad.size:
            raise ValueError(
                f"zero spin direction with a non-zero magnitude for {name_atoms(bad)}"
            )
    _check_magnitudes(mu, "spin magnitudes")
    # ASE refuses to change an array's shape in place (collinear -> vector).
    atoms.set_array("initial_magmoms", None)
    atoms.set_initial_magnetic_moments(unit * mu[:, None])


def get_moments(atoms):
    """The (N, 3) moment vectors μ_i s_i as float64; zeros when the atoms carry none.

    Raises TypeError for moments that are not real numbers, ValueError for
    collinear (N,) moments (vectors are needed), a wrong shape, non-finite
    values or magnitudes outside :data:`MOMENT_RANGE`, naming the offending atoms.
    """
    n = len(atoms)
    if not atoms.has("initial_magmoms"):
        return np.zeros((n, 3))
    m = real_array(atoms.arrays["initial_magmoms"], "initial_magmoms (magnetic moments)")
    if m.ndim == 1:
        nonzero = np.flatnonzero(m)
        if nonzero.size == 0:
            return np.zeros((n, 3))
        raise ValueError(
            f"{name_atoms(nonzero)} carry collinear (N,) magnetic moments; spin "
            "dynamics needs (N, 3) vectors: use ase_spin.set_spins(atoms, directions)"
        )
    if m.shape != (n, 3):
        raise ValueError(f"initial_magmoms must have shape ({n}, 3), got {m.shape}")
    if not np.isfinite(m).all():
        bad = np.flatnonzero(~np.isfinite(m).all(axis=1))
        raise ValueError(f"magnetic moments are not finite for {name_atoms(bad)}")
    _check_magnitudes(split_moments(m)[1], "magnetic moments", stored=True)
    return m


def split_moments(moments):
    """Split (N, 3) vectors v_i into unit directions s_i (zero rows where v_i = 0)
    and magnitudes μ_i, exactly at any scale (no overflow or underflow):

        m = max_k |v_ik|,   μ_i = m |v_i/m|,   s_i = (v_i/m) / |v_i/m|.

    μ_i > 1.8e308 is inf (refused by the callers' range check)."""
    moments = np.ascontiguousarray(moments, dtype=np.float64)
    unit = np.empty(moments.shape)
    mu = np.empty(len(moments))
    _split_rows(moments.reshape(-1, 3), unit.reshape(-1, 3), mu)
    return unit, mu


@nb.njit(cache=True)
def _split_rows(v, unit, mu):
    """:func:`split_moments`, row by row: one pass, no temporaries (it runs
    at every call of the ASE calculator, where numpy's array expressions and
    their temporaries cost a visible share of a small system's call;
    ``benchmarks/bench_calculator.py --parts`` times it, "bound_evaluator")."""
    for i in range(v.shape[0]):
        x = v[i, 0]
        y = v[i, 1]
        z = v[i, 2]
        m = max(abs(x), abs(y), abs(z))
        if m > 0.0:
            x /= m
            y /= m
            z /= m
            norm = np.sqrt(x * x + y * y + z * z)
            unit[i, 0] = x / norm
            unit[i, 1] = y / norm
            unit[i, 2] = z / norm
            mu[i] = m * norm
        else:
            unit[i, 0] = 0.0
            unit[i, 1] = 0.0
            unit[i, 2] = 0.0
            mu[i] = 0.0


def get_spins(atoms):
    """Unit spin directions s_i, shape (N, 3); zero rows for non-magnetic atoms."""
    return split_moments(get_moments(atoms))[0]
