"""Pair-resolved couplings as DFT gives them (TB2J, SPR-KKR, a fit): per pair
(i, j, R) of a reference cell an isotropic J, a Dzyaloshinskii–Moriya vector D
and a symmetric traceless anisotropic tensor Γ, on any supercell of that
cell, on a moving lattice (:class:`PairCouplings`); and what readers of pair
files share (:func:`merge_directions`, :func:`pairs_within`)."""

from __future__ import annotations

from collections.abc import Mapping

import numba as nb
import numpy as np

from ..neighbors import separation
from ..validate import MAX_COUPLING, length, real_array, warn_implausible, warn_user
from .base import PairOperator, PairSpinTerm, mean_buffer, numeric_self_curvature
from .couplings import check_coupling, checked_values

__all__ = ["PairCouplings", "merge_directions", "pairs_within", "coupling_matrices",
           "LAW_FIXED", "LAW_EXPONENTIAL", "LAW_SHAPE"]

#: How a pair's coupling follows its length r (the geometry kernel's ``law``):
#: fixed (𝒥 = 𝒥⁰), exponential (𝒥 = 𝒥⁰ e^{−(r − r⁰)/λ}), or the ratio f(r)/f(r⁰)
#: of a coupling's own values (given to the kernel as arrays).
LAW_FIXED, LAW_EXPONENTIAL, LAW_SHAPE = 0, 1, 2

#: Largest |R| component (cells) a pair may have: keys are packed into int64.
MAX_CELLS = 1000


def coupling_matrices(J, D=None, Gamma=None):
    r"""The 3×3 couplings 𝒥 = J·1 + Γ + [D] of pairs, (n, 3, 3), with the
    convention of :class:`PairCouplings`: [D] v = v × D, so that
    s_iᵀ [D] s_j = D·(s_i × s_j)."""
    J = np.asarray(J, dtype=float)
    out = J[:, None, None] * np.eye(3)
    if Gamma is not None:
        out = out + np.asarray(Gamma, dtype=float)
    if D is not None:
        D = np.asarray(D, dtype=float)
        out[:, 0, 1] += D[:, 2]
        out[:, 0, 2] -= D[:, 1]
        out[:, 1, 0] -= D[:, 2]
        out[:, 1, 2] += D[:, 0]
        out[:, 2, 0] += D[:, 1]
        out[:, 2, 1] -= D[:, 0]
    return out


def _reversed(i, j, R):
    """Whether each pair (i, j, R) is listed against the canonical orientation
    (i < j, or i == j with R's first non-zero component positive)."""
    first = np.argmax(R != 0, axis=1)
    negative = R[np.arange(len(R)), first] < 0
    return (j < i) | ((j == i) & negative)


def merge_directions(i, j, R, J, D, Gamma, where, atol=0.0):
    """Pairs listed in either direction, or in both, as one row per unordered
    pair in canonical orientation: (j, i, −R) is (i, j, R) with D → −D, Γ → Γᵀ
    (E = −s_iᵀ𝒥 s_j = −s_jᵀ𝒥ᵀ s_i). A pair listed in both directions counts
    once, as the mean of the two, with a warning naming it when they differ by
    more than ``atol`` eV; listed more often in one direction: ValueError.
    ``where`` names the source in messages. Returns (i, j, R, J, D, Gamma,
    counts) with counts the number of listings of each pair."""
    i, j = np.asarray(i, dtype=np.int64), np.asarray(j, dtype=np.int64)
    R = np.asarray(R, dtype=np.int64).reshape(-1, 3)
    swap = _reversed(i, j, R)
    a, b = np.where(swap, j, i), np.where(swap, i, j)
    S = np.where(swap[:, None], -R, R)
    D = np.where(swap[:, None], -D, D)
    Gamma = np.where(swap[:, None, None], np.swapaxes(Gamma, 1, 2), Gamma)
    keys = np.column_stack([a, b, S])
    # a pair listed twice in the same direction is a slip, not a second opinion
    seen = np.column_stack([keys, swap])
    _, once = np.unique(seen, axis=0, return_counts=True)
    if (once > 1).any():
        uniq, counts = np.unique(seen, axis=0, return_counts=True)
        q = uniq[np.argmax(counts > 1)]
        raise ValueError(f"{where}: the pair ({q[0]}, {q[1]}, R={q[2:5].tolist()}) is listed "
                         "twice in the same direction")
    uniq, inv, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    inv = inv.ravel()
    n = len(uniq)
    total = np.zeros((n, 13))
    values = np.column_stack([J, D, Gamma.reshape(-1, 9)])
    np.add.at(total, inv, values)
    mean = total / counts[:, None]
    spread = np.zeros(n)
    np.maximum.at(spread, inv, np.abs(values - mean[inv]).max(axis=1))
    if (spread > atol).any():
        q = int(np.argmax(spread))
        warn_user(f"{where}: the two directions of the pair ({uniq[q, 0]}, {uniq[q, 1]}, "
                  f"R={uniq[q, 2:].tolist()}) differ by up to {2 * spread[q]:.3g} eV "
                  f"({int((spread > atol).sum())} such pairs): using their mean")
    return (uniq[:, 0], uniq[:, 1], uniq[:, 2:], mean[:, 0], mean[:, 1:4],
            mean[:, 4:].reshape(n, 3, 3), counts)


