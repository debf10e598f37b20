"""Heisenberg exchange with a distance-dependent coupling J(r)."""

from __future__ import annotations

import numba as nb
import numpy as np

from .._jit import threads
from .._jit.cloning import kernel_twin
from .._jit.reductions import (balanced_chunks, reduce_threads, reduce_threads_serial,
                               sum_over_threads)
from .._jit.threads import threaded
from ..neighbors import separation
from ..validate import flag, length, real_scalar
from .base import (Parameterised, SpinOperator, SpinTerm, Want, is_pair_mapping, linear_pair_field,
                   pair_values, resolve_pairs)
from .lammps_form import LammpsPair, number_text

__all__ = ["Coupling", "BetheSlater", "Cubic", "Exchange", "ExchangeOperator"]

# Coupling forms the compiled kernels evaluate directly; anything else is
# evaluated by its own (vectorised) ``values(r)``.
_OFF, _BETHE_SLATER, _CUBIC, _PYTHON = 0, 1, 2, 3
# Columns of the per-species-pair table.
_RC2, _FORM, _P0, _P1, _P2 = range(5)


class Coupling(Parameterised):
    """A distance-dependent exchange coupling J(r) (eV).

    Subclasses implement :meth:`values` returning ``(J(r), J'(r))`` for an array
    of distances; any object with such a method (and an ``rc`` attribute, the
    distance beyond which J vanishes, or None) plugs into :class:`Exchange`.
    Parameters of the couplings here may be reassigned (``bs.J1 = ...``); the
    terms and integrators using them notice. Other objects are taken to be
    fixed once given to a term.
    """

    rc = None
    _form = _PYTHON
    _params = (0.0, 0.0, 0.0)

    def values(self, r):
        raise NotImplementedError

    def __call__(self, r):
        return self.values(np.asarray(r, dtype=float))[0]

    def derivative(self, r):
        return self.values(np.asarray(r, dtype=float))[1]


class BetheSlater(Coupling):
    r"""The Bethe–Slater form of LAMMPS ``pair_style spin/exchange``:

    .. math::

        J(r) = 4 J_1 \left(\frac{r}{J_3}\right)^2
               \left[1 - J_2 \left(\frac{r}{J_3}\right)^2\right] e^{-(r/J_3)^2},

        J'(r) = 8 J_1 \frac{r}{J_3^2} e^{-(r/J_3)^2}
               \left[1 - \left(\frac{r}{J_3}\right)^2
               - J_2 \left(\frac{r}{J_3}\right)^2 \left(2 - \left(\frac{r}{J_3}\right)^2\right)\right].

    J1 in eV, J2 dimensionless, J3 in Å. It has no cutoff of its own: the
    :class:`Exchange` term's ``rc`` cuts it off hard (J(rc) ≠ 0 in general).
    """

    _form = _BETHE_SLATER

    _parameters = {"J1": "J1", "J2": "J2", "J3": "J3"}

    def __init__(self, J1, J2, J3):
        self.J1 = real_scalar(J1, "BetheSlater J1")
        self.J2 = real_scalar(J2, "BetheSlater J2")
        self.J3 = length(J3, "BetheSlater J3")
        # kernel parameters: J1, J2 and 1/J3² (a product per pair, not a division)
        self._params = (self.J1, self.J2, 1.0 / self.J3**2)
        self._finish()

    def values(self, r):
        x = (r / self.J3) ** 2
        ex = np.exp(-x)
        J = 4.0 * self.J1 * x * (1.0 - self.J2 * x) * ex
        dJ = 8.0 * self.J1 * r / self.J3**2 * ex * (1.0 - x - self.J2 * x * (2.0 - x))
        return J, dJ

    def __repr__(self):
        return f"BetheSlater(J1={self.J1}, J2={self.J2}, J3={self.J3})"


