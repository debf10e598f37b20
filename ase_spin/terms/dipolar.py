"""The magnetic dipole–dipole interaction of point moments (LAMMPS ``pair_style
spin/dipole/cut``, ``spin/dipole/long`` with ``kspace_style ewald/dipole/spin``
or ``pppm/dipole/spin``):
a plain cutoff, the direct sum over all pairs of an open system, and the Ewald
sum of a fully periodic one with tin-foil boundary conditions or of a slab
(periodic in two directions, the Yeh–Berkowitz correction), its reciprocal
part summed over k-vectors (:mod:`ase_spin.terms.dipolar_kspace`) or on a
mesh (smooth particle-mesh Ewald, :mod:`ase_spin.terms.dipolar_mesh`)."""

from __future__ import annotations

import math

import numpy as np
from ase import units

from .._jit import threads
from ..constants import MU_B
from ..validate import length, positive_scalar, warn_user
from .base import SpinOperator, SpinTerm
from .dipolar_kspace import (
    Reciprocal,
    SlabCorrection,
    ewald_error_bound,
    ewald_parameters,
    kvectors,
    slab_geometry,
)
from .dipolar_mesh import (
    ORDERS,
    MeshInfluence,
    MeshReciprocal,
    default_order,
    mesh_size,
)
from .dipolar_pairs import (
    cut_site,
    direct_field,
    direct_pass,
    list_field,
    list_pass,
    pair_geometry,
)
from .lammps_form import LammpsKspace, LammpsPair, number_text

__all__ = [
    "DIPOLAR_CODATA",
    "DIPOLAR_LAMMPS",
    "Dipolar",
    "LAMMPS_PPPM_MAX_ORDER",
    "DipolarOperator",
    "ewald_error_bound",
    "ewald_parameters",
]

#: μ0 μB²/4π in eV·Å³ (CODATA, the set ase.units uses): the energy of two
#: 1 μB moments 1 Å apart, side by side, is this (head to tail: −2×).
DIPOLAR_CODATA = units._mu0 / (4.0 * math.pi) * MU_B**2 * units._e * 1e30

#: LAMMPS SPIN's μ0 μB²/4π (``pair_style spin/dipole/*``, LAMMPS 2025.7.22:
#: μB = 9.274e-4 A·Å², μ0 = 784.15 eV/(Å·A²); the 2019 sources had 785.15),
#: 2.3e-4 relative below :data:`DIPOLAR_CODATA`.
DIPOLAR_LAMMPS = 9.274e-4**2 * 784.15 / (4.0 * math.pi)

_METHODS = ("cut", "direct", "ewald", "pme")

#: The highest stencil order LAMMPS's ``pppm/dipole/spin`` takes (its
#: MAXORDER; its order p is the points per axis, our B-spline order).
LAMMPS_PPPM_MAX_ORDER = 7


class _Bound:
    """What :meth:`Dipolar.bind` makes: the moments μ_i, the prefactor
    μ0μB²/4π (eV·Å³), and for the Ewald sum α, the k-vectors with A(k), the
    volume and the self-term coefficient (for the mesh its
    :class:`~ase_spin.terms.dipolar_mesh.MeshInfluence`); for a slab its
    correction, normal and height."""

    __slots__ = ("A", "alpha", "height", "k", "mesh", "mu", "pref", "self_coef", "slab",
                 "volume")

    def __init__(self, mu, pref, alpha=0.0, k=None, A=None, volume=None, self_coef=0.0,
                 slab=None, height=None, mesh=None):
        self.mu = mu
        self.pref = pref
        self.alpha = alpha
        self.k = k
        self.A = A
        self.volume = volume
        self.self_coef = self_coef
        self.slab = slab
        self.height = height
        self.mesh = mesh  # the MeshInfluence of method="pme"


_NO_ROWS = np.zeros((0, 3))
_NO_ENERGIES = np.zeros(0)


