r"""The reciprocal-space part of the dipolar Ewald sum on a mesh: smooth
particle-mesh Ewald (SPME) for point dipoles (:class:`~ase_spin.terms.dipolar.Dipolar`,
``method="pme"``).

U. Essmann, L. Perera, M. L. Berkowitz, T. Darden, H. Lee, L. G. Pedersen,
J. Chem. Phys. 103, 8577 (1995) interpolate the structure factor of charges
with cardinal B-splines M_p of order p on a mesh of K_1 × K_2 × K_3 points;
for dipoles (A. Toukmaji, C. Sagui, J. Board, T. Darden, J. Chem. Phys. 113,
10913 (2000)) the moment of a dipole spreads as m·∇ of the charge weights:

.. math::

    S(\mathbf k) = \sum_j (\mathbf m_j\cdot\mathbf k)\, e^{i\mathbf k\cdot\mathbf r_j}
    \approx -i\, b(\mathbf m) \sum_{\mathbf g} Q(\mathbf g)\, e^{2\pi i\,\mathbf m\cdot\mathbf g/K},
    \qquad
    Q(\mathbf g) = \sum_j \mathbf m_j\cdot\nabla_{\mathbf r_j} W_{\mathbf g}(\mathbf r_j),

with W_g(r) = Π_a M_p(u_a − g_a) (periodically wrapped), u_a = K_a (r·b_a)
the scaled fractional coordinate (b_a: the reciprocal vectors without 2π,
∇ = Σ_a K_a b_a ∂/∂u_a), b(m) = Π_a b_a(m_a) the Euler-spline factors. The
reciprocal energy (units of μ0μB²/4π, tin-foil: k = 0 left out) is then a
mesh convolution,

.. math::

    E_k = \frac{2\pi}{V} \sum_{\mathbf k\neq 0} A(k) |S(\mathbf k)|^2
    \approx \tfrac12 \sum_{\mathbf g} Q(\mathbf g)\, \varphi(\mathbf g),
    \qquad \varphi = \mathcal F^{-1}[G\, \mathcal F Q],
    \qquad G(\mathbf m) = \frac{4\pi}{V} K_1K_2K_3\, A(k) |b(\mathbf m)|^2,

A = e^{−k²/4α²}/k², k = 2π Σ_a m_a b_a over the mesh's frequencies. Its
derivatives are gathers of φ with the spline derivatives:

- the field (linear in the moments): H_i = −∂E_k/∂m_i = −Σ_g φ(g) ∇W_g(r_i);
- the forces: F_i = −∂E_k/∂r_i = −Σ_g φ(g) (∇∇ᵀW_g(r_i)) m_i;
- the virial, the strain derivative of this mesh energy at fixed fractional
  coordinates (:meth:`MeshReciprocal.virial`).

The B-spline weights and their first and second derivatives are computed
once per position (:class:`MeshReciprocal`): each field then costs one spread
(N p³), one real FFT pair (M log M for M = K_1 K_2 K_3) and one gather (N p³),
all threaded. The energy is taken on the transform, ½ Σ_g Q φ =
(1/2M) Σ_m G |FQ|² (Parseval), as is the influence function's part of the
virial, so that no more than two meshes are alive at once.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np
import scipy.fft

from .._jit import threads
from .._jit.reductions import stencil_groups, store_sums, sum_over_threads
from .._jit.threads import threaded

__all__ = ["MeshInfluence", "MeshReciprocal", "bspline_moduli", "bspline_weights",
           "default_order", "mesh_interpolation_error", "mesh_size", "mesh_spacing"]

#: The B-spline orders taken: from 4 on, the forces (second derivatives of
#: M_p) are continuous.
ORDERS = range(4, 13)


def bspline_weights(t, order):
    r"""M_p(t + j), M_p'(t + j), M_p''(t + j) for j = 0 … p − 1 at fractional
    parts ``t`` ∈ [0, 1) (any shape; result shape t.shape + (p,)), by the
    recursion M_n(x) = [x M_{n−1}(x) + (n − x) M_{n−1}(x − 1)]/(n − 1) from
    M_2(x) = 1 − |x − 1|, and M_n' (x) = M_{n−1}(x) − M_{n−1}(x − 1)."""
    t = np.asarray(t, dtype=float)[..., None]
    levels = {2: np.concatenate([t, 1.0 - t], axis=-1)}
    for n in range(3, order + 1):
        prev = levels[n - 1]
        j = np.arange(n)
        x = t + j
        zero = np.zeros_like(prev[..., :1])
        levels[n] = (x * np.concatenate([prev, zero], axis=-1)
                     + (n - x) * np.concatenate([zero, prev], axis=-1)) / (n - 1)

    def difference(values, times):
        for _ in range(times):
            zero = np.zeros_like(values[..., :1])
            values = np.concatenate([values, zero], axis=-1) - np.concatenate([zero, values],
                                                                              axis=-1)
        return values

    return levels[order], difference(levels[order - 1], 1), difference(levels[order - 2], 2)


