"""The compiled pair kernels of the dipolar term (:class:`~ase_spin.terms.dipolar.Dipolar`):
the (screened) dipole tensor of a pair, passes over a pair list (the plain
cutoff, the Ewald sum's real-space part) and the direct sum over every pair
of an open system. The passes over a pair list are threaded over rows in
the shared skeleton of :mod:`ase_spin._jit.reductions` (fixed chunks,
per-thread buffers summed in order: the same bits whatever the thread count)."""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from .._jit.reductions import (add_row, add_to, balanced_chunks, reduce_scatter, reduce_threads,
                               reduce_threads_serial, scatter_buffers, store_sums, sub_row,
                               thread_buffer)
from .._jit.threads import threaded

__all__ = ["cut_site", "direct_field", "direct_pass", "list_field", "list_pass", "pair_geometry"]

_TWO_OVER_SQRT_PI = 2.0 / math.sqrt(math.pi)


# -- the pair functions -------------------------------------------------------

@nb.njit(cache=True, inline="always")
def _radial(r2, alpha):
    r"""B1, B2, B3 of the (screened) dipole tensor at r² (α = 0: bare):

    B0 = erfc(αr)/r,  B_l = [(2l − 1) B_{l−1} + (2α²)^l e^{−α²r²}/(α√π)] / r²,

    so that B_l = −B'_{l−1}/r; bare, B1 = 1/r³, B2 = 3/r⁵, B3 = 15/r⁷."""
    r = math.sqrt(r2)
    inv2 = 1.0 / r2
    if alpha == 0.0:
        b1 = inv2 / r
        b2 = 3.0 * b1 * inv2
        return b1, b2, 5.0 * b2 * inv2
    a2 = alpha * alpha
    g = _TWO_OVER_SQRT_PI * alpha * math.exp(-a2 * r2)
    b1 = (math.erfc(alpha * r) / r + g) * inv2
    g *= 2.0 * a2
    b2 = (3.0 * b1 + g) * inv2
    g *= 2.0 * a2
    return b1, b2, (5.0 * b2 + g) * inv2


@nb.njit(cache=True, inline="always")
def _pair(mi, mj, dx, dy, dz, b1, b2, b3, i, j):
    """One pair's e = (m_i·m_j) B1 − (m_i·d)(m_j·d) B2 (times μ0μB²/4π: the
    energy), g = ∂e/∂d = −(m_i·m_j) B2 d + (m_i·d)(m_j·d) B3 d
    − B2 [(m_j·d) m_i + (m_i·d) m_j] (−g is the force on j), d = r_j − r_i."""
    a = mi[i, 0] * dx + mi[i, 1] * dy + mi[i, 2] * dz
    b = mj[j, 0] * dx + mj[j, 1] * dy + mj[j, 2] * dz
    c = mi[i, 0] * mj[j, 0] + mi[i, 1] * mj[j, 1] + mi[i, 2] * mj[j, 2]
    e = c * b1 - a * b * b2
    radial = a * b * b3 - c * b2
    gx = radial * dx - b2 * (b * mi[i, 0] + a * mj[j, 0])
    gy = radial * dy - b2 * (b * mi[i, 1] + a * mj[j, 1])
    gz = radial * dz - b2 * (b * mi[i, 2] + a * mj[j, 2])
    return e, gx, gy, gz


@nb.njit(cache=True, inline="always")
def _add_pair_field(H, i, m, j, dx, dy, dz, b1, b2):
    """H_i += −∂e/∂m_i = B2 (m_j·d) d − B1 m_j (the same for d → −d)."""
    b = (m[j, 0] * dx + m[j, 1] * dy + m[j, 2] * dz) * b2
    H[i, 0] += b * dx - b1 * m[j, 0]
    H[i, 1] += b * dy - b1 * m[j, 1]
    H[i, 2] += b * dz - b1 * m[j, 2]