def pairs_within(reference, rc):
    """Every unordered pair (i, j, R) of the periodic ``reference`` (Atoms, or
    the mapping a :class:`PairCouplings` keeps) closer than ``rc`` Å, in
    canonical orientation: (i, j, R, r) sorted by distance. A helper for
    building couplings by hand or from a fit."""
    ref = _reference(reference)
    cell, pos = ref["cell"], ref["positions"]
    rc = length(rc, "pairs_within rc")
    # lattice translations reaching rc: the cell's heights bound each index
    heights = abs(np.linalg.det(cell)) / np.linalg.norm(np.cross(cell[[1, 2, 0]],
                                                                 cell[[2, 0, 1]]), axis=1)
    extent = np.ceil(rc / heights).astype(int) + 1
    grids = np.meshgrid(*[np.arange(-m, m + 1) for m in extent], indexing="ij")
    R = np.stack([g.ravel() for g in grids], axis=1)
    n = len(pos)
    i, j, k = np.meshgrid(np.arange(n), np.arange(n), np.arange(len(R)), indexing="ij")
    i, j, k = i.ravel(), j.ravel(), k.ravel()
    d = pos[j] + R[k] @ cell - pos[i]
    r = np.linalg.norm(d, axis=1)
    keep = (r < rc) & (r > 0.0) & ~_reversed(i, j, R[k])
    i, j, Rk, r = i[keep], j[keep], R[k][keep], r[keep]
    order = np.lexsort((Rk[:, 2], Rk[:, 1], Rk[:, 0], j, i, np.round(r, 8)))
    return i[order], j[order], Rk[order], r[order]


def _reference(reference):
    """The reference structure as {'cell', 'positions', 'symbols'} (read-only
    arrays): from ase.Atoms or such a mapping."""
    if isinstance(reference, Mapping):
        missing = {"cell", "positions", "symbols"} - set(reference)
        if missing:
            raise ValueError(f"PairCouplings reference: a mapping needs 'cell', 'positions' "
                             f"and 'symbols'; missing {sorted(missing)}")
        cell, pos, symbols = reference["cell"], reference["positions"], reference["symbols"]
    elif hasattr(reference, "get_chemical_symbols") and hasattr(reference, "cell"):
        cell, pos = reference.cell.array, reference.positions
        symbols = reference.get_chemical_symbols()
    else:
        raise TypeError("PairCouplings reference must be ase.Atoms (the cell the pairs refer "
                        f"to) or a mapping of cell, positions, symbols; got {reference!r:.60}")
    cell = real_array(cell, "PairCouplings reference cell", (3, 3))
    pos = real_array(pos, "PairCouplings reference positions").reshape(-1, 3)
    symbols = tuple(str(s) for s in symbols)
    if len(symbols) != len(pos) or not len(pos):
        raise ValueError(f"PairCouplings reference: {len(pos)} positions and {len(symbols)} "
                         "symbols (one each per site, at least one site)")
    if not (np.isfinite(cell).all() and np.isfinite(pos).all()):
        raise ValueError("PairCouplings reference: cell and positions must be finite")
    if not abs(np.linalg.det(cell)) > 1e-6:
        raise ValueError(f"PairCouplings reference: the cell {cell.tolist()} spans no volume: "
                         "pairs refer to lattice vectors R of a 3D cell")
    for x in (cell, pos):
        x.setflags(write=False)
    return {"cell": cell, "positions": pos, "symbols": symbols}


