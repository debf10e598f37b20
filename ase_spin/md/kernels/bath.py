"""The baths' compiled pieces: the spin bath's damped precession and
diffusion of each spin (an exact solution of the damped precession and a
Gaussian rotation), applied per block of spins with the field's direction; the
lattice's Ornstein–Uhlenbeck update of the momenta; the midpoint predictor
and remainder for a frozen field."""

from __future__ import annotations

import numba as nb
import numpy as np

from ..._jit.threads import threaded
from ..gaussian import normals
from .midpoint import BLOCK, local_midpoint

# -- compiled per-spin pieces of the spin bath ------------------------------------

@nb.njit(cache=True, inline="always")
def _unit(x, y, z):
    n = 1.0 / np.sqrt(x * x + y * y + z * z)
    return x * n, y * n, z * n


#: Damping angles a = κ|B|t below this take the series form of :func:`_damped`
#: (every spin of a step, in practice), the rest libm's expm1.
_SMALL_ANGLE = 0.04


@nb.njit(cache=True, inline="always")
def _damped_series(sx, sy, sz, bx, by, bz, a):
    """:func:`_damped` for 0 ≤ a < :data:`_SMALL_ANGLE`, without branches (so a
    loop of them runs on SIMD lanes): t = tanh(a/2) from its Taylor series to
    (a/2)⁹ (the rest is below 1e-19 relative), s unchanged for a = 0."""
    u = sx * bx + sy * by + sz * bz
    x = 0.5 * a
    x2 = x * x
    t = x * (1.0 - x2 * (1.0 / 3 - x2 * (2.0 / 15 - x2 * (17.0 / 315 - x2 * (62.0 / 2835)))))
    f = 1.0 - t * t
    c = 2.0 * t * (1.0 + u * t)
    vx, vy, vz = _unit(sx * f + c * bx, sy * f + c * by, sz * f + c * bz)
    keep = a == 0.0
    return (sx if keep else vx), (sy if keep else vy), (sz if keep else vz)


@nb.njit(cache=True, inline="always")
def _damped(sx, sy, sz, bx, by, bz, a):
    r"""s moved by the damping flow ds/dt = κ[B − (s·B)s] about the frozen field
    B = |B| b̂ (``bx, by, bz`` = b̂) for a = κ|B|t: along the great circle to
    b̂, tan(θ/2) = tan(θ₀/2) e^{−a}, i.e. s' = s sech a + [u₀(1 − sech a) +
    tanh a] b̂ with u₀ = s·b̂. With t = tanh(a/2) (sech a = (1−t²)/(1+t²),
    tanh a = 2t/(1+t²)) and the common factor 1 + t² dropped,

        s' ∝ (1 − t²) s + 2t(1 + u₀ t) b̂,

    normalised (|s'| = 1 to round-off; :func:`_damped_series` below
    a = 0.04); from there the same times (1+e)², e = e^{−a}, m = −expm1(−a):
    s' ∝ 4e s + 2m(1 + e + u₀ m) b̂ (no 1 − t² cancellation at large a)."""
    if a < _SMALL_ANGLE:
        return _damped_series(sx, sy, sz, bx, by, bz, a)
    u = sx * bx + sy * by + sz * bz
    m = -np.expm1(-a)
    e = 1.0 - m
    f = 4.0 * e
    c = 2.0 * m * (1.0 + e + u * m)
    return _unit(sx * f + c * bx, sy * f + c * by, sz * f + c * bz)