@nb.njit(cache=True, inline="always")
def cut_site(i, s, data):
    """B_i = C μ_i Σ_j μ_j [B2 (s_j·d) d − B1 s_j] over a full pair list, from
    the spins as they are (the sequential sweeps' field of ``"cut"``)."""
    row, nbr, D, B, mu, pref = data
    bx = 0.0
    by = 0.0
    bz = 0.0
    for k in range(row[i], row[i + 1]):
        j = nbr[k]
        dx = D[k, 0]
        dy = D[k, 1]
        dz = D[k, 2]
        b = (s[j, 0] * dx + s[j, 1] * dy + s[j, 2] * dz) * B[k, 1]
        bx += mu[j] * (b * dx - B[k, 0] * s[j, 0])
        by += mu[j] * (b * dy - B[k, 0] * s[j, 1])
        bz += mu[j] * (b * dz - B[k, 0] * s[j, 2])
    c = pref[0] * mu[i]
    return c * bx, c * by, c * bz


# -- passes over a pair list (cut, ewald real space) -----------------------------

@threaded()
def pair_geometry(nthreads, pos, row, nbr, image, images, rc2, alpha, D, B):
    """For every pair k = (i → j): D_k = d_ij = r_j + S_k − r_i and
    B_k = (B1, B2, B3)(r_ij) of :func:`_radial`; zero beyond rc (the list
    carries a skin) or at r = 0. Rows in ``nthreads`` chunks of equal pair
    count."""
    bounds = balanced_chunks(row, nthreads)
    for t in nb.prange(nthreads):
        for i in range(bounds[t], bounds[t + 1]):
            for k in range(row[i], row[i + 1]):
                j = nbr[k]
                m = image[k]
                dx = (pos[j, 0] - pos[i, 0]) + images[m, 0]
                dy = (pos[j, 1] - pos[i, 1]) + images[m, 1]
                dz = (pos[j, 2] - pos[i, 2]) + images[m, 2]
                r2 = dx * dx + dy * dy + dz * dz
                D[k, 0] = dx
                D[k, 1] = dy
                D[k, 2] = dz
                if r2 >= rc2 or r2 == 0.0:
                    B[k, 0] = B[k, 1] = B[k, 2] = 0.0
                else:
                    B[k, 0], B[k, 1], B[k, 2] = _radial(r2, alpha)


@threaded(reduce_threads=lambda: reduce_threads_serial)
def list_field(nthreads, row, nbr, half, m, D, B, H):
    """H_i += Σ_j [B2 (m_j·d_ij) d_ij − B1 m_j] over a pair list (a half list
    also adds the pair's field on j, into per-thread buffers)."""
    bounds = balanced_chunks(row, nthreads)
    buf = thread_buffer(nthreads, len(row) - 1, half, 3)
    for t in nb.prange(nthreads):
        for i in range(bounds[t], bounds[t + 1]):
            hx = 0.0
            hy = 0.0
            hz = 0.0
            for k in range(row[i], row[i + 1]):
                j = nbr[k]
                dx = D[k, 0]
                dy = D[k, 1]
                dz = D[k, 2]
                b1 = B[k, 0]
                b2 = B[k, 1]
                b = (m[j, 0] * dx + m[j, 1] * dy + m[j, 2] * dz) * b2
                hx += b * dx - b1 * m[j, 0]
                hy += b * dy - b1 * m[j, 1]
                hz += b * dz - b1 * m[j, 2]
                if half:
                    a = (m[i, 0] * dx + m[i, 1] * dy + m[i, 2] * dz) * b2
                    add_row(buf, t, j, 0, a * dx - b1 * m[i, 0], a * dy - b1 * m[i, 1],
                            a * dz - b1 * m[i, 2])
            if half:
                add_row(buf, t, i, 0, hx, hy, hz)
            else:
                add_to(H, i, hx, hy, hz)
    if half:
        reduce_threads(buf, H)