def bspline_moduli(K, order):
    r"""|b(m)|² = 1/|Σ_{k=0}^{p−2} M_p(k + 1) e^{2πimk/K}|² for m = 0 … K − 1
    (Essmann et al., eq. 4.4). For odd p and even K the sum vanishes at the
    Nyquist frequency m = K/2: that mode is left out (0), as its weight
    e^{−k²/4α²} is negligible at a mesh fine enough for the accuracy."""
    M = bspline_weights(np.zeros(1), order)[0][0]  # M_p(j), j = 0 … p − 1
    m = np.arange(K)
    den = np.abs(np.exp(2j * math.pi * np.outer(m, np.arange(order - 1)) / K) @ M[1:]) ** 2
    out = np.zeros(K)
    keep = den > 1e-12
    out[keep] = 1.0 / den[keep]
    return out


def default_order(accuracy):
    """The B-spline order taken when none is given: 8 for ``accuracy`` ≥ 1e-5,
    10 below. A higher order costs p³ per atom in spreading and gathering but
    lets the mesh be coarser (:func:`mesh_spacing` ∝ accuracy^{1/(p−2)}); these
    were the cheaper per evaluation at 1e-4 and 1e-6 (docs/benchmarks.md,
    "Dipolar: cost against N")."""
    return 8 if accuracy >= 1e-5 else 10


def mesh_interpolation_error(alpha, spacing, order):
    r"""The relative error of the mesh's interpolation of the reciprocal
    forces, estimated as ε = 2 [Γ((p + 2)/2)/Γ(3/2)] (α h/π)^{p−2}: a mode k
    is interpolated with the relative error 2 (kh/2π)^{p−n} of its nearest
    aliases (the spline of order p differentiated n times, Essmann et al.
    §3: n = 1 for the field and energy of dipoles, n = 2 for their forces,
    the slower), averaged over the modes with the weight k² e^{−k²/4α²}
    that the reciprocal energy of random moments gives them."""
    return (2.0 * math.gamma(0.5 * (order + 2)) / math.gamma(1.5)
            * (alpha * spacing / math.pi) ** (order - 2))


def mesh_spacing(alpha, accuracy, order):
    """The largest mesh spacing h (Å) whose :func:`mesh_interpolation_error`
    is ``accuracy``."""
    return math.pi / alpha * (accuracy * math.gamma(1.5)
                              / (2.0 * math.gamma(0.5 * (order + 2)))) ** (1.0 / (order - 2))


def mesh_size(cell, alpha, kcut, accuracy, order):
    r"""The mesh (K_1, K_2, K_3) for a cell: along each cell vector h_a, the
    fewest points (a product of 2, 3, 5: fast FFT lengths) such that the mesh
    holds every k-vector of the Ewald sum within k_c (K_a ≥ k_c |h_a|/π) and
    its spacing |h_a|/K_a is at most :func:`mesh_spacing`; at least ``order``
    points."""
    cell = np.asarray(cell, dtype=float)
    spacing = mesh_spacing(alpha, accuracy, order)
    mesh = []
    for a in range(3):
        length = float(np.linalg.norm(cell[a]))
        K = max(order, math.ceil(kcut * length / math.pi), math.ceil(length / spacing))
        mesh.append(scipy.fft.next_fast_len(K, real=True))
    return tuple(mesh)