@nb.njit(cache=True, inline="always")
def _diffused(sx, sy, sz, sigma, x1, x2):
    r"""s' = (s + ζ)/|s + ζ| for the tangent Gaussian vector ζ = σ(ξ₁ e₁ + ξ₂ e₂)
    (e₁, e₂ an orthonormal basis of the tangent plane at s): a step of angle
    atan|ζ| in a uniformly random direction (:func:`noise_amplitude`); s
    unchanged for σ = 0. e₁ = s × x̂/|s × x̂| where s_x² < ½, else s × ŷ/|…|:
    both computed and one selected, without branches (SIMD lanes)."""
    low = sx * sx < 0.5
    nx = 1.0 / np.sqrt(sy * sy + sz * sz)
    ny = 1.0 / np.sqrt(sx * sx + sz * sz)
    e1x = 0.0 if low else -sz * ny
    e1y = sz * nx if low else 0.0
    e1z = -sy * nx if low else sx * ny
    e2x = sy * e1z - sz * e1y
    e2y = sz * e1x - sx * e1z
    e2z = sx * e1y - sy * e1x
    x1 *= sigma
    x2 *= sigma
    vx, vy, vz = _unit(sx + x1 * e1x + x2 * e2x, sy + x1 * e1y + x2 * e2y,
                       sz + x1 * e1z + x2 * e2z)
    keep = sigma == 0.0
    return (sx if keep else vx), (sy if keep else vy), (sz if keep else vz)


@nb.njit(cache=True, inline="always")
def _unit_and_length(bx, by, bz):
    """(b̂, |b|) of the vector b; b̂ = 0 where b = 0."""
    b = np.sqrt(bx * bx + by * by + bz * bz)
    if b == 0.0:
        return 0.0, 0.0, 0.0, 0.0
    inv = 1.0 / b
    return bx * inv, by * inv, bz * inv, b


@nb.njit(cache=True, inline="always")
def _direction(B, i):
    """(b̂, |B|) of row i; b̂ = 0 where B = 0."""
    return _unit_and_length(B[i, 0], B[i, 1], B[i, 2])


# The kernels below run over blocks of BLOCK spins, each in two loops: one
# without branches for every spin whose damping angles are small (the series
# form) and whose field is not zero, on SIMD lanes, then the few others one by
# one. The first indexes flat views of the block from 0: with an offset, or
# with 2-d indexing, LLVM does not vectorise it. The results are the same bits
# as the one-by-one loop alone: the split exists only for speed
# (``benchmarks/bench_langevin.py``; docs/benchmarks.md, "Why each fast path exists").

@nb.njit(cache=True, inline="always")
def _rows(a, lo, m):
    """Rows lo … lo + m − 1 of a C-contiguous (n, 3) array, flat."""
    return a.reshape(-1)[3 * lo:3 * (lo + m)]


@nb.njit(cache=True, inline="always")
def _field_direction(B, B0, w, i):
    """:func:`_direction` of the field F = (1 + w) B − w B0 at row i."""
    a = 1.0 + w
    return _unit_and_length(a * B[i, 0] - w * B0[i, 0], a * B[i, 1] - w * B0[i, 1],
                            a * B[i, 2] - w * B0[i, 2])


