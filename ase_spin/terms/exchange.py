"""Heisenberg exchange with a distance-dependent coupling J(r): the
:class:`Exchange` term, its :class:`ExchangeOperator` and how the operator
stores its pairs (:data:`PAIR_VECTORS_BELOW`). The couplings are in
:mod:`~ase_spin.terms.couplings`, the compiled kernels in
:mod:`~ase_spin.terms.exchange_geometry` (J(r) per pair),
:mod:`~ase_spin.terms.exchange_passes` (passes over prepared pairs) and
:mod:`~ase_spin.terms.exchange_fused` (pieces of the fused small-system step)."""

from __future__ import annotations

import numba as nb
import numpy as np

from .._jit import threads
from ..validate import flag, length
from .base import SpinOperator, SpinTerm, Want, mean_buffer
from .couplings import (FORM, FORM_OFF, FORM_PYTHON, P0, RC2, BetheSlater, Coupling, Cubic,
                        check_coupling, checked_values)
from .exchange_fused import (exchange_add_kept, exchange_couplings, exchange_forces,
                             exchange_forces_two, exchange_geometry)
from .exchange_geometry import direct_kernel, geometry_kernel, geometry_single
from .exchange_passes import (add_kept_pass, forces_two_pass, spin_pass_formed,
                              spin_pass_half_field, spin_pass_half_formed,
                              spin_pass_half_forces_field,
                              spin_pass_half_kernel, spin_pass_kernel, virial_pass)
from .lammps_form import LammpsPair, number_text
from .parameters import is_pair_mapping, pair_values, resolve_pairs
from .skeletons import linear_pair_field

# the couplings are part of this term's interface (Exchange(BetheSlater(...)));
# files saved by earlier versions name them as ase_spin.terms.exchange:BetheSlater
__all__ = ["Coupling", "BetheSlater", "Cubic", "Exchange", "ExchangeOperator",
           "PAIR_VECTORS_BELOW", "NO_ROWS", "copy_positions", "add_kept"]


#: Below this many atoms the exchange operators keep the vector G = J'(r) d/r of
#: every pair (three doubles); from it on, g = J'(r)/r (one double) and the
#: force passes recompute d from the operator's copy of the positions.
#: Recomputing d slows a force pass (more loads and products per pair), so g is
#: used only where memory per atom, not speed, is the limit (docs/benchmarks.md,
#: "Memory" and "Why each fast path exists"; benchmarks/memory_steps.py for the
#: peak, benchmarks/exchange_passes.py for the passes' cost): it saves 16 bytes
#: per pair, 2 × 144 bytes per atom of fcc Co (9 pairs each, operators at q and
#: q̃), from the size at which CollectivePRK also keeps fewer predictor
#: increments (collective.LARGE_SYSTEM). The results are the same bit for bit
#: (G = g·d is the same product either way).
PAIR_VECTORS_BELOW = 500_000


