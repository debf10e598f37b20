"""The exchange passes over a prepared operator's pairs (J and G = J'(r) d/r,
or g = J'(r)/r with d recomputed): fields, forces, energies and virial for given
spins, over full or half pair lists, and their compiled twins — the g form,
one request's flags as constants, two operators' forces in one pass."""

from __future__ import annotations

import numba as nb
import numpy as np

from .._jit.cloning import kernel_twin
from .._jit.reductions import (add_row, add_to, balanced_chunks, reduce_scatter,
                               reduce_threads, reduce_threads_serial, scatter_buffers,
                               store_sums, sum_over_threads, thread_buffer)
from .._jit.threads import threaded
from ..neighbors import separation

__all__ = ["FIELD_ONLY", "FORCES_AND_FIELD", "spin_pass_kernel",
           "spin_pass_formed", "spin_pass_half_kernel", "spin_pass_half_formed",
           "spin_pass_half_field", "spin_pass_half_forces_field",
           "virial_pass", "forces_two_pass", "add_kept_pass"]


#: Read by the pass kernels below as a compile-time constant: False in the
#: kernels of operators keeping G (they read it), True in their twins for
#: operators keeping g (:func:`_formed_twin`: they form G = g d per pair). Two
#: compiled kernels, not a branch per pair: the G kernels' force loop is then
#: the one that read G before g existed, as fast.
_FORMED = False
#: Read by :func:`_spin_pass` as a compile-time constant: False in the
#: kernels over a full pair list, True in their twins over a half list
#: (``spin_pass_half_*``). One pass, two compiled kernels: each holds only its
#: own list's scatter or gather and sums.
_HALF = False
#: Read by :func:`_spin_pass` as a compile-time constant: None in the
#: kernels for any request (the flags are arguments), or the flags (want_b,
#: want_f, want_energy, want_energies, want_virial) themselves in its half-list twins for
#: the two requests of every step — forces alone (the integrators' force
#: passes) and fields alone — whose loops then hold no branch on them
#: (docs/benchmarks.md, "Why each fast path exists").
_WANT = None


def _pass_twin(fn, suffix, **constants):
    """``fn`` (:func:`_spin_pass` or one of its twins) with the module constants
    ``constants`` replaced (:func:`~ase_spin._jit.cloning.kernel_twin`), and so
    the chunk function it calls: its twin takes the same constants."""
    chunk = fn.__globals__["_spin_pass_chunk"]
    chunk_twin = nb.njit(cache=True, error_model="numpy")(
        kernel_twin(chunk.py_func, suffix, **constants))
    return kernel_twin(fn, suffix, _spin_pass_chunk=chunk_twin, **constants)


def _formed_twin(fn):
    """``fn`` with ``_FORMED = True`` (:func:`_pass_twin`)."""
    return _pass_twin(fn, "_formed", _FORMED=True)


#: The requests with twins of their own (see _WANT).
FIELD_ONLY = (True, False, False, False, False)
FORCES_AND_FIELD = (True, True, False, False, False)


@nb.njit(cache=True, inline="always")
def _add_thread_sums(buf, i, col, base, out):
    """out_i = base_i + Σ_t buf[t, i, col:col + 3], t in order: reduce_threads'
    rounding, for the per-thread buffers holding several results per atom."""
    x = base[i, 0]
    y = base[i, 1]
    z = base[i, 2]
    for t in range(buf.shape[0]):
        x += buf[t, i, col]
        y += buf[t, i, col + 1]
        z += buf[t, i, col + 2]
    out[i, 0] = x
    out[i, 1] = y
    out[i, 2] = z


