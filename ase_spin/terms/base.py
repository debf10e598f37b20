"""The contract of the Hamiltonian's terms: what an evaluation should produce
(:class:`Want`), what a term binds to (:class:`System`, :class:`Species`),
the term and spin-operator interfaces (:class:`Term`, :class:`SpinTerm`,
:class:`SpinOperator`), and the two families built on compiled skeletons:
single-site terms (:class:`SingleSiteTerm`, :class:`SiteOperator`) and pair
spin terms (:class:`PairSpinTerm`, :class:`PairOperator`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._jit import threads
from ..conventions import PHYSICAL, Conventions
from ..neighbors import greedy_colouring
from .parameters import Parameterised
from .skeletons import compile_pair_pass, compile_site_pass

__all__ = ["Want", "Term", "SpinTerm", "SpinOperator", "PairSpinTerm", "PairOperator", "System",
           "mean_buffer",
           "Species", "SingleSiteTerm", "SiteOperator", "numeric_self_curvature"]


@dataclass(frozen=True)
class Want:
    """What an evaluation should produce; nothing else is computed."""

    energy: bool = False
    energies: bool = False
    forces: bool = False
    magnetic_forces: bool = False
    virial: bool = False


@dataclass(frozen=True)
class Species:
    """Chemical species of a bound system: ``symbols[types[i]]`` is atom i's symbol."""

    symbols: tuple
    types: np.ndarray

    @classmethod
    def from_symbols(cls, chemical_symbols):
        symbols, types = np.unique(np.asarray(chemical_symbols, dtype=str), return_inverse=True)
        return cls(tuple(str(s) for s in symbols), types.astype(np.int64))


@dataclass(frozen=True)
class System:
    """What a term binds to: the system's species, which atoms are magnetic and
    their moment magnitudes μ_i (μB), its cell and periodicity, and the
    Hamiltonian's :class:`~ase_spin.conventions.Conventions`."""

    species: Species
    moments: np.ndarray
    cell: np.ndarray
    pbc: np.ndarray
    conventions: Conventions = PHYSICAL

    @property
    def types(self):
        return self.species.types

    @property
    def magnetic(self):
        return self.moments > 0.0

    @property
    def natoms(self):
        return len(self.moments)


class Term(Parameterised):
    """A term of the Hamiltonian.

    Subclasses define ``name`` (the key in ``calc.results['energy_terms']``),
    ``spin_dependent``, ``neighbor_list`` (the pair list the term needs:
    ``"half"`` — each pair once —, or None for a term without pairs) and
    ``cutoff`` (Å, its range), and implement :meth:`bind`. Their parameters may
    be reassigned after construction (see
    :class:`~ase_spin.terms.parameters.Parameterised`).

    A lattice (spin-independent) term implements
    ``compute(positions, pairs, types, table, forces, energies, want)``: it adds
    forces and per-atom energies into the given arrays and returns (energy,
    virial in Voigt order, eV).
    """

    name = "term"
    spin_dependent = False
    neighbor_list = "half"
    cutoff = 0.0

    def bind(self, system):
        """The term's parameters made concrete for a :class:`System` (a table
        per species pair, per-atom fields, ...): what its kernels take. Called
        again whenever the system's cell, periodicity or moments change."""
        raise NotImplementedError

    def compiled_lattice(self, pairs, types, table):
        """Optional, for lattice terms: this term's forces as a compiled piece
        of the integrators' fused step for small systems (:mod:`ase_spin.md.fused`):
        ``(f, data)`` with ``f(positions, data, forces, serial)`` a numba
        function adding bitwise the forces :meth:`compute` adds with
        ``Want(forces=True)``, with the twin :meth:`compute` calls at this size
        (serial where :func:`ase_spin._jit.threads.tiny`, else as the kernel's
        ``always`` says; chosen at run time from a flag in ``data``, so that one
        compiled step serves every small size), or the serial twin where
        ``serial`` (the step makes them on one thread beside its midpoint
        solve). None (the default): the integrators take their general path."""
        return None

    def lammps(self, types):
        """This term as LAMMPS input, for :func:`ase_spin.interop.lammps.write_lammps`: a
        list of :class:`~ase_spin.terms.lammps_form.LammpsPair` (a pair style, its
        ``pair_coeff`` lines and ``pair_modify`` options) and
        :class:`~ase_spin.terms.lammps_form.LammpsFix` (e.g. ``precession/spin``) for the
        atom types ``types`` (:class:`~ase_spin.interop.lammps.LammpsTypes`: symbols by
        type, which are magnetic, the rotation into LAMMPS's frame). A term
        LAMMPS cannot express raises NotImplementedError saying why."""
        raise NotImplementedError(f"LAMMPS has no counterpart of {type(self).__name__}")

    def __repr__(self):
        return f"{type(self).__name__}(...)"


