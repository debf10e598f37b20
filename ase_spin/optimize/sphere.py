r"""Geometry on the product of unit spheres (S²)ᴺ, the configuration space of N
spins: tangent projections, rotations (the exponential map), geodesic angles
and distances, geodesic interpolation. Vectorised numpy on (..., 3) arrays; the
minimisers and the band of :mod:`ase_spin.optimize` share these.

Conventions. A rotation vector θ_i turns s_i about θ̂_i by |θ_i| (right hand):

.. math:: R(\boldsymbol\theta)\mathbf s = \mathbf s\cos\theta
    + (\hat{\boldsymbol\theta}\times\mathbf s)\sin\theta
    + \hat{\boldsymbol\theta}(\hat{\boldsymbol\theta}\cdot\mathbf s)(1-\cos\theta),

so that to first order δs = θ × s, and with B = −∂E/∂s the energy changes by
δE = −B·(θ × s) = −θ·(s × B): the gradient of E with respect to the rotation
vector is −τ, τ_i = s_i × B_i the torque (eV). A tangent displacement d ⟂ s
is the rotation θ = s × d (the exponential map exp_s(d) = s cos|d| + d̂ sin|d|).
"""

from __future__ import annotations

import numpy as np

__all__ = ["inner", "dot", "norms", "tangent", "torque", "rotate", "exp_map", "angles",
           "geodesic_distance", "slerp", "perpendicular"]


def inner(a, b):
    """Σ a·b over all elements of two arrays of one shape (a float). Not
    ``np.vdot``: that calls BLAS, whose threads, woken for every call on a
    large band, cost milliseconds on a busy machine; einsum stays on one."""
    return float(np.einsum("i,i->", np.ravel(a), np.ravel(b)))


def dot(a, b):
    """Row-wise dot products of (..., 3) arrays."""
    return np.einsum("...i,...i->...", a, b)


def norms(a):
    """Row-wise Euclidean norms of (..., 3) arrays."""
    return np.sqrt(dot(a, a))


def tangent(v, s):
    """v_i − (v_i·s_i) s_i: the part of v in the tangent planes at unit s."""
    return v - dot(v, s)[..., None] * s


def torque(s, B):
    """τ_i = s_i × B_i (eV): minus the gradient of E in the rotation vectors."""
    return np.cross(s, B)


def rotate(s, theta):
    """R(θ_i) s_i for rotation vectors θ (rows; Rodrigues' formula, the
    module docstring), renormalised so that |s_i| stays 1 to round-off."""
    angle = norms(theta)
    safe = np.where(angle > 0.0, angle, 1.0)
    k = theta / safe[..., None]
    c, sn = np.cos(angle)[..., None], np.sin(angle)[..., None]
    out = s * c + np.cross(k, s) * sn + k * (dot(k, s)[..., None] * (1.0 - c))
    return out / norms(out)[..., None]


def exp_map(s, d):
    """exp_s(d): each s_i moved along the great circle of its tangent
    displacement d_i (d_i ⟂ s_i) by the angle |d_i|."""
    return rotate(s, np.cross(s, d))


def angles(a, b):
    """Geodesic angles θ_i = atan2(|a_i × b_i|, a_i·b_i) ∈ [0, π] between unit
    rows (accurate at small and at near-π angles, unlike arccos)."""
    return np.arctan2(norms(np.cross(a, b)), dot(a, b))


def geodesic_distance(a, b):
    """The geodesic distance on (S²)ᴺ, L = (Σ_i θ_i²)^½ (rad)."""
    return float(np.sqrt(np.sum(angles(a, b) ** 2)))


def perpendicular(s):
    """A unit vector ⟂ each row of s: s × e with e the Cartesian axis least
    aligned with s_i (the axis of a half turn when s_i and its image are
    antiparallel)."""
    e = np.zeros_like(s)
    rows = np.arange(len(s)) if s.ndim == 2 else 0
    e[rows, np.argmin(np.abs(s), axis=-1)] = 1.0
    p = np.cross(s, e)
    return p / norms(p)[..., None]


def slerp(a, b, t, axis=None):
    """Geodesic interpolation: each a_i turned towards b_i about a_i × b_i by
    t θ_i (t = 0: a, t = 1: b). Where a_i and b_i are antiparallel (no
    unique geodesic) the turn is about ``axis`` (a unit vector, or rows) if
    given and ⟂ a_i, else about :func:`perpendicular` (a_i)."""
    cross = np.cross(a, b)
    length = norms(cross)
    theta = np.arctan2(length, dot(a, b))
    k = cross / np.where(length > 0.0, length, 1.0)[..., None]
    antiparallel = (length <= 1e-12) & (dot(a, b) < 0.0)
    if antiparallel.any():
        if axis is None:
            fallback = perpendicular(a)
        else:
            fallback = tangent(np.broadcast_to(np.asarray(axis, dtype=float), a.shape), a)
            small = norms(fallback) < 1e-8
            fallback = np.where(small[..., None], perpendicular(a), fallback)
            fallback /= norms(fallback)[..., None]
        k = np.where(antiparallel[..., None], fallback, k)
        theta = np.where(antiparallel, np.pi, theta)
    return rotate(a, k * (t * theta)[..., None])
