"""The exchange couplings of every pair, compiled: J(r) and J'(r)/r at given
positions for the operators (one species, or a table of species pairs), and
the direct pass that evaluates exchange from positions without keeping them.

The Bethe–Slater form's exp(−r²/J3²) comes from :func:`exp_minus`, an
exponential of this module's own that LLVM vectorises, a block of pairs at a
time (docs/terms.md, "The Bethe–Slater exponential")."""

from __future__ import annotations

import numba as nb
import numpy as np

from .._jit.reductions import (add_row, reduce_scatter, reduce_threads,
                               reduce_threads_serial, scatter_buffers, store_sums, thread_buffer)
from .._jit.threads import threaded
from ..neighbors import separation
from .couplings import FORM, FORM_BETHE_SLATER, FORM_CUBIC, P0, P1, P2, RC2

__all__ = ["exp_minus", "geometry_kernel", "geometry_single", "direct_kernel"]

# the table's layout and the forms (ase_spin.terms.couplings) under the names
# the kernels below read (compile-time constants)
_RC2, _FORM, _P0, _P1, _P2 = RC2, FORM, P0, P1, P2
_BETHE_SLATER, _CUBIC = FORM_BETHE_SLATER, FORM_CUBIC


# exp(−x) for the Bethe–Slater couplings, in a form LLVM vectorises (the
# library exp is a call per pair, most of the geometry pass's time): with
# x = k ln2 + r, |r| ≤ ln2/2 (Cody–Waite, ln2 in two parts),
# exp(−x) = 2^−k exp(−r), exp(−r) by its Taylor series to degree 13 (the
# rest below 2e-17), written 1 + (y + y² q(y)) so that the last rounding is
# the one of 1 + (…): within one ulp of the exact value
# (tests/test_coupling_exp.py). 2^−k is built from its exponent bits. Arguments
# above _EXP_X_MAX (exp(−x) < 2^−1021) give 0, NaN gives NaN.
_INV_LN2 = 1.4426950408889634
_LN2_HI = 6.93147180369123816490e-01
_LN2_LO = 1.90821492927058770002e-10
_EXP_X_MAX = 708.0


@nb.njit(cache=True, inline="always")
def _exp_reduced(x):
    """(k, r) with x = k ln2 + r, |r| ≤ ln2/2, for x clamped to [0, _EXP_X_MAX]
    (NaN: _EXP_X_MAX; the caller gives NaN back)."""
    x = x if x < _EXP_X_MAX else _EXP_X_MAX
    x = x if x > 0.0 else 0.0
    k = np.floor(x * _INV_LN2 + 0.5)
    return k, (x - k * _LN2_HI) - k * _LN2_LO


@nb.njit(cache=True, inline="always")
def _exponent_bits(x):
    """The bits of the double 2^−k of exp(−x) = 2^−k exp(−r) (:func:`_exp_reduced`)."""
    k, _ = _exp_reduced(x)
    return (1023 - np.int64(k)) << 52


@nb.njit(cache=True, inline="always")
def _exp_of_reduced(r):
    """exp(−r) for |r| ≤ ln2/2 (Taylor to degree 13)."""
    y = -r
    q = (0.5 + y * (1.6666666666666666e-01 + y * (4.1666666666666664e-02
         + y * (8.3333333333333332e-03 + y * (1.3888888888888889e-03
         + y * (1.9841269841269841e-04 + y * (2.4801587301587302e-05
         + y * (2.7557319223985893e-06 + y * (2.7557319223985888e-07
         + y * (2.5052108385441720e-08 + y * (2.0876756987868100e-09
         + y * 1.6059043836821613e-10)))))))))))
    return 1.0 + (y + (y * y) * q)


@nb.njit(cache=True, inline="always")
def _exp_range(x, e):
    """e where 0 ≤ x ≤ _EXP_X_MAX, 0 above, NaN for NaN."""
    if x <= _EXP_X_MAX:
        return e
    return 0.0 if x > _EXP_X_MAX else x