def _spin_pass(nthreads, row, nbr, image, images, J, g, G, pos, s, u, c, B, F, energies,
               want_b, want_f, want_energy, want_energies, want_virial):
    """One pass over the exchange pairs for spins s, w = s_i·s_j − c,
    G_ij = J'(r_ij) d_ij/r_ij read from ``G`` (or, in the :func:`_formed_twin`,
    formed as g_ij d_ij), d_ij = (r_j − r_i) + S_ij recomputed from the
    positions ``pos`` the operator was prepared at. Over a full list (each
    pair both ways, gathered into row i):

    B_i += Σ_j J_ij u_j,   F_i += −Σ_j w G_ij,
    e_i += −½ Σ_j J_ij w,   W += −½ Σ_ij w G_ij ⊗ d_ij;

    over a half list (:data:`_HALF`: each pair once, scattered into both rows
    through per-thread buffers, summed in thread order):

    B_i += J u_j, B_j += J u_i,   F_i −= w G, F_j += w G,
    e_i, e_j −= ½ J w,   W −= w G ⊗ d;

    the field B for spins ``u`` (s itself but in :meth:`ExchangeOperator.forces_and_field`).

    (G_ij = g·d is the product the geometry pass stores in G, scaled by w after:
    the same bits either way.) The G kernel reads no positions and gives no
    virial (``want_virial`` False; :func:`virial_pass` adds it): its loop
    holds nothing it does not need. Rows in ``nthreads`` fixed chunks, each
    summing its own energy and virial: the sums do not depend on how many
    threads run the chunks. Returns (E if ``want_energy`` else 0, W in Voigt
    order).
    """
    if _WANT is not None:  # a twin for one request: the flags are constants
        want_b, want_f, want_energy, want_energies, want_virial = _WANT
    # a half list's forces and field together (forces_and_field): one buffer,
    # both on one cache line per atom j (two buffers of the scattered rows miss twice)
    both = _HALF and want_b and want_f
    bounds, fbuf, ebuf, acc = scatter_buffers(row, nthreads, _HALF and want_f and not both,
                                              _HALF and want_energies)
    bbuf = thread_buffer(nthreads, len(row) - 1, _HALF and want_b and not both, 3)
    pbuf = thread_buffer(nthreads, len(row) - 1, both, 6)
    # where the scattered forces and fields go: columns 0-2 of fb, bo.. of bb
    fb = pbuf if both else fbuf
    bb, bo = (pbuf, 3) if both else (bbuf, 0)
    for t in nb.prange(nthreads):
        _spin_pass_chunk(np.int64(t), want_b, want_f, want_energy, want_energies, want_virial,
                         bounds, s, u, pos, row, nbr, J, c, bb, bo, fb, ebuf, B, F, energies,
                         image, g, G, images, acc)
    if _HALF:
        reduce_threads(bbuf, B)
        # F and B: from fbuf, bbuf or from pbuf, never both (the others are empty)
        for i in nb.prange(pbuf.shape[1]):
            _add_thread_sums(pbuf, i, 0, F, F)
            _add_thread_sums(pbuf, i, 3, B, B)
        out = reduce_scatter(reduce_threads, fbuf, F, ebuf, energies, acc)
    else:
        out = sum_over_threads(acc)
    return out[0], out[1], out[2], out[3], out[4], out[5], out[6]


@nb.njit(cache=True, error_model="numpy")
def _spin_pass_chunk(t, want_b, want_f, want_energy, want_energies, want_virial, bounds, s, u,
                     pos, row, nbr, J, c, bb, bo, fb, ebuf, B, F, energies, image, g, G, images,
                     acc):
    """One chunk ``t`` of :func:`_spin_pass`'s threaded loop: its work,
    compiled once for the threaded kernel and its serial twin (twinned with
    the pass: :func:`_pass_twin`, the same compile-time constants)."""
    if _WANT is not None:  # a twin for one request: the flags are constants
        want_b, want_f, want_energy, want_energies, want_virial = _WANT
    need_dot = want_f or want_energy or want_energies or want_virial
    need_d = _FORMED
    e = vxx = vyy = vzz = vyz = vxz = vxy = 0.0
    for i in range(bounds[t], bounds[t + 1]):
        sx = s[i, 0]
        sy = s[i, 1]
        sz = s[i, 2]
        if _HALF:
            vx = u[i, 0]
            vy = u[i, 1]
            vz = u[i, 2]
        if need_d:
            xi = pos[i, 0]
            yi = pos[i, 1]
            zi = pos[i, 2]
        else:
            xi = yi = zi = 0.0
        bx = by = bz = 0.0
        fx = fy = fz = ei = 0.0
        for k in range(row[i], row[i + 1]):
            j = nbr[k]
            Jk = J[k]
            if want_b:
                bx += Jk * u[j, 0]
                by += Jk * u[j, 1]
                bz += Jk * u[j, 2]
                if _HALF:
                    add_row(bb, t, j, bo, Jk * vx, Jk * vy, Jk * vz)
            if need_dot:
                w = sx * s[j, 0] + sy * s[j, 1] + sz * s[j, 2] - c
                if not _HALF:
                    ei -= 0.5 * Jk * w
                elif want_energy or want_energies:  # ½ J w for each end of the pair
                    ei -= Jk * w
                    if want_energies:
                        ebuf[t, j, 0] -= 0.5 * Jk * w
                if need_d:
                    # d = (r_j − r_i) + S as separation() forms it, r_i loaded once
                    m = image[k]
                    dx = (pos[j, 0] - xi) + images[m, 0]
                    dy = (pos[j, 1] - yi) + images[m, 1]
                    dz = (pos[j, 2] - zi) + images[m, 2]
                else:
                    dx = dy = dz = 0.0
                if _FORMED:
                    # G = g d, the geometry pass's product, before w scales it
                    gk = g[k]
                    Gx = gk * dx
                    Gy = gk * dy
                    Gz = gk * dz
                else:
                    Gx = G[k, 0]
                    Gy = G[k, 1]
                    Gz = G[k, 2]
                gx = w * Gx
                gy = w * Gy
                gz = w * Gz
                if want_f:
                    fx -= gx
                    fy -= gy
                    fz -= gz
                    if _HALF:
                        add_row(fb, t, j, 0, gx, gy, gz)
                if want_virial and _HALF:
                    vxx -= gx * dx
                    vyy -= gy * dy
                    vzz -= gz * dz
                    vyz -= gy * dz
                    vxz -= gx * dz
                    vxy -= gx * dy
                elif want_virial:
                    h = -0.5 * w
                    vxx += h * Gx * dx
                    vyy += h * Gy * dy
                    vzz += h * Gz * dz
                    vyz += h * Gy * dz
                    vxz += h * Gx * dz
                    vxy += h * Gx * dy
        if _HALF:
            if want_b:
                add_row(bb, t, i, bo, bx, by, bz)
            if want_f:
                add_row(fb, t, i, 0, fx, fy, fz)
            if want_energies:
                ebuf[t, i, 0] += 0.5 * ei
        else:
            if want_b:
                add_to(B, i, bx, by, bz)
            if want_f:
                add_to(F, i, fx, fy, fz)
            if want_energies:
                energies[i] += ei
        if want_energy:
            e += ei
    store_sums(acc, t, e, vxx, vyy, vzz, vyz, vxz, vxy)