class ExchangeOperator(SpinOperator):
    """Exchange prepared at one set of positions (a :class:`SpinOperator`).

    For every pair k = (i → j) of ``pairs``: ``J[k] = J(r_ij)`` and either
    ``G[k] = J'(r_ij) d_ij / r_ij`` (three doubles per pair; systems below
    :data:`PAIR_VECTORS_BELOW` atoms) or ``g[k] = J'(r_ij) / r_ij`` (one
    double), with d_ij = r_j + S_ij − r_i; J = G = g = 0 unless r² < rc²
    (LAMMPS's rule). The other of G, g is empty. ``pos`` is the operator's own
    copy of the positions it was prepared at (with g, or when prepared with
    ``virial=True``; else None): the passes recompute d_ij from it (as
    :func:`~ase_spin.neighbors.separation` forms it, as the preparation did)
    for the virial, and with g for the forces, G = g d_ij — the same bits as G
    stored. The copy keeps the operator valid whatever happens to the caller's
    position array (integrators reuse their buffers). Spins do not enter: it
    stays valid while only the spins change.

    ``Jbar`` (when prepared with ``mean_with``) is ½[J + J_other] with the J of
    the operator at the other end of the step, on the same pairs: the couplings
    of the collective integrator's midpoint field, B̄_i = Σ_j J̄_ij W_j, filled in
    the same pass over the pairs.
    """

    linear = True
    forces_with_field = True
    merges_forces = True

    __slots__ = ("pairs", "J", "g", "G", "pos", "Jbar", "offset", "params", "stored")

    def __init__(self, pairs, J, g, G, pos, offset=0.0):
        self.pairs, self.J, self.g, self.G, self.pos = pairs, J, g, G, pos
        # the pair vectors G are kept (else g = J'(r)/r; G is then the empty NO_ROWS)
        self.stored = G is not NO_ROWS
        self.Jbar = None
        self.offset = offset
        # (rc², form, p0, p1, p2) of a one-species compiled coupling, else None
        self.params = None

    def compiled(self):
        """The fused step's pieces (see :meth:`SpinOperator.compiled`): on a
        half pair list, one species, a compiled coupling, the pair vectors G
        kept and no positions (no virial: the fused step gives none, and
        operators keeping g are those of systems far above its size)."""
        p = self.pairs
        if not p.half or self.params is None or not self.stored or self.pos is not None:
            return None
        if self.Jbar is None or len(self.Jbar) != len(self.J):
            self.Jbar = np.empty(len(self.J))
        # as few arrays as the pieces use: each one is unboxed at every call of
        # the fused step, a cost a small system's step feels (benchmarks/small_systems.py;
        # docs/benchmarks.md, "Why each fast path exists")
        # the geometry kernel is threaded above the tiny systems (threads.tiny);
        # the parameters as an array: a tuple of five floats cannot be passed
        # into the fused step's parallel branches (numba's parfor arguments)
        return (exchange_forces, exchange_geometry, exchange_couplings,
                (threads.count(), p.row, p.j, p.image, p.images, self.J, self.G, self.Jbar,
                 self.offset, np.array(self.params), threads.tiny()),
                (exchange_forces_two, exchange_add_kept))

    def linear_pairs(self, mean=False):
        """(pairs, c) with B_i = Σ_j c_k W_j over the pairs k = (i → j): the
        form the integrators' fused kernels take."""
        return self.pairs, (self.Jbar if mean else self.J)

    @property
    def site(self):
        if self.pairs.half:
            return None
        return _exchange_site, (self.pairs.row, self.pairs.j, self.J)

    def field(self, W, out, mean=False):
        J = self.Jbar if mean else self.J
        _field(self.pairs, J, W, out)

    def self_curvature(self, W):
        """:meth:`SpinOperator.self_curvature`: B_i = Σ_j J_ij s_j depends on s_i
        only through pairs of an atom with its own periodic image (a cell
        narrower than the cutoff): Σ over them of 2 J (twice on a half list,
        whose pair adds to both ends)."""
        p = self.pairs
        return (2.0 if p.half else 1.0) * _own_image_trace(p.row, p.j, self.J,
                                                           np.ascontiguousarray(W))

    def add(self, W, want, magnetic_forces, forces, energies):
        """Add B_i = Σ_j J_ij s_j, the exchange forces and energies for spins W
        (and the virial, from the d_ij recomputed at ``pos``).

        Returns (energy, virial in Voigt order xx yy zz yz xz xy, eV).
        """
        pairs = self.pairs
        if self.pos is None and want.virial:
            raise ValueError("this exchange operator was prepared without virial=True: "
                             "it keeps no positions to give the virial from")
        pos = self.pos if self.pos is not None else NO_ROWS
        # the G kernels give no virial: a pass of its own (rare: stress frames)
        in_pass = want.virial and not self.stored
        if self.stored:
            kernel = spin_pass_half_kernel if pairs.half else spin_pass_kernel
        else:
            kernel = spin_pass_half_formed if pairs.half else spin_pass_formed
        out = kernel(threads.count(), pairs.row, pairs.j, pairs.image, pairs.images, self.J,
                     self.g, self.G, pos, W, W, self.offset, magnetic_forces, forces,
                     energies, want.magnetic_forces, want.forces, want.energy, want.energies,
                     in_pass)
        virial = np.array(out[1:])
        if want.virial and self.stored:
            virial = np.array(virial_pass(threads.count(), pairs.row, pairs.j, pairs.image,
                                          pairs.images, self.G, pos, W, self.offset,
                                          pairs.half)[1:])
        return out[0], virial

    def forces_and_field(self, W, forces, u, field):
        """forces += the exchange forces at spins W, field += B(u) = Σ_j J_ij u_j
        for other spins u, in one pass over the pairs: the same bits as
        :meth:`add` (forces alone) and :meth:`field` called apart (a
        thermostat's field after its noise, with the step's last forces)."""
        pairs = self.pairs
        if not (pairs.half and self.stored):  # no twin for these forms: two passes
            self.add(W, Want(forces=True), NO_ROWS, forces, _NO_EX)
            self.field(u, field)
            return
        spin_pass_half_forces_field(threads.count(), pairs.row, pairs.j, pairs.image,
                                    pairs.images, self.J, self.g, self.G, NO_ROWS, W, u,
                                    self.offset, field, forces, _NO_EX, True, True, False,
                                    False, False)

    def pairs_with(self, there):
        """Whether :meth:`forces_here_and_there` takes this operator and
        ``there`` in one pass: both on one half list, with their pair vectors."""
        pairs, other = self.pairs, getattr(there, "pairs", None)
        return bool(pairs.half and self.stored and getattr(there, "stored", False)
                    and self.offset == there.offset
                    and (other is pairs or (other.row is pairs.row and other.j is pairs.j)))

    def forces_here_and_there(self, W, forces, there, u=None, field=None):
        """The exchange forces at spins W from this operator (the step's
        positions q) added into ``forces``, and those from ``there`` (the
        operator prepared at the step's other end q̃, on the same pairs) kept
        as per-thread partial sums, in one pass over the pairs; with ``u``,
        also field += B(u) = Σ_j J_ij u_j with ``there``'s couplings (a
        thermostat's field after its noise). Returns the partial sums (give
        them to :func:`add_kept` with the forces to add them to, which makes
        them the forces of :meth:`add` at ``there`` to the bit), or None where
        this storage has no such pass (nothing was computed)."""
        if not self.pairs_with(there):
            return None
        pairs = self.pairs
        n = len(pairs.row) - 1
        with_field = u is not None
        keep = np.empty((threads.count(), n, 9 if with_field else 6))
        forces_two_pass(threads.count(), pairs.row, pairs.j, self.G, there.G, W,
                        self.offset, forces, keep, there.J, u if with_field else NO_ROWS,
                        field if with_field else NO_ROWS)
        return keep

    @staticmethod
    def finish_forces(keep, base, out):
        """out = base + the partial sums ``keep`` of :meth:`forces_here_and_there`
        (:func:`add_kept`)."""
        return add_kept(keep, base, out)