class DipolarOperator(SpinOperator):
    """The dipolar term prepared at given positions: per pair of the list the
    separation d and (B1, B2, B3)(r); for the Ewald sum the k-space phases;
    for the direct sum a copy of the positions. ``other``: the operator at
    the step's other end (``mean_with``), for the midpoint field."""

    __slots__ = ("B", "D", "bound", "method", "other", "pairs", "pos", "recip")

    def __init__(self, bound, method, pairs, D, B, pos, recip, other):
        self.bound = bound
        self.method = method
        self.pairs = pairs
        self.D = D
        self.B = B
        self.pos = pos
        self.recip = recip
        self.other = other

    @property
    def expensive_field(self):
        """The Ewald sums and the direct sum: each field a sum over every
        k-vector, mesh point or atom (its cost against exchange's:
        docs/benchmarks.md, "Dipolar: cost against N"); the cutoff form is a
        pair pass like any other."""
        return self.method != "cut"

    @property
    def site_unavailable(self):
        if self.method == "ewald":
            return ("the Ewald field of one spin is a sum over every k-vector, as dear as "
                    "the whole field, so a sweep would cost O(N²K); use CollectivePRK, "
                    "or Dipolar(method='cut')")
        if self.method == "pme":
            return ("the mesh field of one spin costs a whole mesh convolution, so a sweep "
                    "would cost O(N² log N); use CollectivePRK, or Dipolar(method='cut')")
        if self.method == "direct":
            return ("the direct sum's field of one spin runs over every atom (a sweep "
                    "O(N²)); use CollectivePRK, or Dipolar(method='cut')")
        return None

    @property
    def site(self):
        """The per-spin field of ``"cut"`` on a full pair list (the sweeps'
        list); None otherwise (:attr:`site_unavailable` says why)."""
        if self.method != "cut" or self.pairs.half:
            return None
        b = self.bound
        return cut_site, (self.pairs.row, self.pairs.j, self.D, self.B, b.mu,
                           np.array([b.pref]))

    def _moments(self, W):
        return self.bound.mu[:, None] * np.asarray(W, dtype=float)

    def _field(self, m):
        """H = −∂E/∂m (eV/μB) at moments m."""
        H = np.zeros_like(m)
        if self.method == "direct":
            direct_field(self.pos, m, H)
        else:
            p = self.pairs
            list_field(threads.count(), p.row, p.j, p.half, m, self.D, self.B, H)
        if self.recip is not None:
            self.recip.field(m, H)
            H -= (2.0 * self.bound.self_coef) * m  # −∂/∂m of self_coef |m|²
            if self.bound.slab is not None:
                self.bound.slab.add(m, H, False)
        return H

    def field(self, W, out, mean=False):
        """B_i = μ_i μ0μB²/4π H_i at spins W; with ``mean``, the average of the
        fields of this operator and of ``other`` (the midpoint field)."""
        m = self._moments(W)
        H = self._field(m)
        if mean:
            if self.other is None:
                raise ValueError("mean=True needs an operator prepared with mean_with")
            H = 0.5 * (H + self.other._field(m))
        out += (self.bound.pref * self.bound.mu)[:, None] * H

    def add(self, W, want, magnetic_forces, forces, energies):
        """E = μ0μB²/4π [Σ_pairs e + E_k − (2α³/3√π) Σ_i |m_i|²] and what
        ``want`` asks for; returns (E, virial)."""
        b = self.bound
        m = self._moments(W)
        F = np.zeros_like(m) if want.forces else _NO_ROWS
        e_i = np.zeros(len(m)) if want.energies else _NO_ENERGIES
        if self.method == "direct":
            v = direct_pass(self.pos, m, F, e_i, want.forces, want.energies)
        else:
            p = self.pairs
            v = list_pass(threads.count(), p.row, p.j, p.half, m, self.D, self.B, F, e_i,
                          want.forces, want.energies)
        energy, virial = v[0], v[1:].copy()
        H = None
        if self.recip is None:
            if want.magnetic_forces:
                H = self._field(m)
        else:
            # the field as _field makes it, its real-space part kept apart and
            # its k-space part from the structure factors E_k takes anyway
            # (then the self and slab terms, all quadratic in m)
            need_field = want.magnetic_forces or want.energies
            if need_field:
                p = self.pairs
                Hreal = np.zeros_like(m)
                list_field(threads.count(), p.row, p.j, p.half, m, self.D, self.B, Hreal)
                H = Hreal.copy()
            Ek, Wk = self.recip.add(m, H, F, need_field, want.forces, want.virial)
            m2 = np.einsum("ij,ij->i", m, m)
            energy += Ek + b.self_coef * m2.sum()
            virial += Wk
            if need_field:
                H -= (2.0 * b.self_coef) * m  # −∂/∂m of self_coef |m|²
            if b.slab is not None:
                Es, Ws = b.slab.add(m, H if need_field else None, want.virial)
                energy += Es
                virial += Ws
            if want.energies:
                # E_k + E_self (+ E_slab) is quadratic in m: ½ m_i·∂/∂m_i of it
                # per atom, with H − H_real the field of those parts
                e_i -= 0.5 * np.einsum("ij,ij->i", m, H - Hreal)
        pref = b.pref
        if want.magnetic_forces:
            magnetic_forces += (pref * b.mu)[:, None] * H
        if want.forces:
            forces += pref * F
        if want.energies:
            energies += pref * e_i
        return pref * energy, pref * virial