class SpinOperator:
    """A spin term prepared at given positions: an operator on spins.

    What the integrators and the calculator ask of every spin-dependent term:

    - :meth:`field` — add the magnetic forces B(W) = −∂E/∂s at spins W (eV);
      with ``mean=True``, the midpoint field ½[B(q, W) + B(q̃, W)] of an
      operator prepared at q̃ with ``mean_with`` the one at q (the collective
      step's B̄);
    - :meth:`add` — the energy, lattice forces, per-atom energies, virial and
      magnetic forces at spins W;
    - ``site`` — for the sequential sweeps of the splitting integrator, a
      compiled function ``f(i, s, data) -> (Bx, By, Bz)`` giving spin i's field
      from the spins as they are, and its ``data`` tuple (None: not offered;
      then ``site_unavailable`` may say why, a sentence the integrator's
      refusal quotes: a long-range field whose one spin costs the whole).

    Capabilities an operator may declare (class attributes, False here), each
    with the methods it then provides; integrators ask for the capability,
    never for a concrete term:

    - ``linear`` (a field linear in the spins, B = C s: exchange):
      ``linear_pairs(mean)`` — (pairs, c) with B_i = Σ_k c_k s_j, what the
      compiled midpoint solvers and the thermostat's forms take;
    - ``forces_with_field``: ``forces_and_field(W, forces, u, field)`` — the
      lattice forces at W and the field C u at other spins u in one pass (the
      thermostat's fields after its noise, with a step's last forces);
    - ``merges_forces``: ``pairs_with(there)``, ``forces_here_and_there(W,
      forces, there, u=None, field=None)`` — the lattice forces at W of this
      operator and of ``there`` (prepared at the step's other end, on the same
      pairs: kept as per-thread partial sums), and optionally C u, in one pass
      (a step's forces at q with its end forces) — and ``finish_forces(keep,
      base, out)``, which adds those partial sums onto ``base``.
    - ``expensive_field``: one evaluation of :meth:`field` costs as much as
      many passes over the pairs of a short-range term (a long-range sum):
      the collective midpoint solve holds it fixed while the other terms'
      fields converge, and evaluates it again only once they have
      (:func:`~ase_spin.md.policy.held_operators`).

    Non-magnetic atoms get zero field.

    And one method with a default, for the spin temperature:
    :meth:`self_curvature` — how each spin's field depends on that spin
    itself (0 here: true of every term linear in each spin, as exchange, DMI,
    a field; single-site terms and the biquadratic exchange give theirs).
    """

    site = None
    site_unavailable = None
    linear = False
    forces_with_field = False
    merges_forces = False
    expensive_field = False

    def compiled(self):
        """Optional: this operator as compiled pieces of the integrators' fused
        step for small systems (:mod:`ase_spin.md.fused`), ``(forces, geometry,
        couplings, data)``, numba functions that do bitwise what the methods do,
        with the twins (serial or threaded) the methods call at this size:

        - ``forces(W, data, F)``: add the lattice forces at spins W (:meth:`add`
          with ``Want(forces=True)``);
        - ``geometry(positions, data, other, serial)``: refill ``data`` at new
          positions, with the midpoint quantities from the operator of ``other``
          (the term's ``prepare(positions, out=this, mean_with=that)``), with the
          serial twin where ``serial`` (on one thread beside the lattice forces);
        - ``couplings(data) -> (row, nbr, c)``: the midpoint field as
          B̄_i = Σ_k c_k W_j over a half pair list (``linear_pairs(mean=True)``).

        Optionally a fifth element ``(forces_two, add_kept)``:
        ``forces_two(W, data, there, F) -> keep`` adds the forces as ``forces``
        and returns those of the operator with data ``there`` (the other end of
        the step, on the same pairs) as per-thread partial sums, which
        ``add_kept(keep, base, out)`` adds onto ``base`` as a pass of their own
        would (``forces_here_and_there``).

        None (the default): the integrators take their general path."""
        return None

    def field(self, W, out, mean=False):
        raise NotImplementedError

    def add(self, W, want, magnetic_forces, forces, energies):
        """Add what ``want`` asks for at unit spins W; returns (energy, virial)."""
        raise NotImplementedError

    def self_curvature(self, W):
        r"""Σ_i Σ_t t·(∂B_i/∂s_i) t (eV) at unit spins W, t over two orthonormal
        directions perpendicular to s_i: the part of the Laplacian of the energy
        on the spheres that :math:`2\sum_i \mathbf s_i\cdot\mathbf B_i` leaves out,
        :math:`\nabla^2 E = \sum_i (2\,\mathbf s_i\cdot\mathbf B_i
        - \sum_t \mathbf t\cdot\partial\mathbf B_i/\partial\mathbf s_i\,\mathbf t)`
        (the spin temperature's denominator, ``get_spin_temperature``). Zero
        when B_i does not depend on s_i (terms linear in each spin: exchange,
        DMI, a field), the default; an operator whose field on a spin depends
        on that spin (an anisotropy, a biquadratic coupling) gives its own."""
        return 0.0