def add_kept(keep, base, out):
    """out = base + the partial sums ``keep`` of :meth:`ExchangeOperator.forces_here_and_there`
    (threads in order: the rounding of a pass's own reduction onto ``base``)."""
    add_kept_pass(keep, base, out)
    return out


@nb.njit(cache=True)
def _own_image_trace(row, nbr, c, W):
    """Σ_t t·(∂B_i/∂s_i) t over the pairs k = (i → i) of an atom with its own
    image, for a field B_i ∋ c_k s_i from each: 2 c_k |s_i|² (the trace of
    c_k I over the two directions t ⊥ s_i). One pass, nothing allocated."""
    total = 0.0
    for i in range(len(row) - 1):
        for k in range(row[i], row[i + 1]):
            if nbr[k] == i:
                total += 2.0 * c[k] * (W[i, 0] * W[i, 0] + W[i, 1] * W[i, 1]
                                       + W[i, 2] * W[i, 2])
    return total


def _field(pairs, J, W, out):
    """out_i += Σ_j J_k W_j over a pair list (full: gather; half: scatter)."""
    kernel = spin_pass_half_field if pairs.half else spin_pass_kernel
    kernel(threads.count(), pairs.row, pairs.j, pairs.image, pairs.images, J, _NO_EX, NO_ROWS,
           NO_ROWS, W, W, 0.0, out, NO_ROWS, _NO_EX, True, False, False, False, False)


@nb.njit(cache=True, inline="always")
def _exchange_site(i, s, data):
    """B_i = Σ_j J_ij s_j from the spins as they are (full pair list)."""
    row, nbr, J = data
    return linear_pair_field(i, s, row, nbr, J)