class Dipolar(SpinTerm):
    r"""The magnetic dipole–dipole interaction of point moments
    **m**_i = μ_i μB **s**_i (μ_i: the atom's moment magnitude, μB):

    .. math::

        E = -\frac{\mu_0}{4\pi} \sum_{i<j} \frac{3 (\mathbf m_i\cdot\hat{\mathbf e}_{ij})
            (\mathbf m_j\cdot\hat{\mathbf e}_{ij}) - \mathbf m_i\cdot\mathbf m_j}{r_{ij}^3},
        \qquad
        \mathbf B_i = -\frac{\partial E}{\partial \mathbf s_i}
        = \frac{\mu_0}{4\pi}\mu_B^2 \mu_i \sum_j \mu_j
          \frac{3 (\mathbf s_j\cdot\hat{\mathbf e}_{ij})\hat{\mathbf e}_{ij}
          - \mathbf s_j}{r_{ij}^3},

    in eV, with the forces −∂E/∂r_i and the virial ∂E/∂ε of moments carried by
    moving atoms (two moments head to tail along their axis attract, E < 0).

    ``method``:

    - ``"cut"`` (LAMMPS ``pair_style spin/dipole/cut rc``): the pairs closer
      than ``rc`` (Å), plainly truncated (the energy jumps at rc), over the
      neighbour list; any periodicity.
    - ``"direct"``: every pair of an open system (no periodic direction), in
      O(N²) time per evaluation (no neighbour list); for clusters of up to a
      few thousand atoms.
    - ``"ewald"``: the Ewald sum with tin-foil (conducting) boundary
      conditions, as LAMMPS's ``ewald/dipole/spin``; ``rc`` (Å) is the
      real-space cutoff. ``accuracy`` (relative, default 1e-6) sets the
      splitting α and the k-space cutoff k_c by :func:`ewald_parameters`:
      the neglected terms, relative to the bare pair term at rc, are about
      ``accuracy`` on both sides. ``alpha`` (1/Å) and ``kcut`` (1/Å) given
      explicitly override it. The reciprocal part keeps the phases of every
      atom and k-vector (16 N K bytes, K ∝ (k_c L)³). Fully periodic cells,
      or slabs: pbc = (True, True, False), periodic along cell[0] and
      cell[1], the atoms within the height of cell[2] across the plane; the
      sum runs in a cell ``slab`` times as high (default 3, LAMMPS's
      ``kspace_modify slab``), with the Yeh–Berkowitz correction
      (:class:`~ase_spin.terms.dipolar_kspace.SlabCorrection`).
    - ``"pme"``: the same Ewald sum (same α, real-space part, boundaries and
      slabs), its reciprocal part by smooth particle-mesh Ewald
      (:mod:`~ase_spin.terms.dipolar_mesh`): B-splines of order ``order``
      (4 … 12; None: 8 for ``accuracy`` ≥ 1e-5, else 10, the cheaper
      measured) on a mesh of ``mesh`` = (K1, K2, K3) points along
      the cell vectors, FFTs, O(N log N) per evaluation. ``mesh=None``
      chooses it from ``accuracy``
      (:func:`~ase_spin.terms.dipolar_mesh.mesh_size`: every k-vector within
      k_c, and the interpolation error estimate within ``accuracy``).

    ``prefactor``: μ0 μB²/4π in eV·Å³; None (default) follows the
    Hamiltonian's conventions: :data:`DIPOLAR_CODATA` (physical), LAMMPS's
    rounded :data:`DIPOLAR_LAMMPS` (``conventions="lammps"``); give
    ``DIPOLAR_LAMMPS`` to compare with LAMMPS under physical conventions.

    The sequential sweeps of :class:`~ase_spin.SuzukiTrotter` take the
    ``"cut"`` form (LAMMPS's ``fix nve/spin`` with ``spin/dipole/cut``). The
    field of one spin costs a whole k-space sum for the Ewald sum, and every
    atom for the direct sum: their operators offer no per-spin ``site``
    field and say why (``site_unavailable``), and SuzukiTrotter refuses
    them with that reason; the collective integrators take every method.
    """

    name = "dipolar"
    neighbor_list = "half"

    _parameters = {"rc": "rc", "method": "method", "accuracy": "accuracy", "alpha": "alpha",
                   "kcut": "kcut", "slab": "slab", "mesh": "mesh", "order": "order",
                   "prefactor": "prefactor"}

    def __init__(self, rc=None, method="cut", *, accuracy=1e-6, alpha=None, kcut=None,
                 slab=None, mesh=None, order=None, prefactor=None):
        if method not in _METHODS:
            raise ValueError(f"Dipolar method must be one of {_METHODS}, got {method!r}")
        self.method = method
        if method == "direct":
            if rc is not None:
                raise ValueError("Dipolar(method='direct') sums every pair: it takes no rc")
            self.rc = None
            self.neighbor_list = None
            self.cutoff = 0.0
        else:
            if rc is None:
                raise ValueError(f"Dipolar(method={method!r}) needs a cutoff rc (Å)")
            self.rc = length(rc, "Dipolar rc")
            self.cutoff = self.rc
        self.accuracy = positive_scalar(accuracy, "Dipolar accuracy")
        if not self.accuracy < 1.0:
            raise ValueError(f"Dipolar accuracy must be below 1, got {self.accuracy}")
        self.alpha = None if alpha is None else positive_scalar(alpha, "Dipolar alpha")
        self.kcut = None if kcut is None else positive_scalar(kcut, "Dipolar kcut")
        self._mesh_settings(mesh, order)
        self.slab = None
        if slab is not None:
            if method not in ("ewald", "pme"):
                raise ValueError("Dipolar slab= is a setting of method='ewald' or 'pme', not "
                                 f"{method!r}")
            self.slab = positive_scalar(slab, "Dipolar slab")
            if not self.slab >= 2.0:
                raise ValueError("Dipolar slab (the Ewald cell's height over the slab's) must "
                                 f"be at least 2, as LAMMPS's kspace_modify slab; got {self.slab}")
        self.prefactor = (None if prefactor is None
                          else positive_scalar(prefactor, "Dipolar prefactor"))
        self._finish()

    def _mesh_settings(self, mesh, order):
        if order is not None:
            if isinstance(order, bool) or not hasattr(order, "__index__"):
                raise TypeError("Dipolar order (of the mesh's B-splines) must be a whole "
                                f"number, got {order!r}")
            if int(order) not in ORDERS:
                raise ValueError(f"Dipolar order must lie between {ORDERS[0]} and "
                                 f"{ORDERS[-1]}, got {order}")
            if self.method != "pme":
                raise ValueError(f"Dipolar order= is a setting of method='pme', not "
                                 f"{self.method!r}")
            order = int(order)
        self.order = order
        if mesh is not None:
            if self.method != "pme":
                raise ValueError(f"Dipolar mesh= is a setting of method='pme', not "
                                 f"{self.method!r}")
            points = np.broadcast_to(np.asarray(mesh), (3,)) if np.ndim(mesh) == 0 else mesh
            points = np.asarray(points)
            if (points.shape != (3,) or points.dtype.kind not in "iu"
                    or not np.all(points >= self.spline_order)):
                raise ValueError(f"Dipolar mesh must be one or three whole numbers of mesh "
                                 f"points, each at least the order {self.spline_order}; got "
                                 f"{mesh!r}")
            mesh = tuple(int(K) for K in points)
            if self.kcut is not None:
                raise ValueError("Dipolar: give the mesh's kcut= (the k-vectors it must hold) "
                                 "or mesh=, not both")
        self.mesh = mesh

    @property
    def spline_order(self):
        """The B-spline order of ``method="pme"``: ``order``, or where None the
        cheaper for the accuracy (:func:`~ase_spin.terms.dipolar_mesh.default_order`)."""
        return default_order(self.accuracy) if self.order is None else self.order

    def __repr__(self):
        extra = (f", accuracy={self.accuracy}, alpha={self.alpha}, kcut={self.kcut}, "
                 f"slab={self.slab}" if self.method in ("ewald", "pme") else "")
        if self.method == "pme":
            extra += f", mesh={self.mesh}, order={self.order}"
        return f"Dipolar(rc={self.rc}, method={self.method!r}{extra}, prefactor={self.prefactor})"

    def splitting(self):
        """(α, k_c) of the Ewald sum (1/Å): from ``accuracy`` (:func:`ewald_parameters`),
        α r_c = x and k_c = 2αx, where not given."""
        alpha, kcut = ewald_parameters(self.rc, self.accuracy)
        if self.alpha is not None:
            kcut *= self.alpha / alpha  # the same x = k_c/2α
            alpha = self.alpha
        if self.kcut is not None:
            kcut = self.kcut
        return alpha, kcut

    def _prefactor(self, conventions):
        if self.prefactor is not None:
            return self.prefactor
        return DIPOLAR_LAMMPS if conventions.name == "lammps" else DIPOLAR_CODATA

    def bind(self, system):
        pref = self._prefactor(system.conventions)
        mu = np.ascontiguousarray(system.moments, dtype=float)
        pbc = tuple(bool(p) for p in system.pbc)
        if self.method == "direct":
            if any(pbc):
                raise ValueError("Dipolar(method='direct') is for open systems (pbc all "
                                 f"False), got pbc={list(pbc)}: use method='ewald'")
            return _Bound(mu, pref)
        if self.method == "cut":
            return _Bound(mu, pref)
        cell = np.asarray(system.cell, dtype=float)
        slab = height = None
        if pbc == (True, True, False):
            cell, normal, height = slab_geometry(cell, 3.0 if self.slab is None else self.slab)
        elif pbc != (True, True, True):
            raise ValueError(f"Dipolar(method={self.method!r}) needs a periodic cell in all three "
                             "directions, or a slab periodic in the first two (pbc=[True, "
                             f"True, False]); got pbc={list(pbc)}")
        elif self.slab is not None:
            raise ValueError(f"Dipolar slab={self.slab} is for slabs (pbc=[True, True, False]); "
                             "this cell is periodic in all three directions")
        alpha, kcut = self.splitting()
        self_coef = -2.0 * alpha**3 / (3.0 * math.sqrt(math.pi))
        volume = abs(np.linalg.det(cell))
        if height is not None:
            slab = SlabCorrection(volume, normal)
        if self.method == "pme":
            mesh = self.mesh_size(cell)
            return _Bound(mu, pref, alpha, volume=volume, self_coef=self_coef, slab=slab,
                          height=height, mesh=MeshInfluence(cell, mesh, self.spline_order, alpha))
        k = kvectors(cell, kcut)
        k2 = np.einsum("ij,ij->i", k, k)
        A = np.exp(-k2 / (4.0 * alpha * alpha)) / k2
        return _Bound(mu, pref, alpha, k, A, volume, self_coef, slab, height)

    def mesh_size(self, cell):
        """The mesh (K1, K2, K3) of ``method="pme"`` for the Ewald cell ``cell``:
        ``mesh`` as given, else :func:`~ase_spin.terms.dipolar_mesh.mesh_size`
        from α, k_c, ``accuracy`` and ``order``."""
        if self.mesh is not None:
            return self.mesh
        alpha, kcut = self.splitting()
        return mesh_size(cell, alpha, kcut, self.accuracy, self.spline_order)

    def prepare(self, positions, pairs, types, bound, *, virial=False, out=None,
                mean_with=None):
        """The operator at ``positions``: new arrays each time (an operator at
        q kept as another's ``mean_with`` is never overwritten). A slab's atoms
        must stay within the height of its cell across the plane (else its
        images would overlap)."""
        positions = np.ascontiguousarray(positions, dtype=float)
        if self.method == "direct":
            return DipolarOperator(bound, "direct", None, None, None, positions.copy(), None,
                                   mean_with)
        if bound.slab is not None and len(positions):
            across = positions @ bound.slab.n
            if np.ptp(across) >= bound.height:
                raise ValueError(f"Dipolar slab: the atoms spread {np.ptp(across):.6g} Å across "
                                 f"the slab, not less than the cell's height {bound.height:.6g} "
                                 "Å there: give a higher cell[2]")
        n = len(pairs)
        D = np.empty((n, 3))
        B = np.empty((n, 3))
        pair_geometry(threads.count(), positions, pairs.row, pairs.j, pairs.image, pairs.images,
                      self.rc**2, bound.alpha, D, B)
        recip = None
        if self.method == "ewald":
            recip = Reciprocal(positions, bound.k, bound.A, bound.volume, bound.alpha)
        elif self.method == "pme":
            recip = MeshReciprocal(positions, bound.mesh)
        return DipolarOperator(bound, self.method, pairs, D, B, None, recip, mean_with)

    def lammps(self, types):
        """``pair_style spin/dipole/cut rc``; for the Ewald sum ``spin/dipole/long
        rc`` with ``kspace_style ewald/dipole/spin accuracy``, ``kspace_modify
        gewald α kmax/ewald nx ny nz`` (the k-vectors within k_c along each box
        length; LAMMPS keeps those in the sphere of the largest of them); for
        the mesh (``"pme"``) ``kspace_style pppm/dipole/spin accuracy`` with
        ``kspace_modify gewald α mesh K1 K2 K3 order p`` (LAMMPS's P3M on the
        same mesh: the same sum to both methods' accuracies); for a slab
        ``slab factor``. LAMMPS's P3M takes orders up to
        :data:`LAMMPS_PPPM_MAX_ORDER`: a higher order is exported as that one,
        on the mesh :func:`~ase_spin.terms.dipolar_mesh.mesh_size` chooses
        for it at the same accuracy (``mesh`` as given, if given), with a
        warning naming both. LAMMPS's constant is fixed (:data:`DIPOLAR_LAMMPS`;
        785.15/784.15 of it in its k-space styles): another prefactor is
        warned about. The direct sum has no counterpart (NotImplementedError
        says why)."""
        if self.method == "direct":
            raise NotImplementedError(
                "Dipolar(method='direct') sums every pair of an open system, which no LAMMPS "
                "style does; use method='cut' with rc beyond the system's size "
                "(spin/dipole/cut), the same sum")
        pref = self._prefactor(types.conventions)
        if abs(pref / DIPOLAR_LAMMPS - 1.0) > 1e-12:
            warn_user(f"Dipolar's prefactor {pref:.10g} eV·Å³ is not LAMMPS's fixed "
                      f"{DIPOLAR_LAMMPS:.10g}: the deck's dipolar energies differ by "
                      f"{DIPOLAR_LAMMPS / pref - 1.0:+.3g} relative")
        rc = number_text(self.rc)
        if self.method == "cut":
            return [LammpsPair("spin/dipole/cut", rc, [("*", "*", rc)])]
        box = types.box
        style = "ewald/dipole/spin" if self.method == "ewald" else "pppm/dipole/spin"
        if box is None or np.any(box[np.tril_indices(3, -1)]):
            raise NotImplementedError(f"LAMMPS's {style} takes orthogonal boxes only; this "
                                      "cell is triclinic")
        alpha, kcut = self.splitting()
        slab = types.pbc is not None and tuple(types.pbc) == (True, True, False)
        factor = (3.0 if self.slab is None else self.slab) if slab else 1.0
        lengths = np.diag(box) * [1.0, 1.0, factor]
        if self.method == "ewald":
            kmax = [max(1, math.floor(kcut * length / (2.0 * math.pi))) for length in lengths]
            grid = f"kmax/ewald {kmax[0]} {kmax[1]} {kmax[2]}"
        else:
            grid = self._lammps_mesh(np.diag(lengths), alpha, kcut)
        modify = [f"gewald {number_text(alpha)} {grid}"]
        if slab:
            modify.append(f"slab {number_text(factor)}")
        return [LammpsPair("spin/dipole/long", rc, [("*", "*", rc)]),
                LammpsKspace(style, number_text(self.accuracy), modify)]

    def _lammps_mesh(self, cell, alpha, kcut):
        """``mesh K1 K2 K3 order p`` of ``pppm/dipole/spin`` for the Ewald cell."""
        order = self.spline_order
        if order <= LAMMPS_PPPM_MAX_ORDER:
            mesh = self.mesh_size(cell)
        else:
            ours = self.mesh_size(cell)
            order = LAMMPS_PPPM_MAX_ORDER
            mesh = (self.mesh if self.mesh is not None
                    else mesh_size(cell, alpha, kcut, self.accuracy, order))
            warn_user(f"Dipolar(method='pme') has B-splines of order {self.spline_order} on "
                      f"the mesh {'x'.join(map(str, ours))}; LAMMPS's pppm/dipole/spin takes "
                      f"orders up to {LAMMPS_PPPM_MAX_ORDER}: the deck has order {order} on "
                      f"the mesh {'x'.join(map(str, mesh))}"
                      + (" (as given: coarser interpolation than ours)" if self.mesh is not None
                         else " (chosen for the same accuracy)"))
        return f"mesh {mesh[0]} {mesh[1]} {mesh[2]} order {order}"
