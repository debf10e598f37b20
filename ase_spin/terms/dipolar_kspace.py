"""The k-space side of the dipolar Ewald sum (:class:`~ase_spin.terms.dipolar.Dipolar`,
``method="ewald"``): the splitting parameters for an accuracy, the k-vectors,
the reciprocal-space energy, field, forces and virial at given positions, and
the Yeh–Berkowitz correction of slabs (periodic in two directions)."""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from .._jit.threads import all_threads, threaded

__all__ = ["Reciprocal", "SlabCorrection", "ewald_error_bound", "ewald_parameters",
           "kvectors", "slab_geometry"]

_TWO_OVER_SQRT_PI = 2.0 / math.sqrt(math.pi)


def ewald_error_bound(x):
    r"""The relative size of the first neglected terms of the Ewald sum,
    g(x) = erfc(x) + (2x/√π)(1 + 2x²/3) e^{−x²}: the screened B2 of a pair at
    the real-space cutoff over its bare value, x = α r_c (and the same
    function of x = k_c/2α bounds the neglected reciprocal terms)."""
    return math.erfc(x) + _TWO_OVER_SQRT_PI * x * (1.0 + 2.0 * x * x / 3.0) * math.exp(-x * x)


def ewald_parameters(rc, accuracy):
    """(α in 1/Å, k-space cutoff k_c in 1/Å) for a real-space cutoff ``rc`` (Å)
    and a relative ``accuracy``: α r_c = x and k_c = 2α x with
    :func:`ewald_error_bound` (x) = accuracy (bisection)."""
    lo, hi = 0.0, 40.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if ewald_error_bound(mid) > accuracy:
            lo = mid
        else:
            hi = mid
    alpha = hi / rc
    return alpha, 2.0 * alpha * hi


def kvectors(cell, kcut):
    """The k = 2π n·cell⁻ᵀ with 0 < |k| ≤ k_c, one of each ±k pair."""
    recip = 2.0 * math.pi * np.linalg.inv(cell).T
    nmax = [math.floor(kcut * np.linalg.norm(cell[a]) / (2.0 * math.pi)) for a in range(3)]
    n = np.stack(np.meshgrid(*(np.arange(-m, m + 1) for m in nmax), indexing="ij"),
                 axis=-1).reshape(-1, 3)
    upper = (n[:, 0] > 0) | ((n[:, 0] == 0) & ((n[:, 1] > 0) | ((n[:, 1] == 0) & (n[:, 2] > 0))))
    k = n[upper] @ recip
    return np.ascontiguousarray(k[np.einsum("ij,ij->i", k, k) <= kcut * kcut])


_NO_ROWS = np.zeros((0, 3))


