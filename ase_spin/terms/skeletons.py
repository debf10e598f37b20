"""The compiled skeletons of the spin terms: the pass over atoms of every
single-site term and the pass over pairs of every pair spin term, each
compiled once per term with that term's compiled functions bound in
(:func:`compile_site_pass`, :func:`compile_pair_pass`), and the field of a
term linear in the spins over a pair list (:func:`linear_pair_field`)."""

from __future__ import annotations

import numba as nb
import numpy as np

from .._jit.cloning import compile_with
from .._jit.reductions import (add_row, add_to, balanced_chunks, reduce_scatter, reduce_threads,
                               sum_over_threads, thread_buffer)

__all__ = ["linear_pair_field", "compile_site_pass", "compile_pair_pass"]


@nb.njit(cache=True, inline="always")
def linear_pair_field(i, s, row, nbr, c):
    """B_i = Σ_j c_k s_j over row i of a pair list: the field of a term in the
    ``linear_pairs`` form, from the spins as they are."""
    bx = 0.0
    by = 0.0
    bz = 0.0
    for k in range(row[i], row[i + 1]):
        j = nbr[k]
        bx += c[k] * s[j, 0]
        by += c[k] * s[j, 1]
        bz += c[k] * s[j, 2]
    return bx, by, bz


def _site_pass(s, data, B, energies, want_b, want_energies):
    """Skeleton of every single-site term's pass (compiled once per term, with
    ``site_field`` and ``site_energy`` bound to that term's functions):
    B_i += b(i, s, data), e_i += e(i, s, data); returns Σ_i e_i."""
    total = 0.0
    for i in range(s.shape[0]):
        if s[i, 0] == 0.0 and s[i, 1] == 0.0 and s[i, 2] == 0.0:
            continue
        if want_b:
            bx, by, bz = site_field(i, s, data)  # noqa: F821 - bound per term
            B[i, 0] += bx
            B[i, 1] += by
            B[i, 2] += bz
        e = site_energy(i, s, data)  # noqa: F821 - bound per term
        total += e
        if want_energies:
            energies[i] += e
    return total


def compile_site_pass(field, energy, name):
    """:func:`_site_pass` for one term's compiled ``field(i, s, data) -> (Bx,
    By, Bz)`` and ``energy(i, s, data) -> E_i``, cached on disk under a name
    that changes with their code (a cached skeleton must not outlive an edit
    of the functions it calls)."""
    return compile_with(_site_pass, {"site_field": field, "site_energy": energy}, name)


def _pair_pass(nthreads, row, nbr, half, s, data, B, F, energies, want_b, want_f,
               want_energy, want_energies, want_virial):
    """Skeleton of every pair spin term's pass over a pair list (compiled once
    per term, with ``pair_pass_chunk`` bound to that term's
    :func:`_pair_pass_chunk`). For each pair k = (i → j) of row i:

        B_i += b(k, i, j, s, data, False)      (half list: B_j += b(k, j, i, s, data, True))
        (e, f, d) = pair_energy(k, i, j, s, data):  E += e,  F_j += f,  F_i −= f,
        e_i, e_j += ½e,  W −= sym(f ⊗ d)

    with f = −∂e/∂r_j the force on j and d = r_j + S − r_i. A full list holds
    each pair twice: there row i adds only to atom i, and halves e and W.
    Returns (E, W in Voigt order xx yy zz yz xz xy)."""
    bounds = balanced_chunks(row, nthreads)
    scatter = half
    n = len(row) - 1
    bbuf = thread_buffer(nthreads, n, scatter and want_b, 3)
    fbuf = thread_buffer(nthreads, n, scatter and want_f, 3)
    ebuf = thread_buffer(nthreads, n, scatter and want_energies, 1)
    acc = np.zeros((nthreads, 7))
    need_e = want_f or want_energy or want_energies or want_virial
    w = 1.0 if half else 0.5
    for t in nb.prange(nthreads):
        pair_pass_chunk(np.int64(t), bounds, row, nbr, s, data, B, F, energies,  # noqa: F821
                        bbuf, fbuf, ebuf, acc, scatter, want_b, want_f, want_energies,
                        want_virial, need_e, w)
    if scatter:
        reduce_threads(bbuf, B)
        return reduce_scatter(reduce_threads, fbuf, F, ebuf, energies, acc)
    return sum_over_threads(acc)


def _pair_pass_chunk(t, bounds, row, nbr, s, data, B, F, energies, bbuf, fbuf, ebuf, acc,
                     scatter, want_b, want_f, want_energies, want_virial, need_e, w):
    """One chunk ``t`` of :func:`_pair_pass`'s threaded loop (compiled once per
    term, with ``pair_field`` and ``pair_energy`` bound to that term's
    functions): numba compiles a chunk's work once as a function of its own,
    not again inside the threaded loop."""
    v = np.zeros(7)
    for i in range(bounds[t], bounds[t + 1]):
        if s[i, 0] == 0.0 and s[i, 1] == 0.0 and s[i, 2] == 0.0:
            continue
        bx = by = bz = 0.0
        fx = fy = fz = ei = 0.0
        for k in range(row[i], row[i + 1]):
            j = nbr[k]
            if want_b:
                cx, cy, cz = pair_field(k, i, j, s, data, False)  # noqa: F821
                bx += cx
                by += cy
                bz += cz
                if scatter:
                    cx, cy, cz = pair_field(k, j, i, s, data, True)  # noqa: F821
                    add_row(bbuf, t, j, 0, cx, cy, cz)
            if need_e:
                e, gx, gy, gz, dx, dy, dz = pair_energy(k, i, j, s, data)  # noqa: F821
                ei += 0.5 * e
                v[0] += w * e
                fx -= gx
                fy -= gy
                fz -= gz
                if scatter:
                    if want_f:
                        add_row(fbuf, t, j, 0, gx, gy, gz)
                    if want_energies:
                        ebuf[t, j, 0] += 0.5 * e
                if want_virial:
                    v[1] -= w * gx * dx
                    v[2] -= w * gy * dy
                    v[3] -= w * gz * dz
                    v[4] -= 0.5 * w * (gy * dz + gz * dy)
                    v[5] -= 0.5 * w * (gx * dz + gz * dx)
                    v[6] -= 0.5 * w * (gx * dy + gy * dx)
        if scatter:
            if want_b:
                add_row(bbuf, t, i, 0, bx, by, bz)
            if want_f:
                add_row(fbuf, t, i, 0, fx, fy, fz)
            if want_energies:
                ebuf[t, i, 0] += ei
        else:  # row i belongs to this thread alone
            if want_b:
                add_to(B, i, bx, by, bz)
            if want_f:
                add_to(F, i, fx, fy, fz)
            if want_energies:
                energies[i] += ei
    for c in range(7):
        acc[t, c] = v[c]


def compile_pair_pass(field, energy, name):
    """:func:`_pair_pass` for one term's compiled ``field(k, a, b, s, data,
    reverse) -> (Bx, By, Bz)`` (the field on spin a from spin b over pair k,
    ``reverse`` when a is the pair's second atom) and ``energy(k, i, j, s,
    data) -> (e, fx, fy, fz, dx, dy, dz)``, cached on disk under a name that
    changes with their code."""
    chunk = compile_with(_pair_pass_chunk, {"pair_field": field, "pair_energy": energy}, name,
                         error_model="numpy")
    return compile_with(_pair_pass, {"pair_pass_chunk": chunk}, name, parallel=True)