@nb.njit(cache=True, inline="always")
def _field(k, a, b, s, data, reverse):
    """Field on spin a from spin b: 𝒥_k s_b (a the pair's first atom), 𝒥_kᵀ s_b."""
    C = data[0]
    x, y, z = s[b, 0], s[b, 1], s[b, 2]
    if reverse:
        return (C[k, 0] * x + C[k, 3] * y + C[k, 6] * z, C[k, 1] * x + C[k, 4] * y + C[k, 7] * z,
                C[k, 2] * x + C[k, 5] * y + C[k, 8] * z)
    return (C[k, 0] * x + C[k, 1] * y + C[k, 2] * z, C[k, 3] * x + C[k, 4] * y + C[k, 5] * z,
            C[k, 6] * x + C[k, 7] * y + C[k, 8] * z)


@nb.njit(cache=True, inline="always")
def _bilinear(M, k, s, i, j):
    """s_iᵀ M_k s_j."""
    x, y, z = s[j, 0], s[j, 1], s[j, 2]
    return (s[i, 0] * (M[k, 0] * x + M[k, 1] * y + M[k, 2] * z)
            + s[i, 1] * (M[k, 3] * x + M[k, 4] * y + M[k, 5] * z)
            + s[i, 2] * (M[k, 6] * x + M[k, 7] * y + M[k, 8] * z))


@nb.njit(cache=True, inline="always")
def _energy(k, i, j, s, data):
    """e = −s_iᵀ𝒥 s_j; the force on j, f = −∂e/∂r_j = (φ'/r)(s_iᵀ𝒥⁰ s_j) d; d_ij."""
    C, C0, P, Dv = data
    e = -_bilinear(C, k, s, i, j)
    dx, dy, dz = Dv[k, 0], Dv[k, 1], Dv[k, 2]
    if P[k] == 0.0:
        return e, 0.0, 0.0, 0.0, dx, dy, dz
    h = P[k] * _bilinear(C0, k, s, i, j)
    return e, h * dx, h * dy, h * dz, dx, dy, dz


@nb.njit(cache=True, inline="always")
def _site(i, s, data):
    """B_i = Σ_j 𝒥_ij s_j from the spins as they are (full pair list)."""
    row, nbr, C = data[0], data[1], data[2]
    bx = by = bz = 0.0
    for k in range(row[i], row[i + 1]):
        cx, cy, cz = _field(k, i, nbr[k], s, (C,), False)
        bx += cx
        by += cy
        bz += cz
    return bx, by, bz


@nb.njit(cache=True)
def _geometry(pos, row, nbr, image, images, rc2, law, decay, C0, r0, phi_in, dphi_in,
              C, P, Dv, other, Cbar):
    """Per pair k = (i → j): d_k, and for a reference pair within rc the coupling
    𝒥_k = φ_k 𝒥⁰_k and P_k = φ'_k/r_k (zero otherwise; r0_k = 0 marks a pair
    of the list that is no reference pair). With ``other``, C̄ = ½(other + C)."""
    want_mean = other.shape[0] > 0
    for i in range(len(row) - 1):
        for k in range(row[i], row[i + 1]):
            dx, dy, dz, r2 = separation(pos, images, i, nbr[k], image[k])
            Dv[k, 0] = dx
            Dv[k, 1] = dy
            Dv[k, 2] = dz
            phi = dphi = 0.0
            if r2 < rc2 and r2 > 0.0 and r0[k] > 0.0:
                r = np.sqrt(r2)
                if law == 0:
                    phi = 1.0
                elif law == 1:
                    phi = np.exp(-(r - r0[k]) / decay)
                    dphi = -phi / decay
                else:
                    phi = phi_in[k]
                    dphi = dphi_in[k]
                P[k] = dphi / r
            else:
                P[k] = 0.0
            for c in range(9):
                C[k, c] = phi * C0[k, c]
                if want_mean:
                    Cbar[k, c] = 0.5 * (other[k, c] + C[k, c])