class SpinTerm(Term):
    """A spin-dependent term.

    Implements :meth:`prepare`, returning a :class:`SpinOperator` for given
    positions. :meth:`compute` (one direct evaluation, what the calculator
    calls) defaults to preparing an operator and asking it; pair terms
    override it with a single fused pass.
    """

    spin_dependent = True

    def prepare(self, positions, pairs, types, table, *, virial=False, out=None,
                mean_with=None):
        """The operator at ``positions`` (``pairs``: the term's pair list, or
        None if it needs none). ``virial``: it must be able to give the virial.
        ``out``: an earlier operator of this term whose buffers may be reused.
        ``mean_with``: the operator at the other end of a step (same pair
        list), for ``field(..., mean=True)``."""
        raise NotImplementedError

    def compute(self, positions, pairs, types, table, spins, magnetic_forces, forces,
                energies, want):
        """Everything ``want`` asks for at ``positions`` and ``spins``, added into
        the arrays given; returns (energy, virial)."""
        op = self.prepare(positions, pairs, types, table, virial=want.virial)
        return op.add(spins, want, magnetic_forces, forces, energies)


_NO_FIELD = np.zeros((0, 3))
_NO_SITE_ENERGIES = np.zeros(0)


class SiteOperator(SpinOperator):
    """The operator of a single-site term: B_i and E_i depend on s_i alone
    (and on per-atom data fixed at binding), not on positions; no lattice
    forces, no virial. The same object serves q, q̃ and their midpoint."""

    __slots__ = ("data", "_pass", "site")

    def __init__(self, field, data, site_pass):
        self.data = data
        self._pass = site_pass
        self.site = (field, data)

    def field(self, W, out, mean=False):
        self._pass(W, self.data, out, _NO_SITE_ENERGIES, True, False)

    def add(self, W, want, magnetic_forces, forces, energies):
        e = self._pass(W, self.data, magnetic_forces, energies, want.magnetic_forces,
                       want.energies)
        return e, np.zeros(6)

    def self_curvature(self, W):
        """:meth:`SpinOperator.self_curvature` of any single-site term, from its
        field alone: B_i depends on s_i only, so every spin is turned at once,
        by ±ε along each of two tangent directions on its sphere (great
        circles), and Σ_i t·ΔB_i/(2ε) is read off: central differences, exact
        for a field linear in s (uniaxial), error O(ε²) ≈ 10⁻⁸ relative
        otherwise."""
        W = np.asarray(W, dtype=float)
        magnetic = np.any(W != 0.0, axis=1)
        if not magnetic.any():
            return 0.0
        total = 0.0
        c, sn = np.cos(_TURN), np.sin(_TURN)
        plus, minus = np.empty_like(W), np.empty_like(W)
        Bp, Bm = np.empty_like(W), np.empty_like(W)
        for t in tangent_directions(W):
            np.add(c * W, sn * t, out=plus)
            np.subtract(c * W, sn * t, out=minus)
            Bp[:] = 0.0
            Bm[:] = 0.0
            self.field(plus, Bp)
            self.field(minus, Bm)
            total += float(np.einsum("ij,ij->", t, Bp - Bm)) / (2.0 * sn)
        return total