@nb.njit(cache=True, inline="always")
def exp_minus(x, ex, bits):
    """ex[b] = exp(−x[b]) for x ≥ 0 (see the comment above _EXP_X_MAX), 2^−k
    from its exponent bits (``bits``: an int64 scratch of the same length):
    two straight loops, which LLVM vectorises."""
    for b in range(len(x)):
        bits[b] = _exponent_bits(x[b])
    scale = bits.view(np.float64)
    for b in range(len(x)):
        xb = x[b]
        _, r = _exp_reduced(xb)
        ex[b] = _exp_range(xb, _exp_of_reduced(r) * scale[b])


@nb.njit(cache=True)
def _exp_arguments(lo, hi, pos, row, nbr, image, images, types, table):
    """(x, ex, d) for the pairs of atoms lo … hi − 1 of a multi-species
    table, indexed from the first pair: x = r²/J3² of the Bethe–Slater pairs
    (0 for the others), their exp(−x) (:func:`exp_minus`), and each
    pair's d_ij and r² (:func:`separation`: rows 0–2 and 3)."""
    k0 = row[lo]
    x = np.empty(row[hi] - k0)
    d = np.empty((4, len(x)))
    for i in range(lo, hi):
        ti = types[i]
        for k in range(row[i], row[i + 1]):
            tj = types[nbr[k]]
            dx, dy, dz, r2 = separation(pos, images, i, nbr[k], image[k])
            d[0, k - k0] = dx
            d[1, k - k0] = dy
            d[2, k - k0] = dz
            d[3, k - k0] = r2
            bs = table[ti, tj, _FORM] == _BETHE_SLATER
            x[k - k0] = r2 * table[ti, tj, _P2] if bs else 0.0
    ex = np.empty(len(x))
    exp_minus(x, ex, np.empty(len(x), dtype=np.int64))
    return x, ex, d


@nb.njit(cache=True, inline="always")
def _coupling_given_exp(table, ti, tj, r2, x, ex):
    """J(r) and J'(r)/r for species ti, tj from the parameter table, a
    Bethe–Slater pair's x = r²/J3² and exp(−x) given (:func:`_exp_arguments`)."""
    form = table[ti, tj, _FORM]
    if form == _BETHE_SLATER:
        return _bethe_slater(table[ti, tj, _P0], table[ti, tj, _P1], table[ti, tj, _P2], x, ex)
    return _other_form(form, table[ti, tj, _P0], table[ti, tj, _P1], table[ti, tj, _P2], r2)


@nb.njit(cache=True, inline="always")
def _bethe_slater(p0, p1, p2, x, ex):
    """J and J'(r)/r of the Bethe–Slater form at x = r²/J3², ex = exp(−x)."""
    return (4.0 * p0 * x * (1.0 - p1 * x) * ex,
            8.0 * p0 * p2 * ex * (1.0 - x - p1 * x * (2.0 - x)))


@nb.njit(cache=True, inline="always")
def _other_form(form, p0, p1, p2, r2):
    """J(r) and J'(r)/r of the compiled coupling forms but Bethe–Slater (J1,
    J2, 1/J3²; its exponentials the passes take a block at a time): cubic
    (J0, rc, 1/rc), else 0."""
    if form == _CUBIC:
        r = np.sqrt(r2)
        if r >= p1:
            return 0.0, 0.0
        y = 1.0 - r * p2
        return p0 * y * y * y, -3.0 * p0 * p2 * y * y / r
    return 0.0, 0.0


#: Atoms per block of the passes that take the Bethe–Slater exponentials of
#: their pairs first (_bethe_slater_block, _exp_arguments): a block's scratch
#: stays in the L1 cache.
_GEOMETRY_BLOCK = 64