class Cubic(Coupling):
    r"""The cubic form of Ma, Woo and Dudarev used in the paper:

    .. math::

        J(r) = J_0 (1 - r/r_c)^3 \,\Theta(r_c - r), \qquad
        J'(r) = -\frac{3 J_0}{r_c} (1 - r/r_c)^2 \,\Theta(r_c - r).

    J and J' both vanish at r_c, so this coupling needs no cutoff of its own.
    """

    _form = _CUBIC

    _parameters = {"J0": "J0", "rc": "rc"}

    def __init__(self, J0, rc):
        self.J0 = real_scalar(J0, "Cubic J0")
        self.rc = length(rc, "Cubic rc")
        self._params = (self.J0, self.rc, 1.0 / self.rc)
        self._finish()

    def values(self, r):
        x = np.where(r < self.rc, 1.0 - r / self.rc, 0.0)
        return self.J0 * x**3, -3.0 * self.J0 / self.rc * x**2

    def __repr__(self):
        return f"Cubic(J0={self.J0}, rc={self.rc})"


def _user_values(coupling, r):
    """(J, J') of a coupling evaluated by its own ``values(r)``, checked: a NaN
    here would otherwise reach the spins of every atom within a step."""
    J, dJ = coupling.values(r)
    J = np.asarray(J, dtype=float)
    dJ = np.asarray(dJ, dtype=float)
    if J.shape != r.shape or dJ.shape != r.shape:
        raise ValueError(f"coupling {coupling!r}: values(r) must return two arrays shaped "
                         f"like r {r.shape}, got {J.shape} and {dJ.shape}")
    bad = ~(np.isfinite(J) & np.isfinite(dJ))
    if bad.any():
        k = int(np.argmax(bad))
        raise ValueError(f"coupling {coupling!r} returned non-finite values at r = {float(r[k])} Å: "
                         f"J = {J[k]}, J' = {dJ[k]}")
    return J, dJ


def _check_coupling(c, what):
    if c is not None and not callable(getattr(c, "values", None)):
        raise TypeError(f"{what}: a coupling needs a values(r) -> (J, dJ) method; got {c!r}")
    return c