class MeshInfluence:
    r"""What a mesh needs per cell: the mesh, D (row a = K_a b_a: ∇ = Σ_a D_a ∂/∂u_a),
    and the influence function G(m) of the module's docstring on the
    half-spectrum of a real FFT (shape K_1 × K_2 × (K_3/2 + 1))."""

    __slots__ = ("D", "G", "alpha", "inv", "mesh", "order", "volume")

    def __init__(self, cell, mesh, order, alpha):
        cell = np.asarray(cell, dtype=float)
        self.mesh = tuple(int(K) for K in mesh)
        self.order = int(order)
        self.alpha = float(alpha)
        self.inv = np.linalg.inv(cell)  # s = r @ inv: fractional coordinates
        self.volume = abs(float(np.linalg.det(cell)))
        K = np.array(self.mesh, dtype=float)
        recip = self.inv.T  # row a: b_a
        self.D = K[:, None] * recip
        K1, K2, K3 = self.mesh
        k2 = self.wavenumbers_squared()
        k2[0, 0, 0] = 1.0
        A = np.exp(-k2 / (4.0 * alpha * alpha)) / k2
        A[0, 0, 0] = 0.0
        b2 = (bspline_moduli(K1, order)[:, None, None] * bspline_moduli(K2, order)[None, :, None]
              * bspline_moduli(K3, order)[None, None, :K3 // 2 + 1])
        self.G = (4.0 * math.pi / self.volume) * (K1 * K2 * K3) * A * b2

    def _frequencies(self):
        K1, K2, K3 = self.mesh
        return (np.fft.fftfreq(K1, 1.0 / K1)[:, None, None],
                np.fft.fftfreq(K2, 1.0 / K2)[None, :, None],
                np.arange(K3 // 2 + 1, dtype=float)[None, None, :])

    def wavenumbers_squared(self):
        """k² on the real FFT's half-spectrum, one Cartesian component at a time
        (no (…, 3) array: the mesh can be large)."""
        m1, m2, m3 = self._frequencies()
        recip = 2.0 * math.pi * self.inv.T
        k2 = 0.0
        for c in range(3):
            k2 = k2 + (m1 * recip[0, c] + m2 * recip[1, c] + m3 * recip[2, c]) ** 2
        return k2


# -- spreading and gathering over atoms × p³ mesh points -------------------------

@nb.njit(cache=True, inline="always")
def _spread_atom(i, base, w, dw, c, Q):
    """Q(g) += Σ_a c_ia ∂W_g/∂u_a(u_i) over atom i's p³ mesh points."""
    K1, K2, K3 = Q.shape
    p = w.shape[2]
    c0 = c[i, 0]
    c1 = c[i, 1]
    c2 = c[i, 2]
    if c0 == 0.0 and c1 == 0.0 and c2 == 0.0:
        return
    for j0 in range(p):
        g0 = base[i, 0] - j0
        if g0 < 0:
            g0 += K1
        wx = w[i, 0, j0]
        dx = dw[i, 0, j0]
        for j1 in range(p):
            g1 = base[i, 1] - j1
            if g1 < 0:
                g1 += K2
            wy = w[i, 1, j1]
            dy = dw[i, 1, j1]
            plane = c0 * dx * wy + c1 * wx * dy
            axis = c2 * wx * wy
            for j2 in range(p):
                g2 = base[i, 2] - j2
                if g2 < 0:
                    g2 += K3
                Q[g0, g1, g2] += plane * w[i, 2, j2] + axis * dw[i, 2, j2]


@threaded()
def _spread(groups, base, w, dw, c, Q):
    """Q(g) += Σ_i Σ_a c_ia ∂W_g/∂u_a(u_i) (c_i = D m_i), the atoms sorted by
    mesh cell and cut into groups of planes along the first axis
    (:func:`~ase_spin._jit.reductions.stencil_groups`): the even groups in
    parallel, then the odd ones, each group's atoms in order (the same sums
    in the same order whatever the thread count)."""
    ngroups = len(groups) - 1
    for parity in range(2):
        for h in nb.prange((ngroups - parity + 1) // 2):
            g = 2 * h + parity
            for i in range(groups[g], groups[g + 1]):
                _spread_atom(i, base, w, dw, c, Q)


@threaded()
def _spectrum(nthreads, Qk, G, R, alpha, K3, want_v, acc):
    r"""On the real FFT's half-spectrum FQ (K_1 × K_2 × (K_3/2 + 1)), with the
    weights w_m (2, but 1 on the planes m_3 = 0 and m_3 = K_3/2 that the
    half-spectrum holds once): acc[t] = (Σ w G |FQ|², and with ``want_v``
    Σ w G |FQ|² (1/k² + 1/4α²) k_a k_b in Voigt order) over chunk t of the
    first axis' planes, k = Σ_a m_a R_a (R = 2π (cell⁻¹)ᵀ, m the FFT's
    frequencies); and FQ ← G FQ in place."""
    K1, K2, H3 = Qk.shape
    quarter = 0.25 / (alpha * alpha)
    for t in nb.prange(nthreads):
        e = vxx = vyy = vzz = vyz = vxz = vxy = 0.0
        for a in range(t * K1 // nthreads, (t + 1) * K1 // nthreads):
            m0 = a if a < (K1 + 1) // 2 else a - K1
            for b in range(K2):
                m1 = b if b < (K2 + 1) // 2 else b - K2
                for c in range(H3):
                    q = Qk[a, b, c]
                    g = G[a, b, c]
                    Qk[a, b, c] = g * q
                    if g == 0.0:
                        continue
                    wg = g * (q.real * q.real + q.imag * q.imag)
                    if c != 0 and 2 * c != K3:
                        wg *= 2.0
                    e += wg
                    if want_v:
                        kx = m0 * R[0, 0] + m1 * R[1, 0] + c * R[2, 0]
                        ky = m0 * R[0, 1] + m1 * R[1, 1] + c * R[2, 1]
                        kz = m0 * R[0, 2] + m1 * R[1, 2] + c * R[2, 2]
                        r = wg * (1.0 / (kx * kx + ky * ky + kz * kz) + quarter)
                        vxx += r * kx * kx
                        vyy += r * ky * ky
                        vzz += r * kz * kz
                        vyz += r * ky * kz
                        vxz += r * kx * kz
                        vxy += r * kx * ky
        store_sums(acc, t, e, vxx, vyy, vzz, vyz, vxz, vxy)


@threaded()
def _gather(base, w, dw, d2w, phi, second, G1, G2):
    """G1_ia = Σ_g φ(g) ∂W_g/∂u_a(u_i) and, with ``second``, G2_i (Voigt
    00 11 22 12 02 01) = Σ_g φ(g) ∂²W_g/∂u_a∂u_b(u_i); threaded over atoms."""
    K1, K2, K3 = phi.shape
    p = w.shape[2]
    for i in nb.prange(base.shape[0]):
        a0 = a1 = a2 = 0.0
        s00 = s11 = s22 = s12 = s02 = s01 = 0.0
        for j0 in range(p):
            g0 = base[i, 0] - j0
            if g0 < 0:
                g0 += K1
            wx = w[i, 0, j0]
            dx = dw[i, 0, j0]
            ddx = d2w[i, 0, j0]
            for j1 in range(p):
                g1 = base[i, 1] - j1
                if g1 < 0:
                    g1 += K2
                wy = w[i, 1, j1]
                dy = dw[i, 1, j1]
                ddy = d2w[i, 1, j1]
                # Σ over the third axis of φ W_z, φ W_z', φ W_z''
                f0 = f1 = f2 = 0.0
                for j2 in range(p):
                    g2 = base[i, 2] - j2
                    if g2 < 0:
                        g2 += K3
                    v = phi[g0, g1, g2]
                    f0 += v * w[i, 2, j2]
                    f1 += v * dw[i, 2, j2]
                    if second:
                        f2 += v * d2w[i, 2, j2]
                a0 += dx * wy * f0
                a1 += wx * dy * f0
                a2 += wx * wy * f1
                if second:
                    s00 += ddx * wy * f0
                    s11 += wx * ddy * f0
                    s22 += wx * wy * f2
                    s12 += wx * dy * f1
                    s02 += dx * wy * f1
                    s01 += dx * dy * f0
        G1[i, 0] = a0
        G1[i, 1] = a1
        G1[i, 2] = a2
        if second:
            G2[i, 0] = s00
            G2[i, 1] = s11
            G2[i, 2] = s22
            G2[i, 3] = s12
            G2[i, 4] = s02
            G2[i, 5] = s01


_NO_G2 = np.zeros((0, 6))


class MeshReciprocal:
    """The mesh's reciprocal part at given positions, with the interface of
    :class:`~ase_spin.terms.dipolar_kspace.Reciprocal` (``field``, ``add``):
    the spline weights M_p, M_p', M_p'' of every atom along each axis and its
    mesh cell are kept (9 p doubles and 4 integers per atom), the atoms
    sorted by mesh cell (``order``: neighbours on the mesh are spread and
    gathered one after the other, which keeps the mesh's rows in cache) and
    cut into groups of planes for the threaded spread (``groups``)."""

    __slots__ = ("base", "d2w", "dw", "groups", "influence", "order", "w")

    def __init__(self, positions, influence):
        self.influence = influence
        K = np.array(influence.mesh)
        u = (np.asarray(positions, dtype=float) @ influence.inv) * K
        floor = np.floor(u)
        base = np.mod(floor.astype(np.int64), K)
        self.order = np.lexsort((base[:, 2], base[:, 1], base[:, 0]))
        self.base = np.ascontiguousarray(base[self.order])
        # an atom of plane g spreads onto planes g − p + 1 … g
        self.groups = stencil_groups(self.base[:, 0], influence.mesh[0], influence.order - 1)
        w, dw, d2w = bspline_weights((u - floor)[self.order], influence.order)
        self.w = np.ascontiguousarray(w)
        self.dw = np.ascontiguousarray(dw)
        self.d2w = np.ascontiguousarray(d2w)

    @staticmethod
    def _workers():
        return 1 if threads.small() else nb.get_num_threads()

    def _potential(self, m, want_v=False):
        """(φ, sums) at moments m: spread, FFT, × G, inverse FFT, with sums =
        Σ_t of :func:`_spectrum`'s chunk sums. The 3D FFTs go one axis at a
        time, the complex ones in place: two meshes at most are alive at once
        (Q and its transform, then the transform and φ), where ``rfftn`` and
        ``irfftn`` hold a third (at 10⁵ atoms and more the meshes are most of
        the memory)."""
        inf = self.influence
        Q = np.zeros(inf.mesh)
        _spread(self.groups, self.base, self.w, self.dw,
                np.ascontiguousarray(m[self.order] @ inf.D.T), Q)
        workers = self._workers()
        Qk = scipy.fft.rfft(Q, axis=2, workers=workers)
        del Q
        for axis in (1, 0):
            Qk = scipy.fft.fft(Qk, axis=axis, overwrite_x=True, workers=workers)
        nthreads = threads.count()
        acc = np.zeros((nthreads, 7))
        _spectrum(nthreads, Qk, inf.G, 2.0 * math.pi * inf.inv.T, inf.alpha, inf.mesh[2],
                  want_v, acc)
        for axis in (0, 1):
            Qk = scipy.fft.ifft(Qk, axis=axis, overwrite_x=True, workers=workers)
        phi = scipy.fft.irfft(Qk, n=inf.mesh[2], axis=2, overwrite_x=True, workers=workers)
        return phi, sum_over_threads(acc)

    def _gather(self, phi, second):
        """(G1, G2) of :func:`_gather`, rows in the atoms' order."""
        n = len(self.base)
        G1 = np.empty((n, 3))
        G2 = np.empty((n, 6)) if second else _NO_G2
        _gather(self.base, self.w, self.dw, self.d2w, phi, second, G1, G2)
        out1 = np.empty_like(G1)
        out1[self.order] = G1
        if second:
            out2 = np.empty_like(G2)
            out2[self.order] = G2
            return out1, out2
        return out1, G2

    def field(self, m, H):
        """H_i += −Σ_g φ(g) ∇W_g(r_i) = −Σ_a G1_ia D_a."""
        phi, _ = self._potential(m)
        G1, _ = self._gather(phi, False)
        H -= G1 @ self.influence.D

    def add(self, m, H, F, want_h, want_f, want_v):
        """E_k = ½ Σ_g Q φ = (1/2M) Σ_m G |FQ|² (M = K_1 K_2 K_3 points, F the
        forward FFT: Parseval), and where wanted the field (as :meth:`field`),
        the forces F_i −= Σ_a D_a (G2_i D m_i)_a and the virial
        (:meth:`virial`); returns (E_k, virial)."""
        inf = self.influence
        phi, sums = self._potential(m, want_v)
        npoints = float(np.prod(inf.mesh))
        energy = 0.5 * sums[0] / npoints
        virial = np.zeros(6)
        if want_h or want_f or want_v:
            G1, G2 = self._gather(phi, want_f)
            del phi
            Hk = -(G1 @ inf.D)
            if want_h:
                H += Hk
            if want_f:
                c = m @ inf.D.T
                idx = [[0, 5, 4], [5, 1, 3], [4, 3, 2]]
                Gc = np.einsum("iab,ib->ia", G2[:, idx], c)
                F -= Gc @ inf.D
            if want_v:
                virial = self.virial(m, sums[1:] / npoints, Hk, energy)
        return energy, virial

    @staticmethod
    def virial(m, spectral, Hk, energy):
        r"""∂E_k/∂ε_ab of the mesh energy itself (fractional coordinates fixed):
        the influence function's strain, −δ_ab E_k + Σ_m (2π/V) A |b|²
        2 (1/k² + 1/4α²) k_a k_b |FQ|² (F: the forward FFT, the real FFT's
        half-spectrum planes counted twice but the first and the Nyquist one;
        ``spectral``: that sum in Voigt order, from :func:`_spectrum`, G/2M
        being (2π/V) A |b|²), and that of the spreading's gradients,
        ∇ = Σ_a K_a b_a ∂/∂u_a with b_a → (1 − εᵀ) b_a: sym(Σ_i H_i m_iᵀ) with
        H the reciprocal field (the Ewald sum's −k_a Re(S* T_b) − k_b Re(S* T_a))."""
        X = Hk.T @ m
        W = 0.5 * (X + X.T) - energy * np.eye(3)
        return W[[0, 1, 2, 1, 0, 0], [0, 1, 2, 2, 2, 1]] + spectral