#: the angle (rad) of the central differences of :meth:`SiteOperator.self_curvature`
_TURN = 1e-4


def mean_buffer(mean_with, pairs, kept=None, shape=None):
    """The midpoint array a pair term's ``prepare`` fills: None without
    ``mean_with``; else ``kept`` (the array of the operator being refilled,
    if it has one) or a new array of ``shape`` (or None when ``shape`` is
    None: the term averages without an array of its own). ``mean_with`` must
    be prepared on the same pair list: the midpoint data are averages of the
    step's two ends pair by pair (for a pair term, x̄_k = ½[x_k(q) + x_k(q̃)])."""
    if mean_with is None:
        return None
    if mean_with.pairs is not pairs:
        raise ValueError("mean_with must be an operator on the same pair list")
    if kept is not None or shape is None:
        return kept
    return np.empty(shape)


def numeric_self_curvature(op, W):
    """:meth:`SpinOperator.self_curvature` of a pair operator whose field on a
    spin depends on that spin (a pair term non-linear in each spin, or pairs
    of an atom with its own image), from its field alone: the atoms are
    coloured so that no pair joins two of one colour (a greedy colouring of
    the pairs, both directions), and the spins of one colour at a time are
    turned by ±ε along two tangent directions; Σ_i t·ΔB_i/(2ε) over that
    colour then holds only ∂B_i/∂s_i (pairs of an atom with its own image
    turn with it, as they should). Central differences: exact for a field
    linear in s_i, error O(ε²) otherwise. For the spin temperature, computed
    at log intervals: 4 field passes per colour."""
    W = np.asarray(W, dtype=float)
    p = op.pairs
    i, j = p.i, p.j
    both_i = np.concatenate([i, j]) if p.half else i
    both_j = np.concatenate([j, i]) if p.half else j
    order = np.argsort(both_i, kind="stable")
    row = np.concatenate([[0], np.cumsum(np.bincount(both_i, minlength=len(W)))])
    atoms, starts = greedy_colouring(row.astype(np.int64), both_j[order].astype(np.int64))
    magnetic = np.any(W != 0.0, axis=1)
    c, sn = np.cos(_TURN), np.sin(_TURN)
    total = 0.0
    Bp, Bm = np.empty_like(W), np.empty_like(W)
    for t in tangent_directions(W):
        for colour in range(len(starts) - 1):
            sel = atoms[starts[colour]:starts[colour + 1]]
            sel = sel[magnetic[sel]]
            if not len(sel):
                continue
            plus, minus = W.copy(), W.copy()
            plus[sel] = c * W[sel] + sn * t[sel]
            minus[sel] = c * W[sel] - sn * t[sel]
            Bp[:] = 0.0
            Bm[:] = 0.0
            op.field(plus, Bp)
            op.field(minus, Bm)
            total += float(np.einsum("ij,ij->", t[sel], Bp[sel] - Bm[sel])) / (2.0 * sn)
    return total