#: Below this many atoms the exchange operators keep the vector G = J'(r) d/r of
#: every pair (three doubles); from it on, g = J'(r)/r (one double) and the
#: force passes recompute d from the operator's copy of the positions. Recomputing
#: d makes a force pass 8–31 % slower at 500–10⁶ atoms (more loads and products
#: per pair; benchmarks/exchange_passes.py); g saves 16 bytes per pair, 2 × 144 bytes per
#: atom of fcc Co (9 pairs each, operators at q and q̃), where memory per atom,
#: not speed, is the limit: from the size at which CollectivePRK also keeps
#: fewer predictor increments (collective.LARGE_SYSTEM). The results are the
#: same bit for bit (G = g·d is the same product either way).
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
        # the geometry kernel is threaded above the tiny systems (threads.tiny)
        geometry = _exchange_geometry if threads.tiny() else _exchange_geometry_threaded
        # as few arrays as the pieces use: each one is unboxed at every call of
        # the fused step (two more cost the 30-atom chain ~0.7 µs per step)
        return (_exchange_forces, geometry, _exchange_couplings,
                (threads.count(), p.row, p.j, p.image, p.images, self.J, self.G, self.Jbar,
                 self.offset, self.params), (_exchange_forces_two, _exchange_add_kept))

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
            kernel = _spin_pass_half_kernel if pairs.half else _spin_pass_kernel
            if pairs.half and (want.magnetic_forces, want.forces, want.energy, want.energies,
                               in_pass) == _FORCES_ONLY:
                kernel = _spin_pass_half_forces
        else:
            kernel = _spin_pass_half_formed if pairs.half else _spin_pass_formed
        out = kernel(threads.count(), pairs.row, pairs.j, pairs.image, pairs.images, self.J,
                     self.g, self.G, pos, W, W, self.offset, magnetic_forces, forces,
                     energies, want.magnetic_forces, want.forces, want.energy, want.energies,
                     in_pass)
        virial = np.array(out[1:])
        if want.virial and self.stored:
            virial = np.array(_virial_pass(threads.count(), pairs.row, pairs.j, pairs.image,
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
        _spin_pass_half_forces_field(threads.count(), pairs.row, pairs.j, pairs.image,
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
        _forces_two_pass(threads.count(), pairs.row, pairs.j, self.G, there.G, W,
                         self.offset, forces, keep, there.J, u if with_field else NO_ROWS,
                         field if with_field else NO_ROWS)
        return keep


def add_kept(keep, base, out):
    """out = base + the partial sums ``keep`` of :meth:`ExchangeOperator.forces_here_and_there`
    (threads in order: the rounding of a pass's own reduction onto ``base``)."""
    _add_kept(keep, base, out)
    return out


def _field(pairs, J, W, out):
    """out_i += Σ_j J_k W_j over a pair list (full: gather; half: scatter)."""
    kernel = _spin_pass_half_field if pairs.half else _spin_pass_kernel
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
        self.coupling = pair_values(coupling, "Exchange coupling", _check_coupling)
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
                form = getattr(c, "_form", _PYTHON)
                table[a, b, _RC2] = self.rc**2
                table[a, b, _FORM] = form
                table[a, b, _P0:] = getattr(c, "_params", (0.0, 0.0, 0.0))
        # Any coupling the kernels can't evaluate sends every pair through the
        # couplings' own vectorised values(r).
        python = (table[:, :, _FORM] == _PYTHON).any()
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
        if mean_with is not None:
            if mean_with.pairs is not pairs:
                raise ValueError("mean_with must be an operator on the same pair list")
            if op.Jbar is None or len(op.Jbar) != n:
                op.Jbar = np.empty(n)
            other, Jbar = mean_with.J, op.Jbar
        else:
            op.Jbar = None
            other = Jbar = _NO_EX
        if couplings is None:
            if table.shape[0] == 1:
                # one species: parameters as scalars, no per-pair table lookups
                op.params = tuple(table[0, 0])
                _geometry_single(positions, pairs.row, pairs.j, pairs.image, pairs.images,
                                 *op.params, op.J, op.g, op.G, other, Jbar)
            else:
                op.params = None
                _geometry_kernel(positions, pairs.row, pairs.j, pairs.image, pairs.images,
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
        for a, b in zip(*np.nonzero(table[:, :, _FORM] != _OFF)):
            sel = (ti == a) & (tj == b) & (r2 < table[a, b, _RC2])
            J[sel], dJ[sel] = _user_values(couplings[a, b], r[sel])
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
        out = _direct_kernel(threads.all_threads(), positions, pairs.row, pairs.j,
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
def _geometry_kernel(pos, row, nbr, image, images, types, table, J, g, G, other, Jbar):
    """J_k = J(r_ij) and, into whichever of G and g is not empty,
    G_k = J'(r_ij) d_ij / r_ij or g_k = J'(r_ij)/r_ij for every pair
    k = (i → j), with d_ij = (r_j − r_i) + S_k and r_ij² = |d_ij|²
    (:func:`separation`); with ``other`` given, also Jbar_k = ½(other_k + J_k)."""
    n = len(row) - 1
    want_mean = other.shape[0] > 0
    stored = G.shape[0] > 0
    for blk in nb.prange((n + _GEOMETRY_BLOCK - 1) // _GEOMETRY_BLOCK):
        lo = blk * _GEOMETRY_BLOCK
        hi = min(n, lo + _GEOMETRY_BLOCK)
        _geometry_table_block(lo, hi, pos, row, nbr, image, images, types, table, J, g, G,
                              other, Jbar, want_mean, stored)


@nb.njit(cache=True)
def _geometry_table_block(lo, hi, pos, row, nbr, image, images, types, table, J, g, G, other,
                          Jbar, want_mean, stored):
    """:func:`_geometry_kernel` for the pairs of atoms lo … hi − 1, their
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
    """:func:`_geometry_single`'s Bethe–Slater pass over the pairs of atoms
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
def _geometry_single(pos, row, nbr, image, images, rc2, form, p0, p1, p2, J, g, G, other,
                     Jbar):
    """:func:`_geometry_kernel` for one species (one coupling); Bethe–Slater
    in blocks of :data:`_GEOMETRY_BLOCK` atoms (:func:`_bethe_slater_block`:
    the same values as one pair at a time)."""
    n = len(row) - 1
    want_mean = other.shape[0] > 0
    stored = G.shape[0] > 0
    if form == _BETHE_SLATER:
        for b in nb.prange((n + _GEOMETRY_BLOCK - 1) // _GEOMETRY_BLOCK):
            _bethe_slater_block(b * _GEOMETRY_BLOCK, min(n, (b + 1) * _GEOMETRY_BLOCK), pos,
                                row, nbr, image, images, rc2, p0, p1, p2, J, g, G, other,
                                Jbar, want_mean, stored)
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


#: Read by the pass kernels below as a compile-time constant: False in the
#: kernels of operators keeping G (they read it), True in their twins for
#: operators keeping g (:func:`_formed_twin`: they form G = g d per pair). Two
#: compiled kernels, not a branch per pair: the G kernels' force loop is then
#: the one that read G before g existed, as fast.
_FORMED = False
#: Read by :func:`_spin_pass_half` as a compile-time constant: None in the
#: kernel for any request (the flags are arguments), or the flags (want_b,
#: want_f, want_energy, want_energies, want_virial) themselves in its twins for
#: the two requests of every step — forces alone (the integrators' force
#: passes) and fields alone — whose loops then hold no branch on them
#: (docs/benchmarks.md, "The exchange force pass").
_WANT = None


def _formed_twin(fn):
    """``fn`` with ``_FORMED = True`` (:func:`~ase_spin.terms.base.kernel_twin`)."""
    return kernel_twin(fn, "_formed", _FORMED=True)


#: The requests with twins of their own (see _WANT).
_FORCES_ONLY = (False, True, False, False, False)
_FIELD_ONLY = (True, False, False, False, False)
_FORCES_AND_FIELD = (True, True, False, False, False)


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
    """One pass over the exchange pairs for spins s (full list, gather into i),
    w = s_i·s_j − c, G_ij = J'(r_ij) d_ij/r_ij read from ``G`` (or, in the
    :func:`_formed_twin`, formed as g_ij d_ij), d_ij = (r_j − r_i) + S_ij
    recomputed from the positions ``pos`` the operator was prepared at:

    B_i += Σ_j J_ij u_j,   F_i += −Σ_j w G_ij,
    e_i += −½ Σ_j J_ij w,   W += −½ Σ_ij w G_ij ⊗ d_ij,

    the field B for spins ``u`` (s itself but in :meth:`ExchangeOperator.forces_and_field`).

    (G_ij = g·d is the product the geometry pass stores in G, scaled by w after:
    the same bits either way.) The G kernel reads no positions and gives no
    virial (``want_virial`` False; :func:`_virial_pass` adds it): its loop
    holds nothing it does not need. Rows in ``nthreads`` fixed chunks, each
    summing its own energy and virial: the sums do not depend on how many
    threads run the chunks.
    """
    bounds = balanced_chunks(row, nthreads)
    acc = np.zeros((nthreads, 7))
    need_dot = want_f or want_energy or want_energies or want_virial
    need_d = _FORMED
    for t in nb.prange(nthreads):
        e = 0.0
        vxx = 0.0
        vyy = 0.0
        vzz = 0.0
        vyz = 0.0
        vxz = 0.0
        vxy = 0.0
        for i in range(bounds[t], bounds[t + 1]):
            sx = s[i, 0]
            sy = s[i, 1]
            sz = s[i, 2]
            if need_d:
                xi = pos[i, 0]
                yi = pos[i, 1]
                zi = pos[i, 2]
            else:
                xi = yi = zi = 0.0
            bx = 0.0
            by = 0.0
            bz = 0.0
            fx = 0.0
            fy = 0.0
            fz = 0.0
            ei = 0.0
            for k in range(row[i], row[i + 1]):
                j = nbr[k]
                Jk = J[k]
                if want_b:
                    bx += Jk * u[j, 0]
                    by += Jk * u[j, 1]
                    bz += Jk * u[j, 2]
                if need_dot:
                    w = sx * s[j, 0] + sy * s[j, 1] + sz * s[j, 2] - c
                    if need_d:
                        # d = (r_j − r_i) + S as separation() forms it, r_i loaded once
                        m = image[k]
                        dx = (pos[j, 0] - xi) + images[m, 0]
                        dy = (pos[j, 1] - yi) + images[m, 1]
                        dz = (pos[j, 2] - zi) + images[m, 2]
                    else:
                        dx = dy = dz = 0.0
                    if _FORMED:
                        gk = g[k]
                        Gx = gk * dx
                        Gy = gk * dy
                        Gz = gk * dz
                    else:
                        Gx = G[k, 0]
                        Gy = G[k, 1]
                        Gz = G[k, 2]
                    fx -= w * Gx
                    fy -= w * Gy
                    fz -= w * Gz
                    ei -= 0.5 * Jk * w
                    if want_virial:
                        h = -0.5 * w
                        vxx += h * Gx * dx
                        vyy += h * Gy * dy
                        vzz += h * Gz * dz
                        vyz += h * Gy * dz
                        vxz += h * Gx * dz
                        vxy += h * Gx * dy
            if want_b:
                B[i, 0] += bx
                B[i, 1] += by
                B[i, 2] += bz
            if want_f:
                F[i, 0] += fx
                F[i, 1] += fy
                F[i, 2] += fz
            if want_energies:
                energies[i] += ei
            if want_energy:
                e += ei
        acc[t, 0] = e
        acc[t, 1] = vxx
        acc[t, 2] = vyy
        acc[t, 3] = vzz
        acc[t, 4] = vyz
        acc[t, 5] = vxz
        acc[t, 6] = vxy
    out = sum_over_threads(acc)
    return out[0], out[1], out[2], out[3], out[4], out[5], out[6]


def _spin_pass_half(nthreads, row, nbr, image, images, J, g, G, pos, s, u, c, B, F, energies,
                    want_b, want_f, want_energy, want_energies, want_virial):
    """:func:`_spin_pass` over a half list (each pair once), scattering into
    per-thread buffers, w = s_i·s_j − c, G read (or formed as g d in the
    :func:`_formed_twin`), d recomputed from ``pos``: B_i += J u_j,
    B_j += J u_i, F_i −= w G, F_j += w G, e_i, e_j −= ½ J w, W −= w G ⊗ d."""
    if _WANT is not None:  # a twin for one request: the flags are constants
        want_b, want_f, want_energy, want_energies, want_virial = _WANT
    n = len(row) - 1
    bounds = balanced_chunks(row, nthreads)
    # forces and field together (forces_and_field): one buffer, both on one
    # cache line per atom j (two buffers of the scattered rows miss twice)
    both = want_b and want_f
    bbuf = np.zeros((nthreads, n if want_b and not both else 0, 3))
    fbuf = np.zeros((nthreads, n if want_f and not both else 0, 3))
    pbuf = np.zeros((nthreads, n if both else 0, 6))
    # where the scattered forces and fields go: columns 0-2 of fb, bo.. of bb
    fb = pbuf if both else fbuf
    bb, bo = (pbuf, 3) if both else (bbuf, 0)
    ebuf = np.zeros((nthreads, n if want_energies else 0, 1))
    acc = np.zeros((nthreads, 7))
    need_dot = want_f or want_energy or want_energies or want_virial
    need_d = _FORMED
    for t in nb.prange(nthreads):
        e = 0.0
        vxx = 0.0
        vyy = 0.0
        vzz = 0.0
        vyz = 0.0
        vxz = 0.0
        vxy = 0.0
        for i in range(bounds[t], bounds[t + 1]):
            sx = s[i, 0]
            sy = s[i, 1]
            sz = s[i, 2]
            vx = u[i, 0]
            vy = u[i, 1]
            vz = u[i, 2]
            if need_d:
                xi = pos[i, 0]
                yi = pos[i, 1]
                zi = pos[i, 2]
            else:
                xi = yi = zi = 0.0
            bx = 0.0
            by = 0.0
            bz = 0.0
            fx = 0.0
            fy = 0.0
            fz = 0.0
            ei = 0.0
            for k in range(row[i], row[i + 1]):
                j = nbr[k]
                Jk = J[k]
                if want_b:
                    bx += Jk * u[j, 0]
                    by += Jk * u[j, 1]
                    bz += Jk * u[j, 2]
                    bb[t, j, bo] += Jk * vx
                    bb[t, j, bo + 1] += Jk * vy
                    bb[t, j, bo + 2] += Jk * vz
                if need_dot:
                    w = sx * s[j, 0] + sy * s[j, 1] + sz * s[j, 2] - c
                    if want_energy or want_energies:
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
                        gk = g[k]
                        # w (g d): the product G = g d of the geometry pass first
                        gx = w * (gk * dx)
                        gy = w * (gk * dy)
                        gz = w * (gk * dz)
                    else:
                        gx = w * G[k, 0]
                        gy = w * G[k, 1]
                        gz = w * G[k, 2]
                    if want_f:
                        fx -= gx
                        fy -= gy
                        fz -= gz
                        fb[t, j, 0] += gx
                        fb[t, j, 1] += gy
                        fb[t, j, 2] += gz
                    if want_virial:
                        vxx -= gx * dx
                        vyy -= gy * dy
                        vzz -= gz * dz
                        vyz -= gy * dz
                        vxz -= gx * dz
                        vxy -= gx * dy
            if want_b:
                bb[t, i, bo] += bx
                bb[t, i, bo + 1] += by
                bb[t, i, bo + 2] += bz
            if want_f:
                fb[t, i, 0] += fx
                fb[t, i, 1] += fy
                fb[t, i, 2] += fz
            if want_energies:
                ebuf[t, i, 0] += 0.5 * ei
            e += ei
        acc[t, 0] = e
        acc[t, 1] = vxx
        acc[t, 2] = vyy
        acc[t, 3] = vzz
        acc[t, 4] = vyz
        acc[t, 5] = vxz
        acc[t, 6] = vxy
    reduce_threads(fbuf, F)
    reduce_threads(bbuf, B)
    for i in nb.prange(pbuf.shape[1]):
        _add_thread_sums(pbuf, i, 0, F, F)
        _add_thread_sums(pbuf, i, 3, B, B)
    reduce_threads(ebuf, energies.reshape((energies.shape[0], 1)))
    return sum_over_threads(acc)


@threaded()
def _virial_pass(nthreads, row, nbr, image, images, G, pos, s, c, half):
    """The exchange virial for spins s from stored G = J'(r) d/r and d
    recomputed from ``pos``, w = s_i·s_j − c: W = −Σ_k w G_k ⊗ d_k over a half
    list, −½ Σ_k w G_k ⊗ d_k over a full one; Voigt order. The rows, chunks and
    per-pair products of the passes above in the same order (the same sums)."""
    bounds = balanced_chunks(row, nthreads)
    acc = np.zeros((nthreads, 7))
    for t in nb.prange(nthreads):
        vxx = 0.0
        vyy = 0.0
        vzz = 0.0
        vyz = 0.0
        vxz = 0.0
        vxy = 0.0
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
        acc[t, 1] = vxx
        acc[t, 2] = vyy
        acc[t, 3] = vzz
        acc[t, 4] = vyz
        acc[t, 5] = vxz
        acc[t, 6] = vxy
    return sum_over_threads(acc)


@threaded()
def _forces_two_pass(nthreads, row, nbr, G, G2, s, c, F, keep, J2, u, B):
    """Over a half list, w = s_i·s_j − c, the forces of two pair geometries of
    one list (G at the positions q, G2 at q̃) for the same spins s, each with
    the arithmetic of :func:`_spin_pass_half`'s forces:

    F_i −= w G, F_j += w G (summed into F);  the same with G2, left as
    per-thread partial sums in keep[t, :, 0:3] (:func:`_add_kept`);

    with ``u`` (non-empty), also B_i += J2 u_j, B_j += J2 u_i (summed into B).
    ``keep`` (nthreads, n, 6 or 9) is the scatter buffer, all of one atom's
    columns on one cache line: keep[t, :, 3:6] the forces at q, 6:9 the field."""
    n = len(row) - 1
    bounds = balanced_chunks(row, nthreads)
    want_b = u.shape[0] > 0
    for t in nb.prange(nthreads):
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
    for i in nb.prange(n):
        _add_thread_sums(keep, i, 3, F, F)
        if want_b:
            _add_thread_sums(keep, i, 6, B, B)


@threaded()
def _add_kept(keep, base, out):
    """out_i = base_i + Σ_t keep[t, i, 0:3] (:func:`_add_thread_sums`)."""
    for i in nb.prange(base.shape[0]):
        _add_thread_sums(keep, i, 0, base, out)


_spin_pass_kernel = threaded()(_spin_pass)
_spin_pass_formed = threaded()(_formed_twin(_spin_pass))
_spin_pass_half_kernel = threaded(reduce_threads=lambda: reduce_threads_serial)(_spin_pass_half)
_spin_pass_half_formed = threaded(reduce_threads=lambda: reduce_threads_serial)(
    _formed_twin(_spin_pass_half))
_spin_pass_half_forces = threaded(reduce_threads=lambda: reduce_threads_serial)(
    kernel_twin(_spin_pass_half, "_forces", _WANT=_FORCES_ONLY))
_spin_pass_half_field = threaded(reduce_threads=lambda: reduce_threads_serial)(
    kernel_twin(_spin_pass_half, "_field", _WANT=_FIELD_ONLY))
_spin_pass_half_forces_field = threaded(reduce_threads=lambda: reduce_threads_serial)(
    kernel_twin(_spin_pass_half, "_forces_field", _WANT=_FORCES_AND_FIELD))


@threaded(always=True, reduce_threads=lambda: reduce_threads_serial)
def _direct_kernel(nthreads, pos, row, nbr, image, images, types, table, s, c, B, F, energies,
                   want_b, want_f, want_energy, want_energies, want_virial):
    """One evaluation from positions over a half pair list (each pair once,
    nothing stored per pair; the Bethe–Slater exponentials of a block of
    atoms' pairs first, :func:`_exp_arguments`), w = s_i·s_j − c,
    g = J'(r)/r, d = r_j + S − r_i:

    B_i += J s_j,  B_j += J s_i,  F_i −= w g d,  F_j += w g d,
    e_i, e_j −= ½ J w,  W −= w g d ⊗ d.

    Per-thread buffers as in the Lennard-Jones kernel.
    """
    n = len(row) - 1
    bounds = balanced_chunks(row, nthreads)
    bbuf = np.zeros((nthreads, n if want_b else 0, 3))
    fbuf = np.zeros((nthreads, n if want_f else 0, 3))
    ebuf = np.zeros((nthreads, n if want_energies else 0, 1))
    acc = np.zeros((nthreads, 7))
    for t in nb.prange(nthreads):
        e = 0.0
        vxx = 0.0
        vyy = 0.0
        vzz = 0.0
        vyz = 0.0
        vxz = 0.0
        vxy = 0.0
        for i in range(bounds[t], bounds[t + 1]):
            if (i - bounds[t]) % _GEOMETRY_BLOCK == 0:  # the next block's exponentials
                k0 = row[i]
                xs, exs, ds = _exp_arguments(i, min(bounds[t + 1], i + _GEOMETRY_BLOCK), pos,
                                             row, nbr, image, images, types, table)
            ti = types[i]
            sx = s[i, 0]
            sy = s[i, 1]
            sz = s[i, 2]
            bx = 0.0
            by = 0.0
            bz = 0.0
            fx = 0.0
            fy = 0.0
            fz = 0.0
            ei = 0.0
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
                    bbuf[t, j, 0] += Jk * sx
                    bbuf[t, j, 1] += Jk * sy
                    bbuf[t, j, 2] += Jk * sz
                wg = w * g
                if want_f:
                    gx = wg * dx
                    gy = wg * dy
                    gz = wg * dz
                    fx -= gx
                    fy -= gy
                    fz -= gz
                    fbuf[t, j, 0] += gx
                    fbuf[t, j, 1] += gy
                    fbuf[t, j, 2] += gz
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
                bbuf[t, i, 0] += bx
                bbuf[t, i, 1] += by
                bbuf[t, i, 2] += bz
            if want_f:
                fbuf[t, i, 0] += fx
                fbuf[t, i, 1] += fy
                fbuf[t, i, 2] += fz
            if want_energies:
                ebuf[t, i, 0] += 0.5 * ei
            e += ei
        acc[t, 0] = e
        acc[t, 1] = vxx
        acc[t, 2] = vyy
        acc[t, 3] = vzz
        acc[t, 4] = vyz
        acc[t, 5] = vxz
        acc[t, 6] = vxy
    reduce_threads(fbuf, F)
    reduce_threads(bbuf, B)
    reduce_threads(ebuf, energies.reshape((energies.shape[0], 1)))
    return sum_over_threads(acc)


_geometry_single_serial = _geometry_single.serial
_forces_pass_serial = _spin_pass_half_forces.serial


@nb.njit(cache=True)
def _exchange_forces(W, data, F):
    """F += the exchange forces at spins W (:meth:`ExchangeOperator.add`, forces
    only, serial twin, G kept): a piece of the fused step."""
    nthreads, row, nbr, image, images, J, G, Jbar, offset, params = data
    _forces_pass_serial(nthreads, row, nbr, image, images, J, np.zeros(0), G,
                        np.zeros((0, 3)), W, W, offset, np.zeros((0, 3)), F, np.zeros(0),
                        False, True, False, False, False)


_forces_two_serial = _forces_two_pass.serial
_add_kept_serial = _add_kept.serial


@nb.njit(cache=True)
def _exchange_forces_two(W, data, there, F):
    """F += the exchange forces at spins W (data: the operator at q), and the
    forces of the operator ``there`` (at q̃, the same pairs) as per-thread
    partial sums, returned for :func:`_exchange_add_kept`
    (:meth:`ExchangeOperator.forces_here_and_there`, serial twin): a piece of
    the fused step."""
    nthreads, row, nbr, image, images, J, G, Jbar, offset, params = data
    keep = np.empty((nthreads, len(row) - 1, 6))
    _forces_two_serial(nthreads, row, nbr, G, there[6], W, offset, F, keep, there[5],
                       np.zeros((0, 3)), np.zeros((0, 3)))
    return keep


@nb.njit(cache=True)
def _exchange_add_kept(keep, base, out):
    """out = base + the kept partial sums (:func:`add_kept`): a piece of the fused step."""
    _add_kept_serial(keep, base, out)


@nb.njit(cache=True)
def _exchange_geometry(positions, data, other):
    """J, G and the midpoint couplings J̄ = ½(J + J_other) at ``positions``
    (:meth:`Exchange.prepare` with ``out`` and ``mean_with``, one species,
    serial twin): a piece of the fused step."""
    nthreads, row, nbr, image, images, J, G, Jbar, offset, params = data
    rc2, form, p0, p1, p2 = params
    _geometry_single_serial(positions, row, nbr, image, images, rc2, form, p0, p1, p2, J,
                            np.zeros(0), G, other[5], Jbar)


_geometry_single_parallel = _geometry_single.parallel


@nb.njit(cache=True)
def _exchange_geometry_threaded(positions, data, other):
    """:func:`_exchange_geometry` with the threaded twin of the geometry kernel
    (one result per pair: the same bits whatever the threads), as
    :meth:`Exchange.prepare` runs it above the tiny systems."""
    nthreads, row, nbr, image, images, J, G, Jbar, offset, params = data
    rc2, form, p0, p1, p2 = params
    _geometry_single_parallel(positions, row, nbr, image, images, rc2, form, p0, p1, p2, J,
                              np.zeros(0), G, other[5], Jbar)


@nb.njit(cache=True)
def _exchange_couplings(data):
    """(row, nbr, J̄): the midpoint field B̄_i = Σ_j J̄_ij W_j on the half list."""
    return data[1], data[2], data[7]