_NO_C = np.zeros((0, 9))
_NO_R = np.zeros(0)


class _Binding:
    """What :meth:`PairCouplings.bind` makes of a system: the supercell matrix
    M (cell = M · reference cell, M integer), and, filled at the first
    preparation (positions are needed), each atom's reference site; then per
    pair list the pairs' 𝒥⁰ and r⁰ (:meth:`PairCouplings.lookup`)."""

    __slots__ = ("M", "cell", "natoms", "symbols", "magnetic", "pbc", "sites", "lists",
                 "checked")

    def __init__(self, M, cell, natoms, symbols, magnetic, pbc):
        self.M, self.cell, self.natoms, self.symbols = M, cell, natoms, symbols
        self.magnetic, self.pbc = magnetic, pbc
        self.sites = None
        self.lists = {}
        self.checked = False


class PairOperatorWithSelf(PairOperator):
    """:class:`PairOperator` of a term whose pairs may join an atom to its own
    image (cells smaller than the couplings' range): there the field on a spin
    depends on that spin, which :meth:`self_curvature` accounts for."""

    __slots__ = ()

    def self_curvature(self, W):
        p = self.pairs
        if not (p.j == p.i).any():
            return 0.0
        return numeric_self_curvature(self, W)


class PairCouplings(PairSpinTerm):
    r"""Couplings given pair by pair on a reference cell, as DFT gives them:

    .. math::

        E = -\sum_{i<j} \mathbf s_i^{\mathsf T}\,\mathcal J_{ij}\,\mathbf s_j,
        \qquad \mathcal J_{ij} = J_{ij}\,\mathbb 1 + \Gamma_{ij} + [\mathbf D_{ij}],
        \qquad [\mathbf D]\,\mathbf v = \mathbf v\times\mathbf D,

    so that the three parts are −J s_i·s_j (J > 0 ferromagnetic, as
    :class:`~ase_spin.Exchange`), −D·(s_i × s_j) (as TB2J, and as
    :class:`~ase_spin.DMI` with **D**_ij = **e**_ij × **D**) and −s_iᵀΓ s_j,
    each pair once. (j, i, −R) is the same pair with 𝒥ᵀ: D → −D.

    Pairs: site ``i`` of ``reference`` (ase.Atoms, or a mapping of ``cell``,
    ``positions``, ``symbols``) with site ``j`` in the cell shifted by the
    integer lattice vector ``R`` (j at r_j + R·cell); ``J`` (eV, n), ``D`` (eV,
    (n, 3)) and ``Gamma`` (eV, (n, 3, 3), symmetric and traceless) per pair,
    each unordered pair once (:func:`merge_directions` merges both listings).

    The term acts on any supercell of the reference (cell = M · reference
    cell with an integer M, the atoms on its sites, in any order): each atom
    is mapped once to its reference site (the nearest site, within
    ``tolerance`` Å; its species must match); a pair of the neighbour list is
    then the reference pair (a_i, a_j, R) with R the lattice vector its
    separation spans — by identity, not by distance. Cells smaller than the
    pairs' range work (a pair with several images is several pairs).

    On a moving lattice each pair's coupling scales with its length r:

    .. math::

        \mathcal J_{ij}(r) = \mathcal J^0_{ij}\,\varphi_{ij}(r), \qquad
        \varphi_{ij}(r) = e^{-(r - r^0_{ij})/\lambda} \;(\texttt{decay}=\lambda)
        \quad\text{or}\quad \frac{f(r)}{f(r^0_{ij})} \;(\texttt{shape}=f),

    r⁰ the pair's length in the reference, f any coupling J(r) (such as
    :class:`~ase_spin.BetheSlater`); neither: fixed couplings (no spin–lattice
    forces). The directions of D and the axes of Γ stay those of the
    reference (a crystal frame), whatever the bond's direction. The force on
    j is (φ'/r)(s_iᵀ𝒥⁰s_j) d_ij. ``rc`` (Å; default the longest reference
    pair + 0.5 Å) cuts pairs off hard: every reference pair must be within it
    at the structure first seen.
    """

    name = "pair_couplings"
    pair_field, pair_energy, pair_site = _field, _energy, _site

    _parameters = {"reference": "reference", "i": "i", "j": "j", "R": "R", "J": "J", "D": "D",
                   "Gamma": "Gamma", "decay": "decay", "shape": "shape", "rc": "rc",
                   "tolerance": "tolerance"}

    def __init__(self, reference, i, j, R, J, D=None, Gamma=None, *, decay=None, shape=None,
                 rc=None, tolerance=0.5):
        self.reference = _reference(reference)
        nref = len(self.reference["symbols"])
        i = np.asarray(i)
        j = np.asarray(j)
        for name, idx in (("i", i), ("j", j)):
            if idx.ndim != 1 or idx.dtype.kind not in "iu":
                raise TypeError(f"PairCouplings {name} must be a 1D array of site indices "
                                f"(integers), got dtype {idx.dtype} shape {idx.shape}")
        n = len(i)
        if len(j) != n or not n:
            raise ValueError(f"PairCouplings: i and j must have one entry per pair (at least "
                             f"one), got {len(i)} and {len(j)}")
        bad = (i < 0) | (i >= nref) | (j < 0) | (j >= nref)
        if bad.any():
            k = int(np.argmax(bad))
            raise ValueError(f"PairCouplings pair {k}: sites ({i[k]}, {j[k]}) are not sites of "
                             f"the reference (0 to {nref - 1})")
        Rf = real_array(R, "PairCouplings R").reshape(-1, 3) if np.size(R) else np.zeros((0, 3))
        if Rf.shape != (n, 3) or not (np.isfinite(Rf).all() and (Rf == np.round(Rf)).all()):
            raise ValueError(f"PairCouplings R must be ({n}, 3) integer lattice vectors")
        R = Rf.astype(np.int64)
        if np.abs(R).max() > MAX_CELLS:
            raise ValueError(f"PairCouplings R: a lattice vector beyond {MAX_CELLS} cells")
        J = real_array(J, "PairCouplings J").reshape(-1)
        D = np.zeros((n, 3)) if D is None else real_array(D, "PairCouplings D")
        Gamma = np.zeros((n, 3, 3)) if Gamma is None else real_array(Gamma, "PairCouplings Gamma")
        for name, x, shape_ in (("J", J, (n,)), ("D", D, (n, 3)), ("Gamma", Gamma, (n, 3, 3))):
            if x.shape != shape_:
                raise ValueError(f"PairCouplings {name} must have shape {shape_}, got {x.shape}")
            if not np.isfinite(x).all():
                k = int(np.argmax(~np.isfinite(x.reshape(n, -1)).all(axis=1)))
                raise ValueError(f"PairCouplings {name} of pair {k} is not finite")
        scale = max(np.abs(J).max(), np.abs(D).max(), np.abs(Gamma).max(), 1e-300)
        asym = np.abs(Gamma - np.swapaxes(Gamma, 1, 2)).max(axis=(1, 2))
        trace = np.abs(np.trace(Gamma, axis1=1, axis2=2))
        for what, x in (("not symmetric (its antisymmetric part is D)", asym),
                        ("not traceless (its trace belongs to J)", trace)):
            if (x > 1e-12 * scale).any():
                k = int(np.argmax(x))
                raise ValueError(f"PairCouplings Gamma of pair {k} is {what}: off by {x[k]:.3g} "
                                 "eV; coupling_matrices / from_matrices split a full tensor")
        self_pair = (i == j) & (R == 0).all(axis=1)
        if self_pair.any():
            raise ValueError(f"PairCouplings pair {int(np.argmax(self_pair))}: site {i[self_pair][0]} "
                             "with itself (R = 0) is no pair (an on-site term is an anisotropy)")
        swap = _reversed(i, j, R)
        # canonical orientation, stored as such: (j, i, −R) with D → −D, Γᵀ = Γ
        self.i = np.where(swap, j, i).astype(np.int64)
        self.j = np.where(swap, i, j).astype(np.int64)
        self.R = np.where(swap[:, None], -R, R)
        self.J, self.D, self.Gamma = J.copy(), np.where(swap[:, None], -D, D), Gamma.copy()
        keys = np.column_stack([self.i, self.j, self.R])
        uniq, counts = np.unique(keys, axis=0, return_counts=True)
        if (counts > 1).any():
            q = uniq[int(np.argmax(counts > 1))]
            raise ValueError(f"PairCouplings: the pair ({q[0]}, {q[1]}, R={q[2:].tolist()}) is "
                             "given twice (each unordered pair once; merge_directions merges "
                             "files that list both directions)")
        warn_implausible(scale, MAX_COUPLING, "PairCouplings |J|, |D|, |Γ|", "eV",
                         "DFT couplings are meV to ~0.1 eV per pair", "energy")
        cell, pos = self.reference["cell"], self.reference["positions"]
        self.r0 = np.linalg.norm(pos[self.j] + self.R @ cell - pos[self.i], axis=1)
        if not self.r0.min() > 0.1:
            k = int(np.argmin(self.r0))
            raise ValueError(f"PairCouplings pair {k}: sites {self.i[k]} and {self.j[k]} are "
                             f"{self.r0[k]:.3g} Å apart in the reference")
        if decay is not None and shape is not None:
            raise ValueError("PairCouplings: give decay (exponential law) or shape (f(r)/f(r0)), "
                             "not both")
        self.decay = None if decay is None else length(decay, "PairCouplings decay")
        self.shape = check_coupling(shape, "PairCouplings shape")
        if self.shape is not None:
            f0 = checked_values(self.shape, self.r0)[0]
            if (f0 == 0.0).any():
                k = int(np.argmax(f0 == 0.0))
                raise ValueError(f"PairCouplings shape: f(r0) = 0 for pair {k} (r0 = "
                                 f"{self.r0[k]:.4f} Å): f(r)/f(r0) is undefined")
            self._f0 = f0
        self.rc = (length(rc, "PairCouplings rc") if rc is not None
                   else float(self.r0.max()) + 0.5)
        if self.rc <= self.r0.max():
            k = int(np.argmax(self.r0))
            raise ValueError(f"PairCouplings rc = {self.rc} Å leaves out pair {k} at "
                             f"r0 = {self.r0[k]:.4f} Å")
        self.cutoff = self.rc
        self.tolerance = length(tolerance, "PairCouplings tolerance")
        for x in (self.i, self.j, self.R, self.J, self.D, self.Gamma, self.r0):
            x.setflags(write=False)
        self._finish()

    @classmethod
    def from_matrices(cls, reference, i, j, R, matrices, **kw):
        """The couplings of full 3×3 tensors 𝒥 (eV, (n, 3, 3), E = −s_iᵀ𝒥 s_j):
        J = tr 𝒥/3, D from the antisymmetric part, Γ the symmetric traceless rest."""
        M = real_array(matrices, "PairCouplings matrices")
        if M.ndim != 3 or M.shape[1:] != (3, 3):
            raise ValueError(f"PairCouplings matrices must have shape (n, 3, 3), got {M.shape}")
        J = np.trace(M, axis1=1, axis2=2) / 3.0
        A = 0.5 * (M - np.swapaxes(M, 1, 2))
        D = np.stack([A[:, 1, 2], A[:, 2, 0], A[:, 0, 1]], axis=1)
        Gamma = 0.5 * (M + np.swapaxes(M, 1, 2)) - J[:, None, None] * np.eye(3)
        return cls(reference, i, j, R, J, D, Gamma, **kw)

    def matrices(self):
        """The pairs' 3×3 couplings 𝒥⁰ (eV, (n, 3, 3)) in canonical orientation."""
        return coupling_matrices(self.J, self.D, self.Gamma)

    def __len__(self):
        return len(self.J)

    def __repr__(self):
        return (f"PairCouplings({len(self)} pairs on {len(self.reference['symbols'])} sites, "
                f"rc={self.rc}, decay={self.decay}, shape={self.shape!r})")

    def lammps(self, types):
        raise NotImplementedError(
            "PairCouplings: LAMMPS's pair styles take couplings per pair of atom types as "
            "functions of distance; an explicit list of pairs (i, j, R) with their own J, D "
            "and Γ cannot be expressed in them")

    # -- binding ----------------------------------------------------------
    def bind(self, system):
        cell = np.asarray(system.cell, dtype=float)
        ref = self.reference["cell"]
        M = cell @ np.linalg.inv(ref)
        Mi = np.round(M)
        nref = len(self.reference["symbols"])
        # a strained supercell still maps: M is the nearest integer matrix
        if not (np.isfinite(M).all() and np.abs(M - Mi).max() < 0.25
                and abs(np.linalg.det(Mi)) > 0.5):
            raise ValueError(
                "PairCouplings: the cell is not a supercell of the reference cell (cell = M · "
                f"reference cell needs an integer M; got M = {np.round(M, 3).tolist()}): build "
                "the structure as reference.repeat(...) or make_supercell(reference, M)")
        ncells = int(round(abs(np.linalg.det(Mi))))
        if system.natoms != ncells * nref:
            raise ValueError(f"PairCouplings: {system.natoms} atoms in a supercell of {ncells} "
                             f"reference cells of {nref} sites (expected {ncells * nref})")
        symbols = np.asarray(system.species.symbols)[system.types]
        return _Binding(Mi, cell, system.natoms, symbols, system.magnetic, np.asarray(system.pbc))

    def _map_sites(self, binding, positions, cell_now):
        """Each atom's reference site: the nearest one modulo the (strained)
        reference lattice, within ``tolerance`` Å, of the atom's species. The
        structure may be translated as a whole: if the sites do not fit as
        they are, atom 0 is tried on each site of its species."""
        frac = positions @ np.linalg.inv(cell_now)                # (N, 3) reference units
        site_frac = self.reference["positions"] @ np.linalg.inv(self.reference["cell"])
        ref_symbols = np.asarray(self.reference["symbols"])
        shifts = [np.zeros(3)] + [frac[0] - site_frac[a] for a in range(len(site_frac))
                                  if ref_symbols[a] == binding.symbols[0]]
        for shift in shifts:
            delta = (frac - shift)[:, None, :] - site_frac[None, :, :]
            delta -= np.round(delta)
            dist = np.linalg.norm(delta @ cell_now, axis=2)       # (N, nsites)
            sites = np.argmin(dist, axis=1)
            off = dist[np.arange(len(sites)), sites]
            if (off <= self.tolerance).all():
                break
        if (off > self.tolerance).any():
            a = int(np.argmax(off))
            raise ValueError(f"PairCouplings: atom {a} is {off[a]:.3g} Å from the nearest site "
                             f"of the reference (tolerance {self.tolerance} Å): the structure "
                             "is not a supercell of the reference, or too distorted to map")
        ref_symbols = ref_symbols[sites]
        wrong = ref_symbols != binding.symbols
        if wrong.any():
            a = int(np.argmax(wrong))
            raise ValueError(f"PairCouplings: atom {a} ({binding.symbols[a]}) sits on reference "
                             f"site {sites[a]} ({ref_symbols[a]})")
        counts = np.bincount(sites, minlength=len(site_frac))
        if (counts != counts[0]).any():
            raise ValueError("PairCouplings: the atoms do not fill the reference sites evenly "
                             f"(atoms per site {counts.tolist()}): two atoms share a site")
        return sites

    def lookup(self, binding, pairs, positions):
        """(𝒥⁰ as (n, 9), r⁰) of every pair of ``pairs`` (zero for pairs that
        are no reference pair), kept per pair list."""
        kept = binding.lists.get(id(pairs))
        if kept is not None and kept[0] is pairs:
            return kept[1], kept[2]
        # the reference cell as strained with the supercell
        cell_now = np.linalg.inv(binding.M) @ binding.cell
        if binding.sites is None:
            binding.sites = self._map_sites(binding, positions, cell_now)
        sites = binding.sites
        i, j = pairs.i, pairs.j
        d = positions[j] + pairs.shift - positions[i]
        site_frac = self.reference["positions"] @ np.linalg.inv(self.reference["cell"])
        R = np.round(d @ np.linalg.inv(cell_now) - site_frac[sites[j]]
                     + site_frac[sites[i]]).astype(np.int64)
        # every reference pair in both orientations: (a, b, R) → 𝒥, (b, a, −R) → 𝒥ᵀ
        mats = self.matrices()
        a_all = np.concatenate([self.i, self.j])
        b_all = np.concatenate([self.j, self.i])
        R_all = np.concatenate([self.R, -self.R])
        m_all = np.concatenate([mats, np.swapaxes(mats, 1, 2)]).reshape(-1, 9)
        r0_all = np.concatenate([self.r0, self.r0])
        index_all = np.concatenate([np.arange(len(self)), np.arange(len(self))])
        nref = len(self.reference["symbols"])
        span = 2 * MAX_CELLS + 3

        def pack(a, b, R):
            R = np.clip(R, -MAX_CELLS - 1, MAX_CELLS + 1) + MAX_CELLS + 1
            return ((a * nref + b) * span + R[:, 0]) * span ** 2 + R[:, 1] * span + R[:, 2]

        keys = pack(a_all, b_all, R_all)
        order = np.argsort(keys)
        keys = keys[order]
        q = pack(sites[i], sites[j], R)
        at = np.minimum(np.searchsorted(keys, q), len(keys) - 1)
        found = keys[at] == q
        # (a, a, R) and (a, a, −R) of one pair are two entries; a self pair is listed once
        C0 = np.where(found[:, None], m_all[order][at], 0.0)
        r0 = np.where(found, r0_all[order][at], 0.0)
        if not binding.checked:
            binding.checked = True
            self._check_found(binding, pairs, found, index_all[order][at], positions)
        C0 = np.ascontiguousarray(C0)
        if len(binding.lists) > 3:
            binding.lists.clear()
        binding.lists[id(pairs)] = (pairs, C0, r0)
        return C0, r0

    def _check_found(self, binding, pairs, found, index, positions):
        """Every reference pair is in the first pair list (a fully periodic,
        all-magnetic system): ncells times on a half list, twice that on a full one."""
        if not (binding.pbc.all() and binding.magnetic.all()):
            return
        ncells = binding.natoms // len(self.reference["symbols"])
        per_pair = np.bincount(index[found], minlength=len(self))
        expected = ncells * (1 if pairs.half else 2)
        short = per_pair < expected
        if short.any():
            k = int(np.argmax(short))
            raise ValueError(f"PairCouplings: reference pair {k} ({self.i[k]}, {self.j[k]}, "
                             f"R={self.R[k].tolist()}, r0 = {self.r0[k]:.4f} Å) is beyond rc = "
                             f"{self.rc} Å in this structure for {expected - per_pair[k]} of its "
                             f"{expected} copies: raise rc")

    # -- preparation --------------------------------------------------------
    def prepare(self, positions, pairs, types, binding, *, virial=False, out=None,
                mean_with=None):
        C0, r0 = self.lookup(binding, pairs, positions)
        n = len(pairs)
        if out is not None and out.pairs is pairs and out.data[1] is C0:
            C, P, Dv = out.data[0], out.data[2], out.data[3]
            Cbar = out.mean_data[0] if out.mean_data is not None else None
        else:
            C, P, Dv, Cbar = np.empty((n, 9)), np.empty(n), np.empty((n, 3)), None
        Cbar = mean_buffer(mean_with, pairs, Cbar, (n, 9))
        other = mean_with.data[0] if mean_with is not None else _NO_C
        law, phi, dphi = LAW_FIXED, _NO_R, _NO_R
        if self.decay is not None:
            law = LAW_EXPONENTIAL
        elif self.shape is not None:
            law = LAW_SHAPE
            phi, dphi = self._shape_ratio(binding, pairs, positions, r0)
        _geometry(positions, pairs.row, pairs.j, pairs.image, pairs.images, self.rc**2, law,
                  self.decay or 1.0, C0, r0, phi, dphi, C, P, Dv, other,
                  Cbar if Cbar is not None else _NO_C)
        data = (C, C0, P, Dv)
        mean_data = (Cbar, C0, P, Dv) if Cbar is not None else None
        return PairOperatorWithSelf(pairs, data, mean_data, self._compiled_pass(),
                                    type(self).pair_site)

    def _shape_ratio(self, binding, pairs, positions, r0):
        """φ = f(r)/f(r⁰) and φ' = f'(r)/f(r⁰) per pair, by the coupling's own values."""
        d = positions[pairs.j] + pairs.shift - positions[pairs.i]
        r = np.sqrt(np.einsum("ij,ij->i", d, d))
        phi, dphi = np.zeros(len(r)), np.zeros(len(r))
        ok = r0 > 0.0
        f, df = checked_values(self.shape, r[ok])
        f0 = checked_values(self.shape, r0[ok])[0]
        phi[ok], dphi[ok] = f / f0, df / f0
        return phi, dphi