@threaded(always=True)
def phases(nthreads, positions, k, c, s):
    """c = cos(k·r_j), s = sin(k·r_j) per atom j and k-vector."""
    N = positions.shape[0]
    for t in nb.prange(nthreads):
        for j in range(t * N // nthreads, (t + 1) * N // nthreads):
            x = positions[j, 0]
            y = positions[j, 1]
            z = positions[j, 2]
            for q in range(k.shape[0]):
                p = x * k[q, 0] + y * k[q, 1] + z * k[q, 2]
                c[j, q] = math.cos(p)
                s[j, q] = math.sin(p)


@threaded(always=True)
def structure_factors(nthreads, m, k, c, s, Sc, Ss):
    """Sc + i Ss = S(k) = Σ_j (m_j·k)[cos(k·r_j) + i sin(k·r_j)] for every k,
    each thread over its own range of k (no reduction between threads), the
    atoms in the outer loop so that the rows of c and s are read in order."""
    K = k.shape[0]
    for t in nb.prange(nthreads):
        lo = t * K // nthreads
        hi = (t + 1) * K // nthreads
        for q in range(lo, hi):
            Sc[q] = 0.0
            Ss[q] = 0.0
        for j in range(m.shape[0]):
            mx = m[j, 0]
            my = m[j, 1]
            mz = m[j, 2]
            for q in range(lo, hi):
                v = mx * k[q, 0] + my * k[q, 1] + mz * k[q, 2]
                Sc[q] += v * c[j, q]
                Ss[q] += v * s[j, q]


@threaded(always=True)
def reciprocal_rows(nthreads, m, k, c, s, ASc, ASs, coef, H, F, want_h, want_f):
    """Per atom i, with ASc + i ASs = A(k) S(k) and coef = 8π/V:

    H_i −= coef Σ_k k [cos(k·r_i) ASc + sin(k·r_i) ASs]            (the field),
    F_i += coef Σ_k k (m_i·k)[sin(k·r_i) ASc − cos(k·r_i) ASs]     (the forces)."""
    N = c.shape[0]
    K = k.shape[0]
    for t in nb.prange(nthreads):
        for i in range(t * N // nthreads, (t + 1) * N // nthreads):
            hx = 0.0
            hy = 0.0
            hz = 0.0
            fx = 0.0
            fy = 0.0
            fz = 0.0
            mx = m[i, 0]
            my = m[i, 1]
            mz = m[i, 2]
            for q in range(K):
                kx = k[q, 0]
                ky = k[q, 1]
                kz = k[q, 2]
                if want_h:
                    w = c[i, q] * ASc[q] + s[i, q] * ASs[q]
                    hx += w * kx
                    hy += w * ky
                    hz += w * kz
                if want_f:
                    w = (mx * kx + my * ky + mz * kz) * (s[i, q] * ASc[q] - c[i, q] * ASs[q])
                    fx += w * kx
                    fy += w * ky
                    fz += w * kz
            if want_h:
                H[i, 0] -= coef * hx
                H[i, 1] -= coef * hy
                H[i, 2] -= coef * hz
            if want_f:
                F[i, 0] += coef * fx
                F[i, 1] += coef * fy
                F[i, 2] += coef * fz


class Reciprocal:
    r"""The reciprocal-space part of the Ewald sum at given positions, over the
    half k-space (each ±k once, hence the factor 2 of the full sum):

    E_k = (4π/V) Σ_k A(k) |S(k)|²,  A = e^{−k²/4α²}/k²,  S(k) = Σ_j (m_j·k) e^{ik·r_j},

    in units of μ0μB²/4π with m_j = μ_j s_j. The phases cos(k·r_j), sin(k·r_j)
    are kept (16 N K bytes)."""

    __slots__ = ("A", "alpha", "c", "k", "pref", "s")

    def __init__(self, positions, k, A, volume, alpha):
        self.k = k
        self.A = A
        self.c = np.empty((len(positions), len(k)))
        self.s = np.empty((len(positions), len(k)))
        phases(all_threads(), np.ascontiguousarray(positions, dtype=float), k, self.c, self.s)
        self.pref = 4.0 * math.pi / volume
        self.alpha = alpha

    def _sums(self, m):
        """(Re S, Im S) per k."""
        Sc = np.empty(len(self.k))
        Ss = np.empty(len(self.k))
        structure_factors(all_threads(), m, self.k, self.c, self.s, Sc, Ss)
        return Sc, Ss

    def field(self, m, H):
        """H_i += −∂E_k/∂m_i = −(8π/V) Σ_k A k [cos(k·r_i) Re S + sin(k·r_i) Im S]."""
        Sc, Ss = self._sums(m)
        reciprocal_rows(all_threads(), m, self.k, self.c, self.s, self.A * Sc, self.A * Ss,
                        2.0 * self.pref, H, H, True, False)

    def add(self, m, H, F, want_h, want_f, want_v):
        """E_k, and where wanted: the field (as :meth:`field`), the forces
        F_i = (8π/V) Σ_k A k (m_i·k)[sin(k·r_i) Re S − cos(k·r_i) Im S] and the
        virial ∂E_k/∂ε_ab = −δ_ab E_k + (4π/V) Σ_k A [2 (1/k² + 1/4α²) k_a k_b
        |S|² − k_a Re(S* T_b) − k_b Re(S* T_a)], T(k) = Σ_j m_j e^{ik·r_j}."""
        Sc, Ss = self._sums(m)
        AS2 = self.A * (Sc * Sc + Ss * Ss)
        energy = self.pref * AS2.sum()
        if want_h or want_f:
            reciprocal_rows(all_threads(), m, self.k, self.c, self.s, self.A * Sc,
                            self.A * Ss, 2.0 * self.pref, H if want_h else _NO_ROWS,
                            F if want_f else _NO_ROWS, want_h, want_f)
        virial = np.zeros(6)
        if want_v:
            k = self.k
            k2 = np.einsum("ij,ij->i", k, k)
            radial = 2.0 * (1.0 / k2 + 0.25 / self.alpha**2) * AS2
            # Re(S* T) = Re S Re T + Im S Im T, with T = Σ_j m_j e^{ik·r_j}
            ReST = (self.c * Sc + self.s * Ss).T @ m  # (K, 3)
            W = (k * radial[:, None]).T @ k
            Q = (k * self.A[:, None]).T @ ReST
            W = self.pref * (W - Q - Q.T) - energy * np.eye(3)
            virial = W[[0, 1, 2, 1, 0, 0], [0, 1, 2, 2, 2, 1]]
        return energy, virial


# -- slabs: the Yeh–Berkowitz correction ----------------------------------------

def slab_geometry(cell, factor):
    r"""The Ewald cell of a slab periodic along ``cell[0]`` and ``cell[1]``:
    (extended cell, unit normal n̂ ∝ a × b, height h = c·n̂), the third
    vector stretched ``factor`` times (LAMMPS's ``kspace_modify slab factor``)
    so that the slab's periodic images along it are kept apart by vacuum."""
    cell = np.asarray(cell, dtype=float)
    n = np.cross(cell[0], cell[1])
    area = float(np.linalg.norm(n))
    if not area > 0.0:
        raise ValueError(f"Dipolar slab: the periodic cell vectors {cell[:2].tolist()} "
                         "span no plane")
    n /= area
    height = float(cell[2] @ n)
    if not height > 0.0:
        raise ValueError("Dipolar slab: the third cell vector must reach across the slab "
                         f"(a positive height along a×b), got {cell[2].tolist()}; give the "
                         "slab's cell height (atoms plus some vacuum) as cell[2]")
    extended = cell.copy()
    extended[2] *= factor
    return extended, n, height


class SlabCorrection:
    r"""The Yeh–Berkowitz correction (I.-C. Yeh, M. L. Berkowitz, J. Chem. Phys.
    111, 3155 (1999); for dipoles A. Bródka, Chem. Phys. Lett. 400, 62 (2004)),
    which turns the tin-foil Ewald sum of slabs stacked along n̂ into that of
    one slab periodic in its plane, up to terms that fall off exponentially
    with the vacuum between images (the field outside a uniformly
    magnetised infinite plate vanishes):

    E_s = (2π/V') (M·n̂)²,  M = Σ_i m_i,

    in units of μ0μB²/4π (m_i = μ_i s_i in μB, V' the volume of the extended
    cell). For point dipoles the cell's moment is M itself (charges have
    Σ q_i z_i), so E_s depends on the spins alone: no lattice forces. It is
    minus the energy of the planar-sum surface term: the 3D sum over images
    stacked slab after slab, in vacuum, has the depolarising energy
    2π (M·n̂)²/V' of an infinite plate, which tin-foil boundaries remove."""

    __slots__ = ("coef", "n")

    def __init__(self, volume, normal):
        self.coef = 2.0 * math.pi / volume
        self.n = np.asarray(normal, dtype=float)

    def add(self, m, H, want_v):
        """E_s; H −= ∂E_s/∂m_i = 2 (2π/V')(M·n̂) n̂ on every row (H may be None),
        and the virial ∂E_s/∂ε = −E_s δ − (2π/V')(M·n̂)(M n̂ᵀ + n̂ Mᵀ)
        + 2 E_s n̂ n̂ᵀ (the volume and the normal strained, n̂ ∝ (1 − ε)n̂)."""
        M = m.sum(axis=0)
        Mn = float(M @ self.n)
        energy = self.coef * Mn * Mn
        if H is not None:
            H -= (2.0 * self.coef * Mn) * self.n
        virial = np.zeros(6)
        if want_v:
            W = (-energy * np.eye(3) - self.coef * Mn * (np.outer(M, self.n) + np.outer(self.n, M))
                 + 2.0 * energy * np.outer(self.n, self.n))
            virial = W[[0, 1, 2, 1, 0, 0], [0, 1, 2, 2, 2, 1]]
        return energy, virial