def tangent_directions(W):
    """Two (N, 3) arrays of unit vectors t1, t2 with (W_i/|W_i|, t1_i, t2_i)
    orthonormal for each row; zero rows where W_i is zero (non-magnetic
    atoms)."""
    W = np.asarray(W, dtype=float)
    norm = np.linalg.norm(W, axis=1)
    magnetic = norm > 0.0
    u = np.zeros_like(W)
    u[magnetic] = W[magnetic] / norm[magnetic, None]
    # the coordinate axis least aligned with u, made perpendicular to it
    axis = np.zeros_like(W)
    axis[np.arange(len(W)), np.argmin(np.abs(u), axis=1)] = 1.0
    t1 = axis - np.einsum("ij,ij->i", axis, u)[:, None] * u
    t1 /= np.linalg.norm(t1, axis=1)[:, None]
    t2 = np.cross(u, t1)
    t1[~magnetic] = 0.0
    t2[~magnetic] = 0.0
    return t1, t2


class SingleSiteTerm(SpinTerm):
    """A spin term acting on each spin alone (fields, anisotropies): no pairs.

    A subclass sets ``site_field`` and ``site_energy``, compiled
    (``numba.njit(inline="always")``) functions of ``(i, s, data)`` giving B_i
    = −∂E_i/∂s_i and E_i for unit spins s, and implements :meth:`bind`
    returning ``data``: a tuple of per-atom arrays (zero on non-magnetic atoms)
    built from its parameters and the system's moments. That is all: the
    passes over atoms, the operator and the integrators' use of it follow.
    """

    neighbor_list = None
    site_field = None
    site_energy = None

    @classmethod
    def _compiled_pass(cls):
        if "_site_pass" not in cls.__dict__:
            cls._site_pass = compile_site_pass(cls.site_field, cls.site_energy, cls.__name__)
        return cls._site_pass

    def prepare(self, positions, pairs, types, table, *, virial=False, out=None,
                mean_with=None):
        if out is not None and out.data is table:
            return out
        return SiteOperator(type(self).site_field, table, self._compiled_pass())


class PairSpinTerm(SpinTerm):
    """A spin term that is a sum over pairs, built on the pair pass of
    :func:`~ase_spin.terms.skeletons.compile_pair_pass`.

    A subclass sets ``pair_field`` and ``pair_energy`` (compiled functions, see
    :func:`compile_pair_pass`) and ``pair_site`` (``f(i, s, (row, nbr,
    *data))``: spin i's field for the sequential sweeps), and implements
    :meth:`prepare` filling its per-pair data and returning
    :meth:`operator`. The passes over half or full pair lists follow.
    """

    neighbor_list = "half"
    pair_field = None
    pair_energy = None
    pair_site = None

    @classmethod
    def _compiled_pass(cls):
        if "_pair_pass" not in cls.__dict__:
            cls._pair_pass = compile_pair_pass(cls.pair_field, cls.pair_energy, cls.__name__)
        return cls._pair_pass

    def operator(self, pairs, data, mean_data):
        """The :class:`PairOperator` of per-pair ``data`` (and its midpoint
        version ``mean_data``, or None) on ``pairs``."""
        return PairOperator(pairs, data, mean_data, self._compiled_pass(),
                            type(self).pair_site)


class PairOperator(SpinOperator):
    """The operator of a pair spin term built on the compiled pair pass: per-pair
    data prepared at one set of positions (``data``; ``mean_data``, the same
    tuple with the midpoint quantities where the field reads them) and the
    term's compiled pass."""

    __slots__ = ("pairs", "data", "mean_data", "_pass", "site_function", "extra")

    def __init__(self, pairs, data, mean_data, pair_pass, site_function=None):
        self.pairs = pairs
        self.data = data
        self.mean_data = mean_data
        self._pass = pair_pass
        self.site_function = site_function

    @property
    def site(self):
        if self.pairs.half or self.site_function is None:
            return None
        return self.site_function, (self.pairs.row, self.pairs.j, *self.data)

    def field(self, W, out, mean=False):
        data = self.mean_data if mean else self.data
        p = self.pairs
        self._pass(threads.count(), p.row, p.j, p.half, W, data, out, _NO_FIELD,
                   _NO_SITE_ENERGIES, True, False, False, False, False)

    def add(self, W, want, magnetic_forces, forces, energies):
        p = self.pairs
        out = self._pass(threads.count(), p.row, p.j, p.half, W, self.data, magnetic_forces,
                         forces, energies, want.magnetic_forces, want.forces, want.energy,
                         want.energies, want.virial)
        return out[0], np.array(out[1:])
