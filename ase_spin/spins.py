"""Classical spins on :class:`ase.Atoms`.

The spin of atom i is stored as the vector moment μ_i s_i (μB) in the per-atom
array ``initial_magmoms`` with shape (N, 3): the one array that ASE's calculators
watch for changes and that ``.traj`` files keep. ``s_i`` is a unit direction and
``μ_i >= 0`` its magnitude; an atom whose moment is the zero vector is
non-magnetic and takes no part in exchange or spin motion.
"""

from __future__ import annotations

import numpy as np

__all__ = ["set_spins", "get_spins", "get_moments", "split_moments"]


def _name_atoms(indices, limit=10):
    indices = [int(i) for i in np.atleast_1d(indices)]
    shown = ", ".join(str(i) for i in indices[:limit])
    more = f" and {len(indices) - limit} more" if len(indices) > limit else ""
    return f"atom{'s' if len(indices) > 1 else ''} {shown}{more}"


def _existing_magnitudes(atoms):
    """Magnitudes of the moments already on ``atoms`` (collinear or vector), or None."""
    if not atoms.has("initial_magmoms"):
        return None
    m = np.asarray(atoms.arrays["initial_magmoms"], dtype=float)
    return np.abs(m) if m.ndim == 1 else np.linalg.norm(m, axis=1)


def set_spins(atoms, directions, magnitudes=None):
    """Store spins on ``atoms`` as ``initial_magmoms`` (N, 3) = μ_i s_i.

    Parameters
    ----------
    atoms : ase.Atoms
    directions : array_like, shape (N, 3) or (3,)
        Spin directions; normalised here. A (3,) vector is used for every atom.
        A zero row makes that atom non-magnetic (magnitude 0).
    magnitudes : float or array_like, shape (N,), optional
        Moment magnitudes μ_i in μB. Default: the magnitudes already on the
        atoms (collinear or vector ``initial_magmoms``) where they are non-zero,
        else 1.

    Raises
    ------
    ValueError
        Wrong shapes, NaN/inf, negative magnitudes, or a zero direction given a
        non-zero magnitude; the message names the offending atoms and ``atoms``
        is left unchanged.
    """
    n = len(atoms)
    d = np.asarray(directions, dtype=float)
    if d.shape == (3,):
        d = np.broadcast_to(d, (n, 3))
    if d.shape != (n, 3):
        raise ValueError(
            f"spin directions must have shape ({n}, 3) or (3,), got {np.shape(directions)}"
        )
    bad = np.flatnonzero(~np.isfinite(d).all(axis=1))
    if bad.size:
        raise ValueError(f"spin directions are not finite for {_name_atoms(bad)}")
    norms = np.linalg.norm(d, axis=1)
    zero = norms == 0.0

    if magnitudes is None:
        mu = _existing_magnitudes(atoms)
        mu = np.ones(n) if mu is None else np.where(mu > 0.0, mu, 1.0)
        mu = np.where(zero, 0.0, mu)
    else:
        mu = np.asarray(magnitudes, dtype=float)
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
    unit = np.zeros((n, 3))
    unit[~zero] = d[~zero] / norms[~zero, None]
    # ASE refuses to change an array's shape in place (collinear -> vector).
    atoms.set_array("initial_magmoms", None)
    atoms.set_initial_magnetic_moments(unit * mu[:, None])


def get_moments(atoms):
    """The (N, 3) moment vectors μ_i s_i; zeros when the atoms carry none.

    Raises ValueError for collinear (N,) moments (vectors are needed), a wrong
    shape or non-finite values, naming the offending atoms.
    """
    n = len(atoms)
    if not atoms.has("initial_magmoms"):
        return np.zeros((n, 3))
    m = np.asarray(atoms.arrays["initial_magmoms"], dtype=float)
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
    return m


def split_moments(moments):
    """Split (N, 3) moments into unit directions (zero rows where μ = 0) and magnitudes."""
    mu = np.linalg.norm(moments, axis=1)
    unit = np.zeros_like(moments)
    mag = mu > 0.0
    unit[mag] = moments[mag] / mu[mag, None]
    return unit, mu


def get_spins(atoms):
    """Unit spin directions s_i, shape (N, 3); zero rows for non-magnetic atoms."""
    return split_moments(get_moments(atoms))[0]