@threaded()
def virial_pass(nthreads, row, nbr, image, images, G, pos, s, c, half):
    """The exchange virial for spins s from stored G = J'(r) d/r and d
    recomputed from ``pos``, w = s_i·s_j − c: W = −Σ_k w G_k ⊗ d_k over a half
    list, −½ Σ_k w G_k ⊗ d_k over a full one; Voigt order. The rows, chunks and
    per-pair products of the passes above in the same order (the same sums)."""
    bounds = balanced_chunks(row, nthreads)
    acc = np.zeros((nthreads, 7))
    for t in nb.prange(nthreads):
        _virial_pass_chunk(np.int64(t), bounds, s, half, row, nbr, c, pos, images, image, G, acc)
    return sum_over_threads(acc)


@nb.njit(cache=True, error_model="numpy")
def _virial_pass_chunk(t, bounds, s, half, row, nbr, c, pos, images, image, G, acc):
    """One chunk ``t`` of :func:`virial_pass`'s threaded loop: its work,
    compiled once for the threaded kernel and its serial twin."""
    vxx = vyy = vzz = vyz = vxz = vxy = 0.0
    for i in range(bounds[t], bounds[t + 1]):
        sx = s[i, 0]
        sy = s[i, 1]
        sz = s[i, 2]
        for k in range(row[i], row[i + 1]):
            j = nbr[k]
            w = sx * s[j, 0] + sy * s[j, 1] + sz * s[j, 2] - c
            dx, dy, dz, r2 = separation(pos, images, i, j, image[k])
            if half:
                gx = w * G[k, 0]
                gy = w * G[k, 1]
                gz = w * G[k, 2]
                vxx -= gx * dx
                vyy -= gy * dy
                vzz -= gz * dz
                vyz -= gy * dz
                vxz -= gx * dz
                vxy -= gx * dy
            else:
                h = -0.5 * w
                vxx += h * G[k, 0] * dx
                vyy += h * G[k, 1] * dy
                vzz += h * G[k, 2] * dz
                vyz += h * G[k, 1] * dz
                vxz += h * G[k, 0] * dz
                vxy += h * G[k, 0] * dy
    store_sums(acc, t, 0.0, vxx, vyy, vzz, vyz, vxz, vxy)