class Exchange(SpinTerm):
    r"""Heisenberg exchange (LAMMPS ``pair_style spin/exchange``)

    .. math::

        E = -\sum_{i<j} J(r_{ij})\, (\mathbf s_i\cdot\mathbf s_j - c),
        \qquad c = 1 \text{ if offset else } 0,

    each pair once, unit directions s, J > 0 ferromagnetic, J = 0 for r > rc.
    It gives

    .. math::

        \mathbf F_i = \sum_j J'(r_{ij}) (\mathbf s_i\cdot\mathbf s_j - c)
                      \frac{\mathbf r_i - \mathbf r_j}{r_{ij}}, \qquad
        \mathbf B_i = -\frac{\partial E}{\partial \mathbf s_i} = \sum_j J(r_{ij}) \mathbf s_j .

    ``offset=True`` is LAMMPS's ``offset yes``: a ferromagnet then has zero
    exchange energy and pressure; magnetic forces are unchanged.

    ``coupling`` is a :class:`Coupling` (:class:`BetheSlater`, :class:`Cubic`,
    or any object with ``values(r) -> (J, J')``), or a mapping keyed by pairs of
    chemical symbols, ``{("Fe", "Fe"): BetheSlater(...), ("Fe", "Co"): ...}``
    (None switches a pair off). ``rc`` (Å) cuts J off hard; default: the
    couplings' own ``rc``.
    """

    name = "exchange"

    _parameters = {"coupling": "coupling", "rc": "rc", "offset": "offset"}

    def __init__(self, coupling, rc=None, offset=False):
        self.coupling = pair_values(coupling, "Exchange coupling", check_coupling)
        self.offset = flag(offset, "Exchange offset")
        couplings = (list(self.coupling.values()) if is_pair_mapping(self.coupling)
                     else [self.coupling])
        couplings = [c for c in couplings if c is not None]
        if rc is None:
            own = [getattr(c, "rc", None) for c in couplings]
            if not own or any(r is None for r in own):
                raise ValueError(
                    "Exchange needs rc: a coupling without a cutoff of its own "
                    "(such as BetheSlater) was given"
                )
            rc = max(length(r, "the coupling's rc") for r in own)
        self.rc = length(rc, "Exchange rc")
        self.cutoff = self.rc
        self._finish()

    def __repr__(self):
        return f"Exchange({self.coupling!r}, rc={self.rc}, offset={self.offset})"

    def bind(self, system):
        couplings = resolve_pairs(self.coupling, system.species.symbols, "Exchange coupling")
        nt = len(system.species.symbols)
        table = np.zeros((nt, nt, 5))
        for a in range(nt):
            for b in range(nt):
                c = couplings[a, b]
                if c is None:
                    continue
                form = getattr(c, "_form", FORM_PYTHON)
                table[a, b, RC2] = self.rc**2
                table[a, b, FORM] = form
                table[a, b, P0:] = getattr(c, "_params", (0.0, 0.0, 0.0))
        # Any coupling the kernels can't evaluate sends every pair through the
        # couplings' own vectorised values(r).
        python = (table[:, :, FORM] == FORM_PYTHON).any()
        return table, (couplings if python else None)

    def lammps(self, types):
        """``pair_style spin/exchange rc`` with ``pair_coeff I J exchange rc J1 J2
        J3 [offset yes]`` per pair of types: Bethe–Slater couplings only (LAMMPS
        has no other J(r) and no tabulated spin pair style). Pairs switched off
        (None) or with a non-magnetic species get J1 = 0: LAMMPS's exchange acts
        on the unit spins whatever their moment."""

        couplings = resolve_pairs(self.coupling, types.symbols, "Exchange coupling")
        coeffs = []
        for i, j, _, _ in types.pairs():
            c = couplings[i - 1, j - 1]
            if c is not None and type(c) is not BetheSlater:
                raise NotImplementedError(
                    f"the {type(c).__name__} coupling of pair {types.symbols[i - 1]}-"
                    f"{types.symbols[j - 1]}: LAMMPS's spin/exchange has only the "
                    "Bethe–Slater form J(r) = 4 J1 (r/J3)² [1 − J2 (r/J3)²] e^{−(r/J3)²}, and "
                    "no tabulated spin pair style")
            if c is None or not (types.magnetic[i - 1] and types.magnetic[j - 1]):
                args = "0.0 0.0 1.0"
            else:
                args = f"{number_text(c.J1)} {number_text(c.J2)} {number_text(c.J3)}"
            coeffs.append((i, j, f"exchange {number_text(self.rc)} {args}"
                           + (" offset yes" if self.offset else "")))
        return [LammpsPair("spin/exchange", number_text(self.rc), coeffs)]

    @property
    def energy_offset(self):
        return 1.0 if self.offset else 0.0

    def prepare(self, positions, pairs, types, bound, *, virial=False, out=None,
                mean_with=None):
        """:class:`ExchangeOperator` of ``pairs`` at ``positions``, with its own
        copy of them when it needs them later (in the g form, or for the
        virial: ``virial=True``).

        ``out``: an operator on the same pair list whose arrays are overwritten.
        ``mean_with``: an operator on the same pairs; fills ``Jbar``.
        """
        op = self._operator(pairs, out, len(positions), virial)
        if op.pos is not None:
            op.pos = positions = copy_positions(positions, op.pos)
        self._fill(op, positions, types, bound, mean_with)
        return op

    def _operator(self, pairs, out, natoms, virial):
        """``out`` if it is an operator on ``pairs`` of the same kind (its
        arrays to be overwritten), else a new one: with the pair vectors G below
        :data:`PAIR_VECTORS_BELOW` atoms (and a buffer for the positions if
        ``virial``), else with g and that buffer."""
        stored = natoms < PAIR_VECTORS_BELOW
        keep = virial or not stored
        if (out is not None and out.pairs is pairs and out.stored == stored
                and (out.pos is not None or not keep)):
            out.offset = self.energy_offset
            return out
        if out is not None:  # its buffers are given up: freed before the new ones
            out.J = out.g = out.G = out.pos = out.Jbar = None
        n = len(pairs)
        if stored:
            g, G = _NO_EX, np.empty((n, 3))
        else:
            g, G = np.empty(n), NO_ROWS
        return ExchangeOperator(pairs, np.empty(n), g, G,
                                np.empty((natoms, 3)) if keep else None, self.energy_offset)

    def _fill(self, op, positions, types, bound, mean_with):
        """J, G or g (and Jbar) of ``op`` at ``positions``: J_k = J(r_k),
        G_k = J'(r_k) d_k/r_k or g_k = J'(r_k)/r_k, J̄_k = ½(J_k + J_k of
        ``mean_with``)."""
        table, couplings = bound
        pairs = op.pairs
        n = len(pairs)
        kept = op.Jbar if op.Jbar is not None and len(op.Jbar) == n else None
        op.Jbar = mean_buffer(mean_with, pairs, kept, n)
        if mean_with is not None:
            other, Jbar = mean_with.J, op.Jbar
        else:
            other = Jbar = _NO_EX
        if couplings is None:
            if table.shape[0] == 1:
                # one species: parameters as scalars, no per-pair table lookups
                op.params = tuple(table[0, 0])
                geometry_single(positions, pairs.row, pairs.j, pairs.image, pairs.images,
                                *op.params, op.J, op.g, op.G, other, Jbar)
            else:
                op.params = None
                geometry_kernel(positions, pairs.row, pairs.j, pairs.image, pairs.images,
                                types, table, op.J, op.g, op.G, other, Jbar)
            return
        op.params = None
        i = pairs.i
        # d = (r_j − r_i) + S in separation()'s order of operations: the passes
        # recompute it from op.pos bit for bit
        d = (positions[pairs.j] - positions[i]) + pairs.shift
        r2 = np.einsum("ij,ij->i", d, d)
        r = np.sqrt(r2)
        J = np.zeros(n)
        dJ = np.zeros(n)
        ti, tj = types[i], types[pairs.j]
        for a, b in zip(*np.nonzero(table[:, :, FORM] != FORM_OFF)):
            sel = (ti == a) & (tj == b) & (r2 < table[a, b, RC2])
            J[sel], dJ[sel] = checked_values(couplings[a, b], r[sel])
        op.J[:] = J
        g = dJ / np.where(r > 0.0, r, 1.0)
        if op.stored:
            np.multiply(g[:, None], d, out=op.G)
        else:
            op.g[:] = g
        if op.Jbar is not None:
            np.multiply(0.5, mean_with.J + J, out=op.Jbar)

    def compute(self, positions, pairs, types, bound, spins, magnetic_forces, forces,
                energies, want):
        """Everything ``want`` asks for at ``positions`` and ``spins`` in one pass
        over the half list (no pair geometry kept). Returns (energy, virial)."""
        table, couplings = bound
        if couplings is not None:
            op = self.prepare(positions, pairs, types, bound, virial=want.virial)
            return op.add(spins, want, magnetic_forces, forces, energies)
        out = direct_kernel(threads.all_threads(), positions, pairs.row, pairs.j,
                            pairs.image, pairs.images, types, table, spins,
                            self.energy_offset, magnetic_forces, forces, energies,
                            want.magnetic_forces, want.forces, want.energy, want.energies,
                            want.virial)
        return out[0], out[1:]


NO_ROWS = np.zeros((0, 3))
_NO_EX = np.zeros(0)


def copy_positions(positions, buffer):
    """``positions`` copied into ``buffer`` (an (N, 3) float64 array, reused
    when its shape fits, else a new one): the operator's own copy, so that
    buffers the integrators reuse or users edit cannot change an operator
    after it was prepared."""
    if buffer is None or buffer.shape != np.shape(positions):
        buffer = np.empty((len(positions), 3))
    np.copyto(buffer, positions)
    return buffer