@threaded()
def bath_block(s, out, before, B, B0, w, k1, sigma, key, k2, magnetic):
    """The spin bath between two collective steps, per magnetic spin:
    out ← D_F(k2) N(σ, ξ) D_F(k1) s (:func:`_damped` with a = k|F_i|,
    :func:`_diffused`; k = κ_i t per spin, 0: no damping; σ_i = 0: no noise;
    ξ_i = Gaussian numbers 2i, 2i + 1 of stream ``key``), the state before the
    last D written to ``before``; other rows: out = s. s is left as it was
    (the bath's start, for its energy). The field F = (1 + w) B − w B0: B
    itself for w = 0 (to the bit: pass B0 = B), the field at a midpoint
    step's end 2B̄ − B(y₀) for w = 1 (see Langevin._closing_bath), formed
    row by row here rather than stored."""
    n = s.shape[0]
    a = 1.0 + w
    for blk in nb.prange((n + BLOCK - 1) // BLOCK):
        _bath_block_chunk(np.int64(blk), n, s, before, B, out, B0, k1, k2, sigma, magnetic, key,
                          a, w)


@nb.njit(cache=True, error_model="numpy")
def _bath_block_chunk(blk, n, s, before, B, out, B0, k1, k2, sigma, magnetic, key, a, w):
    """One chunk ``blk`` of :func:`bath_block`'s threaded loop: its work,
    compiled once for the threaded kernel and its serial twin."""
    lo = blk * BLOCK
    m = min(n, lo + BLOCK) - lo
    sf, bf, Bf = _rows(s, lo, m), _rows(before, lo, m), _rows(B, lo, m)
    of, Zf = _rows(out, lo, m), _rows(B0, lo, m)
    kk1, kk2, sig, mag = k1[lo:lo + m], k2[lo:lo + m], sigma[lo:lo + m], magnetic[lo:lo + m]
    xi = np.zeros(2 * m)
    noisy = False
    for j in range(m):
        noisy |= sig[j] != 0.0
    if noisy:  # (σ = 0 rows do not use theirs)
        normals(key, 2 * lo, xi)
    # out starts as s and is updated in place: with s read and out written
    # in the loop below, LLVM leaves it scalar (benchmarks/bench_langevin.py;
    # docs/benchmarks.md, "Why each fast path exists")
    for j in range(3 * m):
        of[j] = sf[j]
    rest = 0
    for j in range(m):
        bx = a * Bf[3 * j] - w * Zf[3 * j]
        by = a * Bf[3 * j + 1] - w * Zf[3 * j + 1]
        bz = a * Bf[3 * j + 2] - w * Zf[3 * j + 2]
        b = np.sqrt(bx * bx + by * by + bz * bz)
        inv = 1.0 / b
        bx *= inv
        by *= inv
        bz *= inv
        a1 = kk1[j] * b
        a2 = kk2[j] * b
        fast = mag[j] & (b > 0.0) & (a1 < _SMALL_ANGLE) & (a2 < _SMALL_ANGLE)
        rest += mag[j] & (not fast)
        sx, sy, sz = of[3 * j], of[3 * j + 1], of[3 * j + 2]
        x, y, z = _damped_series(sx, sy, sz, bx, by, bz, a1)
        x, y, z = _diffused(x, y, z, sig[j], xi[2 * j], xi[2 * j + 1])
        bf[3 * j] = x if fast else bf[3 * j]
        bf[3 * j + 1] = y if fast else bf[3 * j + 1]
        bf[3 * j + 2] = z if fast else bf[3 * j + 2]
        x, y, z = _damped_series(x, y, z, bx, by, bz, a2)
        of[3 * j] = x if fast else sx
        of[3 * j + 1] = y if fast else sy
        of[3 * j + 2] = z if fast else sz
    for j in range(m if rest else 0):
        i = lo + j
        if not magnetic[i]:
            continue
        bx, by, bz, b = _field_direction(B, B0, w, i)
        if b > 0.0 and k1[i] * b < _SMALL_ANGLE and k2[i] * b < _SMALL_ANGLE:
            continue  # done above
        x, y, z = _damped(s[i, 0], s[i, 1], s[i, 2], bx, by, bz, k1[i] * b)
        x, y, z = _diffused(x, y, z, sigma[i], xi[2 * j], xi[2 * j + 1])
        before[i, 0] = x
        before[i, 1] = y
        before[i, 2] = z
        x, y, z = _damped(x, y, z, bx, by, bz, k2[i] * b)
        out[i, 0] = x
        out[i, 1] = y
        out[i, 2] = z


@threaded()
def damp_from(start, B, k, magnetic, out, y0, c, kick, keep):
    """out = D_B(k) start per magnetic spin (:func:`_damped`, a = k|B_i|).

    With ``kick`` not empty (the corrector of a bath, out = y; rows without
    spin 0; empty arrays for ``y0``, ``c``, ``kick``, ``keep``: none of this),
    also what the predictor needs, per row: kick = (y − y0) + c_i y × B (the
    move since the fields B were taken at y0, plus the explicit half step of
    precession in them: C·kick is the field change the midpoint sees, for a
    term B = C s); and B copied to ``keep``."""
    n = start.shape[0]
    for blk in nb.prange((n + BLOCK - 1) // BLOCK):
        _damp_from_chunk(np.int64(blk), n, start, out, B, k, magnetic, kick, y0, c, keep)


@nb.njit(cache=True, error_model="numpy")
def _damp_from_chunk(blk, n, start, out, B, k, magnetic, kick, y0, c, keep):
    """One chunk ``blk`` of :func:`damp_from`'s threaded loop: its work,
    compiled once for the threaded kernel and its serial twin."""
    lo = blk * BLOCK
    m = min(n, lo + BLOCK) - lo
    sf, of, Bf = _rows(start, lo, m), _rows(out, lo, m), _rows(B, lo, m)
    kk, mag = k[lo:lo + m], magnetic[lo:lo + m]
    rest = 0
    for j in range(m):
        bx, by, bz = Bf[3 * j], Bf[3 * j + 1], Bf[3 * j + 2]
        b = np.sqrt(bx * bx + by * by + bz * bz)
        inv = 1.0 / b
        a = kk[j] * b
        fast = mag[j] & (b > 0.0) & (a < _SMALL_ANGLE)
        rest += mag[j] & (not fast)
        x, y, z = _damped_series(sf[3 * j], sf[3 * j + 1], sf[3 * j + 2], bx * inv,
                                 by * inv, bz * inv, a)
        of[3 * j] = x if fast else of[3 * j]
        of[3 * j + 1] = y if fast else of[3 * j + 1]
        of[3 * j + 2] = z if fast else of[3 * j + 2]
    for j in range(m if rest else 0):
        i = lo + j
        if not magnetic[i]:
            continue
        bx, by, bz, b = _direction(B, i)
        if b > 0.0 and k[i] * b < _SMALL_ANGLE:
            continue  # done above
        x, y, z = _damped(start[i, 0], start[i, 1], start[i, 2], bx, by, bz, k[i] * b)
        out[i, 0] = x
        out[i, 1] = y
        out[i, 2] = z
    if kick.shape[0] > 0:
        af, cc = _rows(y0, lo, m), c[lo:lo + m]
        kf, ef = _rows(kick, lo, m), _rows(keep, lo, m)
        for j in range(m):
            x, y, z = of[3 * j], of[3 * j + 1], of[3 * j + 2]
            bx, by, bz = Bf[3 * j], Bf[3 * j + 1], Bf[3 * j + 2]
            kf[3 * j] = (x - af[3 * j]) + cc[j] * (y * bz - z * by)
            kf[3 * j + 1] = (y - af[3 * j + 1]) + cc[j] * (z * bx - x * bz)
            kf[3 * j + 2] = (z - af[3 * j + 2]) + cc[j] * (x * by - y * bx)
            ef[3 * j] = bx
            ef[3 * j + 1] = by
            ef[3 * j + 2] = bz


def noise_amplitude(d_tau):
    r"""σ_i of the noise step N(τ) (:func:`_diffused`) for D_i τ = ``d_tau``:
    σ² = 2Dτ(1 + 5Dτ).

    Isotropy reduces the weak error of N to the spherical harmonics: it must
    give E P_ℓ(cos θ) = e^{−ℓ(ℓ+1)Dτ} + O(τ³) for every ℓ (θ the angle moved;
    the heat kernel of the sphere). With P_ℓ(cos θ) = 1 − Lθ²/4 +
    (L²/64 − L/96)θ⁴ + O(θ⁶), L = ℓ(ℓ+1), and θ = atan r, r = |ζ| for a 2-d
    Gaussian ζ of variance σ² per component (E r² = 2σ², E r⁴ = 8σ⁴:
    E θ² = 2σ² − 16σ⁴/3, E θ⁴ = 8σ⁴ + O(σ⁶)), the L² terms give σ² = 2Dτ at
    leading order and the L terms σ²/2 − 5σ⁴/4 = Dτ, i.e.
    σ² = 2Dτ(1 + 5Dτ) + O(τ³). σ² = 2Dτ alone (as a plain Gaussian rotation)
    leaves an O(τ²) error per step: weak first order."""
    return np.sqrt(2.0 * d_tau * (1.0 + 5.0 * d_tau))


@threaded()
def ornstein_uhlenbeck(p, key, m, c1, c2, fix_com, out):
    """out_i = c1 p_i + c2 √m_i ξ_i (c2 = √((1 − c1²) k_B T); ξ_ia Gaussian
    number 3i + a of stream ``key``); with ``fix_com`` the change of the total
    momentum is taken off, mass-weighted. Returns the change of the kinetic
    energy. Sums over fixed blocks of atoms, added in block order: the same
    bits for any thread count."""
    n = p.shape[0]
    nblocks = (n + BLOCK - 1) // BLOCK
    part = np.zeros((nblocks, 4))
    for blk in nb.prange(nblocks):
        _ornstein_uhlenbeck_chunk0(np.int64(blk), n, key, c2, part, m, out, c1, p)
    dP = np.zeros(3)
    M = 0.0
    for blk in range(nblocks):
        for a in range(3):
            dP[a] += part[blk, a]
        M += part[blk, 3]
    # the velocity change every atom gives back (fixcm), 0 without
    dvx = dP[0] / M if fix_com else 0.0
    dvy = dP[1] / M if fix_com else 0.0
    dvz = dP[2] / M if fix_com else 0.0
    kinetic = np.zeros(nblocks)
    for blk in nb.prange(nblocks):
        _ornstein_uhlenbeck_chunk1(np.int64(blk), n, m, out, dvx, dvy, dvz, p, kinetic)
    dK = 0.0
    for blk in range(nblocks):
        dK += kinetic[blk]
    return dK


@nb.njit(cache=True, error_model="numpy")
def _ornstein_uhlenbeck_chunk0(blk, n, key, c2, part, m, out, c1, p):
    """One chunk ``blk`` of :func:`ornstein_uhlenbeck`'s threaded loop: its work,
    compiled once for the threaded kernel and its serial twin."""
    lo = blk * BLOCK
    xi = np.empty(3 * (min(n, lo + BLOCK) - lo))
    normals(key, 3 * lo, xi)
    for i in range(lo, min(n, lo + BLOCK)):
        r = c2 * np.sqrt(m[i])
        part[blk, 3] += m[i]
        for a in range(3):
            v = c1 * p[i, a] + r * xi[3 * (i - lo) + a]
            out[i, a] = v
            part[blk, a] += v - p[i, a]


@nb.njit(cache=True, error_model="numpy")
def _ornstein_uhlenbeck_chunk1(blk, n, m, out, dvx, dvy, dvz, p, kinetic):
    """One chunk ``blk`` of :func:`ornstein_uhlenbeck`'s threaded loop: its work,
    compiled once for the threaded kernel and its serial twin."""
    dK = 0.0
    for i in range(blk * BLOCK, min(n, (blk + 1) * BLOCK)):
        mi = m[i]
        x = out[i, 0] - mi * dvx
        y = out[i, 1] - mi * dvy
        z = out[i, 2] - mi * dvz
        out[i, 0] = x
        out[i, 1] = y
        out[i, 2] = z
        dK += 0.5 * ((x * x + y * y + z * z)
                     - (p[i, 0] * p[i, 0] + p[i, 1] * p[i, 1] + p[i, 2] * p[i, 2])) / mi
    kinetic[blk] = dK


@nb.njit(cache=True, inline="always")
def _frozen_field_midpoint(sx, sy, sz, bx, by, bz, c):
    r"""The midpoint of one spin s in the frozen field B (``bx, by, bz``): the
    unit W with W ∝ s + c W × B, the spherical midpoint step of the spin alone
    (a Cayley rotation about B; :func:`~ase_spin.md.kernels.local_midpoint`
    with its c = 2c). The part of the midpoint known from the start of the
    step; the rest — the other spins' and the lattice's motion over the step
    beyond the field used here — is extrapolated. Where that equation has no
    root (a half-turn or more per step) the unit vector along
    s + c s × B + c²(s·B)B (the root of m = s + c m × B)."""
    wx, wy, wz, found = local_midpoint(sx, sy, sz, bx, by, bz, 2.0 * c)
    tx = sy * bz - sz * by
    ty = sz * bx - sx * bz
    tz = sx * by - sy * bx
    cu = c * c * (sx * bx + sy * by + sz * bz)
    x, y, z = _unit(sx + c * tx + cu * bx, sy + c * ty + cu * by, sz + c * tz + cu * bz)
    return (wx if found else x), (wy if found else y), (wz if found else z)


@threaded()
def predict_midpoint(s, B, c, R0, R1, R2, R3, coef, out, known):
    """out_i = (:func:`_frozen_field_midpoint` + Σ_k coef_k R_k,i) / |…| (magnetic
    rows, 0 elsewhere), the known part into ``known`` (for
    :func:`midpoint_remainder`'s W − known). Blocks of flat rows without
    branches: SIMD lanes (see :func:`bath_block`)."""
    n = s.shape[0]
    c0, c1, c2, c3 = coef[0], coef[1], coef[2], coef[3]
    for blk in nb.prange((n + BLOCK - 1) // BLOCK):
        _predict_midpoint_chunk(np.int64(blk), n, s, B, c, R0, R1, R2, R3, out, known, c3, c2, c0,
                                c1)


@nb.njit(cache=True, error_model="numpy")
def _predict_midpoint_chunk(blk, n, s, B, c, R0, R1, R2, R3, out, known, c3, c2, c0, c1):
    """One chunk ``blk`` of :func:`predict_midpoint`'s threaded loop: its work,
    compiled once for the threaded kernel and its serial twin."""
    lo = blk * BLOCK
    m = min(n, lo + BLOCK) - lo
    sf, Bf, cc = _rows(s, lo, m), _rows(B, lo, m), c[lo:lo + m]
    r0, r1, r2, r3 = _rows(R0, lo, m), _rows(R1, lo, m), _rows(R2, lo, m), _rows(R3, lo, m)
    of, kf = _rows(out, lo, m), _rows(known, lo, m)
    for j in range(m):
        sx, sy, sz = sf[3 * j], sf[3 * j + 1], sf[3 * j + 2]
        spin = (sx != 0.0) | (sy != 0.0) | (sz != 0.0)
        vx, vy, vz = _frozen_field_midpoint(sx, sy, sz, Bf[3 * j], Bf[3 * j + 1],
                                            Bf[3 * j + 2], cc[j])
        kf[3 * j] = vx if spin else 0.0
        kf[3 * j + 1] = vy if spin else 0.0
        kf[3 * j + 2] = vz if spin else 0.0
    # a second loop: with every array in one, LLVM leaves it scalar
    for j in range(m):
        vx, vy, vz = kf[3 * j], kf[3 * j + 1], kf[3 * j + 2]
        spin = (vx != 0.0) | (vy != 0.0) | (vz != 0.0)
        x, y, z = _unit(
            vx + (c0 * r0[3 * j] + c1 * r1[3 * j] + c2 * r2[3 * j] + c3 * r3[3 * j]),
            vy + (c0 * r0[3 * j + 1] + c1 * r1[3 * j + 1] + c2 * r2[3 * j + 1]
                  + c3 * r3[3 * j + 1]),
            vz + (c0 * r0[3 * j + 2] + c1 * r1[3 * j + 2] + c2 * r2[3 * j + 2]
                  + c3 * r3[3 * j + 2]))
        of[3 * j] = x if spin else 0.0
        of[3 * j + 1] = y if spin else 0.0
        of[3 * j + 2] = z if spin else 0.0


@threaded()
def midpoint_remainder(W, s, B, c, out):
    """out = W − :func:`_frozen_field_midpoint`: what it misses of the midpoint
    (rows without spin: W)."""
    for i in nb.prange(s.shape[0]):
        if s[i, 0] == 0.0 and s[i, 1] == 0.0 and s[i, 2] == 0.0:
            out[i, 0] = W[i, 0]
            out[i, 1] = W[i, 1]
            out[i, 2] = W[i, 2]
            continue
        vx, vy, vz = _frozen_field_midpoint(s[i, 0], s[i, 1], s[i, 2], B[i, 0], B[i, 1], B[i, 2],
                                        c[i])
        out[i, 0] = W[i, 0] - vx
        out[i, 1] = W[i, 1] - vy
        out[i, 2] = W[i, 2] - vz