@threaded(always=True)
def geometry_kernel(pos, row, nbr, image, images, types, table, J, g, G, other, Jbar):
    """J_k = J(r_ij) and, into whichever of G and g is not empty,
    G_k = J'(r_ij) d_ij / r_ij or g_k = J'(r_ij)/r_ij for every pair
    k = (i → j), with d_ij = (r_j − r_i) + S_k and r_ij² = |d_ij|²
    (:func:`separation`); with ``other`` given, also Jbar_k = ½(other_k + J_k)."""
    n = len(row) - 1
    want_mean = other.shape[0] > 0
    stored = G.shape[0] > 0
    for blk in nb.prange((n + _GEOMETRY_BLOCK - 1) // _GEOMETRY_BLOCK):
        _geometry_kernel_chunk(np.int64(blk), n, pos, row, nbr, image, images, types, table, J, g,
                               G, other, Jbar, want_mean, stored)


@nb.njit(cache=True, error_model="numpy")
def _geometry_kernel_chunk(blk, n, pos, row, nbr, image, images, types, table, J, g, G, other,
                           Jbar, want_mean, stored):
    """One chunk ``blk`` of :func:`geometry_kernel`'s threaded loop: its work,
    compiled once for the threaded kernel and its serial twin."""
    lo = blk * _GEOMETRY_BLOCK
    hi = min(n, lo + _GEOMETRY_BLOCK)
    _geometry_table_block(lo, hi, pos, row, nbr, image, images, types, table, J, g, G,
                          other, Jbar, want_mean, stored)


@nb.njit(cache=True)
def _geometry_table_block(lo, hi, pos, row, nbr, image, images, types, table, J, g, G, other,
                          Jbar, want_mean, stored):
    """:func:`geometry_kernel` for the pairs of atoms lo … hi − 1, their
    exponentials first (:func:`_exp_arguments`)."""
    k0 = row[lo]
    xs, exs, ds = _exp_arguments(lo, hi, pos, row, nbr, image, images, types, table)
    for i in range(lo, hi):
        ti = types[i]
        for k in range(row[i], row[i + 1]):
            j = nbr[k]
            tj = types[j]
            b = k - k0
            dx, dy, dz, r2 = ds[0, b], ds[1, b], ds[2, b], ds[3, b]
            if r2 >= table[ti, tj, _RC2]:
                Jk = 0.0
                gk = 0.0
            else:
                Jk, gk = _coupling_given_exp(table, ti, tj, r2, xs[b], exs[b])
            J[k] = Jk
            if stored:
                G[k, 0] = gk * dx
                G[k, 1] = gk * dy
                G[k, 2] = gk * dz
            else:
                g[k] = gk
            if want_mean:
                Jbar[k] = 0.5 * (other[k] + Jk)


@nb.njit(cache=True, inline="always")
def _bethe_slater_values(r2, p0, p1, p2, rc2, scale, J, g, other, Jbar, want_mean):
    """J, J'/r (into ``g``) and J̄ of a block of pairs from their r² (read
    from ``J``) and 2^−k (``scale``), every array indexed from 0: a straight
    loop without calls, which LLVM vectorises (the arithmetic of
    :func:`exp_minus` and :func:`_bethe_slater`, the same values)."""
    for b in range(len(r2)):
        d2 = r2[b]
        x = d2 * p2
        _, r = _exp_reduced(x)
        Jk, gk = _bethe_slater(p0, p1, p2, x,
                               _exp_range(x, _exp_of_reduced(r) * scale[b]))
        outside = d2 >= rc2  # (NaN: not outside, and NaN results)
        Jk = 0.0 if outside else Jk
        J[b] = Jk
        g[b] = 0.0 if outside else gk
        if want_mean:
            Jbar[b] = 0.5 * (other[b] + Jk)


@nb.njit(cache=True)
def _bethe_slater_block(lo, hi, pos, row, nbr, image, images, rc2, p0, p1, p2, J, g, G,
                        other, Jbar, want_mean, stored):
    """:func:`geometry_single`'s Bethe–Slater pass over the pairs of atoms
    lo … hi − 1: r² of each (into J; the pair vectors into G when stored),
    then 2^−k of each from its exponent bits, then J, J'/r and J̄
    (:func:`_bethe_slater_values`; J'/r into a buffer of the block when G is
    stored, then G = (J'/r) d)."""
    k0 = row[lo]
    k1 = row[hi]
    for i in range(lo, hi):
        for k in range(row[i], row[i + 1]):
            dx, dy, dz, r2 = separation(pos, images, i, nbr[k], image[k])
            J[k] = r2
            if stored:
                G[k, 0] = dx
                G[k, 1] = dy
                G[k, 2] = dz
    r2 = J[k0:k1]
    bits = np.empty(k1 - k0, dtype=np.int64)
    for b in range(len(r2)):
        bits[b] = _exponent_bits(r2[b] * p2)
    scale = bits.view(np.float64)
    gb = np.empty(k1 - k0) if stored else g[k0:k1]
    if want_mean:
        _bethe_slater_values(r2, p0, p1, p2, rc2, scale, r2, gb, other[k0:k1],
                             Jbar[k0:k1], True)
    else:
        _bethe_slater_values(r2, p0, p1, p2, rc2, scale, r2, gb, other, Jbar, False)
    if stored:
        Gb = G[k0:k1]
        for b in range(len(gb)):
            Gb[b, 0] *= gb[b]
            Gb[b, 1] *= gb[b]
            Gb[b, 2] *= gb[b]


@threaded(always=True)
def geometry_single(pos, row, nbr, image, images, rc2, form, p0, p1, p2, J, g, G, other,
                    Jbar):
    """:func:`geometry_kernel` for one species (one coupling); Bethe–Slater
    in blocks of :data:`_GEOMETRY_BLOCK` atoms (:func:`_bethe_slater_block`:
    the same values as one pair at a time)."""
    n = len(row) - 1
    want_mean = other.shape[0] > 0
    stored = G.shape[0] > 0
    if form == _BETHE_SLATER:
        for b in nb.prange((n + _GEOMETRY_BLOCK - 1) // _GEOMETRY_BLOCK):
            _geometry_single_chunk(np.int64(b), pos, row, nbr, image, images, rc2, p0, p1, p2, J,
                                   g, G, other, Jbar, want_mean, stored, n)
        return
    for i in nb.prange(n):
        for k in range(row[i], row[i + 1]):
            dx, dy, dz, r2 = separation(pos, images, i, nbr[k], image[k])
            if r2 >= rc2:
                Jk = 0.0
                gk = 0.0
            else:
                Jk, gk = _other_form(form, p0, p1, p2, r2)
            J[k] = Jk
            if stored:
                G[k, 0] = gk * dx
                G[k, 1] = gk * dy
                G[k, 2] = gk * dz
            else:
                g[k] = gk
            if want_mean:
                Jbar[k] = 0.5 * (other[k] + Jk)


@nb.njit(cache=True, error_model="numpy")
def _geometry_single_chunk(b, pos, row, nbr, image, images, rc2, p0, p1, p2, J, g, G, other, Jbar,
                           want_mean, stored, n):
    """One chunk ``b`` of :func:`geometry_single`'s threaded loop: its work,
    compiled once for the threaded kernel and its serial twin."""
    _bethe_slater_block(b * _GEOMETRY_BLOCK, min(n, (b + 1) * _GEOMETRY_BLOCK), pos,
                        row, nbr, image, images, rc2, p0, p1, p2, J, g, G, other,
                        Jbar, want_mean, stored)


@threaded(always=True, reduce_threads=lambda: reduce_threads_serial)
def direct_kernel(nthreads, pos, row, nbr, image, images, types, table, s, c, B, F, energies,
                  want_b, want_f, want_energy, want_energies, want_virial):
    """One evaluation from positions over a half pair list (each pair once,
    nothing stored per pair; the Bethe–Slater exponentials of a block of
    atoms' pairs first, :func:`_exp_arguments`), w = s_i·s_j − c,
    g = J'(r)/r, d = r_j + S − r_i:

    B_i += J s_j,  B_j += J s_i,  F_i −= w g d,  F_j += w g d,
    e_i, e_j −= ½ J w,  W −= w g d ⊗ d.

    Per-thread buffers as in the Lennard-Jones kernel.
    """
    bounds, fbuf, ebuf, acc = scatter_buffers(row, nthreads, want_f, want_energies)
    bbuf = thread_buffer(nthreads, len(row) - 1, want_b, 3)
    for t in nb.prange(nthreads):
        _direct_kernel_chunk(np.int64(t), want_b, want_f, want_energies, bounds, types, s,
                             want_virial, row, pos, nbr, image, images, table, c, bbuf, fbuf,
                             ebuf, acc)
    reduce_threads(bbuf, B)
    return reduce_scatter(reduce_threads, fbuf, F, ebuf, energies, acc)


@nb.njit(cache=True, error_model="numpy")
def _direct_kernel_chunk(t, want_b, want_f, want_energies, bounds, types, s, want_virial, row,
                         pos, nbr, image, images, table, c, bbuf, fbuf, ebuf, acc):
    """One chunk ``t`` of :func:`direct_kernel`'s threaded loop: its work,
    compiled once for the threaded kernel and its serial twin."""
    e = vxx = vyy = vzz = vyz = vxz = vxy = 0.0
    for i in range(bounds[t], bounds[t + 1]):
        if (i - bounds[t]) % _GEOMETRY_BLOCK == 0:  # the next block's exponentials
            k0 = row[i]
            xs, exs, ds = _exp_arguments(i, min(bounds[t + 1], i + _GEOMETRY_BLOCK), pos,
                                         row, nbr, image, images, types, table)
        ti = types[i]
        sx = s[i, 0]
        sy = s[i, 1]
        sz = s[i, 2]
        bx = by = bz = 0.0
        fx = fy = fz = ei = 0.0
        for k in range(row[i], row[i + 1]):
            j = nbr[k]
            tj = types[j]
            b = k - k0
            dx, dy, dz, r2 = ds[0, b], ds[1, b], ds[2, b], ds[3, b]
            if r2 >= table[ti, tj, _RC2]:
                continue
            Jk, g = _coupling_given_exp(table, ti, tj, r2, xs[b], exs[b])
            ux = s[j, 0]
            uy = s[j, 1]
            uz = s[j, 2]
            w = sx * ux + sy * uy + sz * uz - c
            ei -= Jk * w
            if want_b:
                bx += Jk * ux
                by += Jk * uy
                bz += Jk * uz
                add_row(bbuf, t, j, 0, Jk * sx, Jk * sy, Jk * sz)
            wg = w * g
            if want_f:
                gx = wg * dx
                gy = wg * dy
                gz = wg * dz
                fx -= gx
                fy -= gy
                fz -= gz
                add_row(fbuf, t, j, 0, gx, gy, gz)
            if want_energies:
                ebuf[t, j, 0] -= 0.5 * Jk * w
            if want_virial:
                vxx -= wg * dx * dx
                vyy -= wg * dy * dy
                vzz -= wg * dz * dz
                vyz -= wg * dy * dz
                vxz -= wg * dx * dz
                vxy -= wg * dx * dy
        if want_b:
            add_row(bbuf, t, i, 0, bx, by, bz)
        if want_f:
            add_row(fbuf, t, i, 0, fx, fy, fz)
        if want_energies:
            ebuf[t, i, 0] += 0.5 * ei
        e += ei
    store_sums(acc, t, e, vxx, vyy, vzz, vyz, vxz, vxy)
