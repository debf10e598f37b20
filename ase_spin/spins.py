"""Classical spins on :class:`ase.Atoms`.

The spin of atom i is stored as the vector moment μ_i s_i (μB) in the per-atom
array ``initial_magmoms`` with shape (N, 3): the one array that ASE's calculators
watch for changes and that ``.traj`` files keep. ``s_i`` is a unit direction and
``μ_i >= 0`` its magnitude; an atom whose moment is the zero vector is
non-magnetic and takes no part in exchange or spin motion.
"""

from __future__ import annotations

import numpy as np

from .validate import real_array, robust_norm

__all__ = ["set_spins", "get_spins", "get_moments", "split_moments", "MOMENT_RANGE"]


def _name_atoms(indices, limit=10):
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


def _check_magnitudes(mu, what):
    lo, hi = MOMENT_RANGE
    bad = np.flatnonzero((mu != 0.0) & ~((mu >= lo) & (mu <= hi)))
    if bad.size:
        raise ValueError(
            f"{what} of {_name_atoms(bad)} ({mu[bad[0]]:.3g} μB) outside the supported "
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
        raise ValueError(f"spin directions are not finite for {_name_atoms(bad)}")
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
                f"spin magnitudes must be finite and >= 0; not so for {_name_atoms(bad)}"
            )
        bad = np.flatnonzero(zero & (mu > 0.0))
        if bad.size:
            raise ValueError(
                f"zero spin direction with a non-zero magnitude for {_name_atoms(bad)}"
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
            f"{_name_atoms(nonzero)} carry collinear (N,) magnetic moments; spin "
            "dynamics needs (N, 3) vectors: use ase_spin.set_spins(atoms, directions)"
        )
    if m.shape != (n, 3):
        raise ValueError(f"initial_magmoms must have shape ({n}, 3), got {m.shape}")
    bad = np.flatnonzero(~np.isfinite(m).all(axis=1))
    if bad.size:
        raise ValueError(f"magnetic moments are not finite for {_name_atoms(bad)}")
    _check_magnitudes(robust_norm(m), "magnetic moments")
    return m


def split_moments(moments):
    """Split (N, 3) vectors into unit directions (zero rows where the vector is
    zero) and magnitudes, exactly at any scale (no overflow or underflow)."""
    largest = np.abs(moments).max(axis=1) if len(moments) else np.zeros(0)
    mag = largest > 0.0
    scaled = moments[mag] / largest[mag, None]
    norm = np.sqrt(np.einsum("ij,ij->i", scaled, scaled))
    unit = np.zeros(moments.shape)
    unit[mag] = scaled / norm[:, None]
    mu = np.zeros(len(moments))
    with np.errstate(over="ignore"):  # |v| > 1.8e308: inf, refused by the callers' range check
        mu[mag] = largest[mag] * norm
    return unit, mu


def get_spins(atoms):
    """Unit spin directions s_i, shape (N, 3); zero rows for non-magnetic atoms."""
    return split_moments(get_moments(atoms))[0]