@threaded(reduce_threads=lambda: reduce_threads_serial)
def list_pass(nthreads, row, nbr, half, m, D, B, F, energies, want_f, want_e):
    """Σ e (:func:`_pair`) over a pair list and its derivatives: F_j −= g,
    F_i += g, e_i, e_j += ½e, W += sym(g ⊗ d) (Voigt xx yy zz yz xz xy). A
    full list holds each pair twice: row i then adds to atom i alone, with
    half of e and W. Returns (E, W...)."""
    w = 1.0 if half else 0.5
    bounds, fbuf, ebuf, acc = scatter_buffers(row, nthreads, want_f, want_e)
    for t in nb.prange(nthreads):
        e_sum = vxx = vyy = vzz = vyz = vxz = vxy = 0.0
        for i in range(bounds[t], bounds[t + 1]):
            for k in range(row[i], row[i + 1]):
                if B[k, 0] == 0.0:
                    continue
                j = nbr[k]
                dx = D[k, 0]
                dy = D[k, 1]
                dz = D[k, 2]
                e, gx, gy, gz = _pair(m, m, dx, dy, dz, B[k, 0], B[k, 1], B[k, 2], i, j)
                e_sum += w * e
                vxx += w * gx * dx
                vyy += w * gy * dy
                vzz += w * gz * dz
                vyz += 0.5 * w * (gy * dz + gz * dy)
                vxz += 0.5 * w * (gx * dz + gz * dx)
                vxy += 0.5 * w * (gx * dy + gy * dx)
                if want_f:
                    add_row(fbuf, t, i, 0, gx, gy, gz)
                    if half:
                        sub_row(fbuf, t, j, 0, gx, gy, gz)
                if want_e:
                    ebuf[t, i, 0] += 0.5 * e
                    if half:
                        ebuf[t, j, 0] += 0.5 * e
        store_sums(acc, t, e_sum, vxx, vyy, vzz, vyz, vxz, vxy)
    return reduce_scatter(reduce_threads, fbuf, F, ebuf, energies, acc)


# -- the direct sum over all pairs (open systems) -------------------------------

@nb.njit(cache=True)
def direct_field(pos, m, H):
    """H_i += Σ_{j≠i} [3 (m_j·d) d/r⁵ − m_j/r³] over all pairs of magnetic atoms."""
    n = pos.shape[0]
    for i in range(n):
        if m[i, 0] == 0.0 and m[i, 1] == 0.0 and m[i, 2] == 0.0:
            continue
        for j in range(i + 1, n):
            if m[j, 0] == 0.0 and m[j, 1] == 0.0 and m[j, 2] == 0.0:
                continue
            dx = pos[j, 0] - pos[i, 0]
            dy = pos[j, 1] - pos[i, 1]
            dz = pos[j, 2] - pos[i, 2]
            b1, b2, _ = _radial(dx * dx + dy * dy + dz * dz, 0.0)
            _add_pair_field(H, i, m, j, dx, dy, dz, b1, b2)
            _add_pair_field(H, j, m, i, dx, dy, dz, b1, b2)


@nb.njit(cache=True)
def direct_pass(pos, m, F, energies, want_f, want_e):
    """:func:`list_pass` over all pairs i < j of magnetic atoms, bare."""
    n = pos.shape[0]
    v = np.zeros(7)
    for i in range(n):
        if m[i, 0] == 0.0 and m[i, 1] == 0.0 and m[i, 2] == 0.0:
            continue
        for j in range(i + 1, n):
            if m[j, 0] == 0.0 and m[j, 1] == 0.0 and m[j, 2] == 0.0:
                continue
            dx = pos[j, 0] - pos[i, 0]
            dy = pos[j, 1] - pos[i, 1]
            dz = pos[j, 2] - pos[i, 2]
            b1, b2, b3 = _radial(dx * dx + dy * dy + dz * dz, 0.0)
            e, gx, gy, gz = _pair(m, m, dx, dy, dz, b1, b2, b3, i, j)
            v[0] += e
            v[1] += gx * dx
            v[2] += gy * dy
            v[3] += gz * dz
            v[4] += 0.5 * (gy * dz + gz * dy)
            v[5] += 0.5 * (gx * dz + gz * dx)
            v[6] += 0.5 * (gx * dy + gy * dx)
            if want_f:
                F[i, 0] += gx
                F[i, 1] += gy
                F[i, 2] += gz
                F[j, 0] -= gx
                F[j, 1] -= gy
                F[j, 2] -= gz
            if want_e:
                energies[i] += 0.5 * e
                energies[j] += 0.5 * e
    return v