@threaded()
def forces_two_pass(nthreads, row, nbr, G, G2, s, c, F, keep, J2, u, B):
    """Over a half list, w = s_i·s_j − c, the forces of two pair geometries of
    one list (G at the positions q, G2 at q̃) for the same spins s, each with
    the arithmetic of :func:`_spin_pass`'s forces over a half list:

    F_i −= w G, F_j += w G (summed into F);  the same with G2, left as
    per-thread partial sums in keep[t, :, 0:3] (:func:`add_kept_pass`);

    with ``u`` (non-empty), also B_i += J2 u_j, B_j += J2 u_i (summed into B).
    ``keep`` (nthreads, n, 6 or 9) is the scatter buffer, all of one atom's
    columns on one cache line: keep[t, :, 3:6] the forces at q, 6:9 the field."""
    n = len(row) - 1
    bounds = balanced_chunks(row, nthreads)
    want_b = u.shape[0] > 0
    for t in nb.prange(nthreads):
        _forces_two_pass_chunk(np.int64(t), n, keep, want_b, bounds, s, u, row, nbr, c, J2, G, G2)
    for i in nb.prange(n):
        _add_thread_sums(keep, i, 3, F, F)
        if want_b:
            _add_thread_sums(keep, i, 6, B, B)


@nb.njit(cache=True, error_model="numpy")
def _forces_two_pass_chunk(t, n, keep, want_b, bounds, s, u, row, nbr, c, J2, G, G2):
    """One chunk ``t`` of :func:`forces_two_pass`'s threaded loop: its work,
    compiled once for the threaded kernel and its serial twin."""
    for i in range(n):
        for col in range(keep.shape[2]):
            keep[t, i, col] = 0.0
    for i in range(bounds[t], bounds[t + 1]):
        sx = s[i, 0]
        sy = s[i, 1]
        sz = s[i, 2]
        vx = u[i, 0] if want_b else 0.0
        vy = u[i, 1] if want_b else 0.0
        vz = u[i, 2] if want_b else 0.0
        fx = 0.0
        fy = 0.0
        fz = 0.0
        hx = 0.0
        hy = 0.0
        hz = 0.0
        bx = 0.0
        by = 0.0
        bz = 0.0
        for k in range(row[i], row[i + 1]):
            j = nbr[k]
            if want_b:
                Jk = J2[k]
                bx += Jk * u[j, 0]
                by += Jk * u[j, 1]
                bz += Jk * u[j, 2]
                keep[t, j, 6] += Jk * vx
                keep[t, j, 7] += Jk * vy
                keep[t, j, 8] += Jk * vz
            w = sx * s[j, 0] + sy * s[j, 1] + sz * s[j, 2] - c
            gx = w * G[k, 0]
            gy = w * G[k, 1]
            gz = w * G[k, 2]
            fx -= gx
            fy -= gy
            fz -= gz
            keep[t, j, 3] += gx
            keep[t, j, 4] += gy
            keep[t, j, 5] += gz
            gx = w * G2[k, 0]
            gy = w * G2[k, 1]
            gz = w * G2[k, 2]
            hx -= gx
            hy -= gy
            hz -= gz
            keep[t, j, 0] += gx
            keep[t, j, 1] += gy
            keep[t, j, 2] += gz
        if want_b:
            keep[t, i, 6] += bx
            keep[t, i, 7] += by
            keep[t, i, 8] += bz
        keep[t, i, 3] += fx
        keep[t, i, 4] += fy
        keep[t, i, 5] += fz
        keep[t, i, 0] += hx
        keep[t, i, 1] += hy
        keep[t, i, 2] += hz


@threaded()
def add_kept_pass(keep, base, out):
    """out_i = base_i + Σ_t keep[t, i, 0:3] (:func:`_add_thread_sums`)."""
    for i in nb.prange(base.shape[0]):
        _add_thread_sums(keep, i, 0, base, out)


spin_pass_kernel = threaded()(_spin_pass)
spin_pass_formed = threaded()(_formed_twin(_spin_pass))
_spin_pass_half = _pass_twin(_spin_pass, "_half", _HALF=True)
spin_pass_half_kernel = threaded(reduce_threads=lambda: reduce_threads_serial)(_spin_pass_half)
spin_pass_half_formed = threaded(reduce_threads=lambda: reduce_threads_serial)(
    _formed_twin(_spin_pass_half))
spin_pass_half_field = threaded(reduce_threads=lambda: reduce_threads_serial)(
    _pass_twin(_spin_pass_half, "_field", _WANT=FIELD_ONLY))
spin_pass_half_forces_field = threaded(reduce_threads=lambda: reduce_threads_serial)(
    _pass_twin(_spin_pass_half, "_forces_field", _WANT=FORCES_AND_FIELD))
