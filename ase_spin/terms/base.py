"""What every Hamiltonian term shares: its interface and per-species parameters."""

from __future__ import annotations

import itertools
from collections.abc import Mapping
from dataclasses import dataclass

import numba as nb
import numpy as np

from .._jit import threads
from .._jit.cloning import compile_with
from .._jit.reductions import balanced_chunks, reduce_threads, sum_over_threads
from ..validate import real_scalar

__all__ = ["Want", "Term", "SpinTerm", "SpinOperator", "PairSpinTerm", "PairOperator", "System",
           "Parameterised", "PairParameters",
           "Species", "pair_key", "resolve_pairs", "pair_values", "parameter_generation"]

_versions = itertools.count(1)
_last_change = [0]


def parameter_generation():
    """A number that grows whenever any term's or coupling's parameter is assigned:
    caches built from parameters compare it before trusting themselves."""
    return _last_change[0]


class Parameterised:
    """An object whose parameters are its constructor's arguments.

    ``_parameters`` maps each constructor argument to the attribute that holds
    it. Assigning a parameter after construction (``lj.epsilon = 0.5``) runs the
    constructor's checks again on the new set (a bad value is refused and the
    object left as it was) and gives the object a new version, so that every
    table, pair list and integrator state built from the old values knows it is
    stale (see :meth:`fingerprint`). Any other public attribute assigned later
    also counts as a change.
    """

    _parameters: dict = {}

    def _finish(self):
        """Call at the end of ``__init__``: from now on assignments are changes."""
        self.__dict__["_version"] = next(_versions)
        _last_change[0] = self.__dict__["_version"]

    def __setattr__(self, name, value):
        if "_version" not in self.__dict__ or name.startswith("_"):
            object.__setattr__(self, name, value)
            return
        by_attribute = {attr: arg for arg, attr in self._parameters.items()}
        if name in by_attribute:
            args = {arg: getattr(self, attr) for arg, attr in self._parameters.items()}
            args[by_attribute[name]] = value
            fresh = object.__new__(type(self))
            fresh.__init__(**args)  # the constructor's checks; raises, self unchanged
            self.__dict__.update(fresh.__dict__)
        else:
            object.__setattr__(self, name, value)
            self.__dict__["_version"] = next(_versions)
        _last_change[0] = self.__dict__["_version"]

    def fingerprint(self):
        """Versions of this object and of the parameterised objects it holds
        (couplings inside a term): equal fingerprints, equal parameters."""
        nested = []
        for attr in self._parameters.values():
            value = getattr(self, attr, None)
            values = value.values() if isinstance(value, Mapping) else (value,)
            nested.extend(v.fingerprint() for v in values if isinstance(v, Parameterised))
        return (type(self).__name__, self.__dict__.get("_version", 0), *nested)


class PairParameters(Mapping):
    """A read-only mapping of per-species-pair parameters, kept by a term.

    Editing it in place is refused: the term would not know that its tables
    are stale. Assign a new mapping instead (``lj.epsilon = {...}``).
    """

    def __init__(self, mapping, what):
        self._data = dict(mapping)
        self._what = what

    def __getitem__(self, key):
        return self._data[key]

    def __iter__(self):
        return iter(self._data)

    def __len__(self):
        return len(self._data)

    def __setitem__(self, key, value):
        raise TypeError(
            f"{self._what} is read-only once given to a term: assign a new mapping "
            "to the term's attribute instead (e.g. lj.epsilon = {...})")

    __delitem__ = __setitem__

    def __repr__(self):
        return repr(self._data)


def pair_values(value, what, check):
    """Check a per-pair parameter: one value or a mapping keyed by pairs of
    symbols. ``check(v, what)`` validates one value (and returns it normalised).
    Returns the value, or a :class:`PairParameters` copy of the mapping."""
    if isinstance(value, Mapping):
        checked = {}
        for key, v in value.items():
            k = pair_key(key)
            checked[key] = check(v, f"{what} for the pair {k[0]}-{k[1]}")
        return PairParameters(checked, what)
    return check(value, what)


def real_or_none(value, what):
    return None if value is None else real_scalar(value, what)


def pair_key(key):
    """Normalise a pair of chemical symbols: ("Fe", "Co"), "Fe-Co" -> ("Co", "Fe")."""
    if isinstance(key, str):
        parts = key.replace(" ", "").split("-")
    else:
        parts = list(key)
    if len(parts) != 2 or not all(isinstance(p, str) and p for p in parts):
        raise ValueError(
            f"species pair keys are pairs of chemical symbols such as ('Fe', 'Co') "
            f"or 'Fe-Co'; got {key!r}"
        )
    return tuple(sorted(parts))


def is_pair_mapping(value):
    return isinstance(value, Mapping)


def resolve_pairs(value, symbols, what):
    """Expand a per-pair parameter to a (ntypes, ntypes) object array.

    ``value`` is either one object for every pair or a mapping keyed by pairs of
    chemical symbols (order does not matter). A pair of species present in
    ``symbols`` but missing from the mapping is an error naming the pair.
    """
    nt = len(symbols)
    table = np.empty((nt, nt), dtype=object)
    if not is_pair_mapping(value):
        table[:, :] = value
        return table
    mapping = {}
    for key, v in value.items():
        k = pair_key(key)
        if k in mapping:
            raise ValueError(f"{what}: pair {k[0]}-{k[1]} given twice")
        mapping[k] = v
    for a in range(nt):
        for b in range(nt):
            k = tuple(sorted((symbols[a], symbols[b])))
            if k not in mapping:
                raise ValueError(
                    f"{what}: no parameters for the pair {k[0]}-{k[1]}; give one "
                    "(None switches the interaction off for that pair)"
                )
            table[a, b] = mapping[k]
    return table


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
    their moment magnitudes μ_i (μB), its cell and periodicity."""

    species: Species
    moments: np.ndarray
    cell: np.ndarray
    pbc: np.ndarray

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
    be reassigned after construction (see :class:`Parameterised`).

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
        ``(f, data)`` with ``f(positions, data, forces)`` a numba function adding
        bitwise the forces :meth:`compute` adds with ``Want(forces=True)``, with
        the twin :meth:`compute` calls at this size (serial where
        :func:`ase_spin._jit.threads.tiny`, else as the kernel's ``always`` says).
        None (the default): the integrators take their general path."""
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
      from the spins as they are, and its ``data`` tuple (None: not offered).

    Optional, for a term whose field is linear in the spins, B = C s
    (exchange): ``linear_pairs(mean)`` — (pairs, c) with B_i = Σ_k c_k s_j,
    what the compiled midpoint solvers and the thermostat's forms take; and
    ``forces_and_field(W, forces, u, field)`` — the lattice forces at W and the
    field C u at other spins u in one pass (the thermostat's fields after its
    noise, with a step's last forces); ``pairs_with(there)`` and
    ``forces_here_and_there(W, forces, there, u=None, field=None)`` — the
    lattice forces at W of this operator and of ``there`` (prepared at the
    step's other end, on the same pairs: kept as per-thread partial sums for
    ``add_kept``), and optionally C u, in one pass (a step's forces at q with
    its end forces).

    Non-magnetic atoms get zero field.
    """

    site = None

    def compiled(self):
        """Optional: this operator as compiled pieces of the integrators' fused
        step for small systems (:mod:`ase_spin.md.fused`), ``(forces, geometry,
        couplings, data)``, numba functions that do bitwise what the methods do,
        with the twins (serial or threaded) the methods call at this size:

        - ``forces(W, data, F)``: add the lattice forces at spins W (:meth:`add`
          with ``Want(forces=True)``);
        - ``geometry(positions, data, other)``: refill ``data`` at new positions,
          with the midpoint quantities from the operator of ``other`` (the term's
          ``prepare(positions, out=this, mean_with=that)``);
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


def species_values(value, what, check):
    """Check a per-species parameter: one value, or a mapping from chemical
    symbol to value. Returns the value or a read-only mapping."""
    if isinstance(value, Mapping):
        checked = {}
        for key, v in value.items():
            if not isinstance(key, str) or not key:
                raise ValueError(f"{what}: keys are chemical symbols such as 'Fe'; got {key!r}")
            checked[key] = check(v, f"{what} for {key}")
        return PairParameters(checked, what)
    return check(value, what)


def per_atom(value, system, what):
    """A per-species parameter (see :func:`species_values`) as a per-atom array,
    zero on non-magnetic atoms. A magnetic species missing from a mapping is an
    error naming it."""
    magnetic = system.magnetic
    if not isinstance(value, Mapping):
        return np.where(magnetic, float(value), 0.0)
    symbols = system.species.symbols
    table = np.zeros(len(symbols))
    present = set(system.types[magnetic].tolist())
    for t, sym in enumerate(symbols):
        if sym in value:
            table[t] = value[sym]
        elif t in present:
            raise ValueError(f"{what}: no value for the magnetic species {sym}; give one "
                             "(0 switches the term off for it)")
    return np.where(magnetic, table[system.types], 0.0)


# -- pair spin terms ----------------------------------------------------------------


def _pair_pass(nthreads, row, nbr, half, s, data, B, F, energies, want_b, want_f,
               want_energy, want_energies, want_virial):
    """Skeleton of every pair spin term's pass over a pair list (compiled once
    per term, with ``pair_field`` and ``pair_energy`` bound to that term's
    functions). For each pair k = (i → j) of row i:

        B_i += b(k, i, j, s, data, False)      (half list: B_j += b(k, j, i, s, data, True))
        (e, f, d) = pair_energy(k, i, j, s, data):  E += e,  F_j += f,  F_i −= f,
        e_i, e_j += ½e,  W −= sym(f ⊗ d)

    with f = −∂e/∂r_j the force on j and d = r_j + S − r_i. A full list holds
    each pair twice: there row i adds only to atom i, and halves e and W.
    Returns (E, W in Voigt order xx yy zz yz xz xy)."""
    n = len(row) - 1
    bounds = balanced_chunks(row, nthreads)
    scatter = half
    nb_ = n if scatter else 0
    bbuf = np.zeros((nthreads, nb_ if want_b else 0, 3))
    fbuf = np.zeros((nthreads, nb_ if want_f else 0, 3))
    ebuf = np.zeros((nthreads, nb_ if want_energies else 0, 1))
    acc = np.zeros((nthreads, 7))
    need_e = want_f or want_energy or want_energies or want_virial
    w = 1.0 if half else 0.5
    for t in nb.prange(nthreads):
        v = np.zeros(7)
        for i in range(bounds[t], bounds[t + 1]):
            if s[i, 0] == 0.0 and s[i, 1] == 0.0 and s[i, 2] == 0.0:
                continue
            bx = 0.0
            by = 0.0
            bz = 0.0
            fx = 0.0
            fy = 0.0
            fz = 0.0
            ei = 0.0
            for k in range(row[i], row[i + 1]):
                j = nbr[k]
                if want_b:
                    cx, cy, cz = pair_field(k, i, j, s, data, False)  # noqa: F821
                    bx += cx
                    by += cy
                    bz += cz
                    if scatter:
                        cx, cy, cz = pair_field(k, j, i, s, data, True)  # noqa: F821
                        bbuf[t, j, 0] += cx
                        bbuf[t, j, 1] += cy
                        bbuf[t, j, 2] += cz
                if need_e:
                    e, gx, gy, gz, dx, dy, dz = pair_energy(k, i, j, s, data)  # noqa: F821
                    ei += 0.5 * e
                    v[0] += w * e
                    fx -= gx
                    fy -= gy
                    fz -= gz
                    if scatter:
                        if want_f:
                            fbuf[t, j, 0] += gx
                            fbuf[t, j, 1] += gy
                            fbuf[t, j, 2] += gz
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
                    bbuf[t, i, 0] += bx
                    bbuf[t, i, 1] += by
                    bbuf[t, i, 2] += bz
                if want_f:
                    fbuf[t, i, 0] += fx
                    fbuf[t, i, 1] += fy
                    fbuf[t, i, 2] += fz
                if want_energies:
                    ebuf[t, i, 0] += ei
            else:  # row i belongs to this thread alone
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
        for c in range(7):
            acc[t, c] = v[c]
    if scatter:
        reduce_threads(bbuf, B)
        reduce_threads(fbuf, F)
        reduce_threads(ebuf, energies.reshape((energies.shape[0], 1)))
    return sum_over_threads(acc)


def compile_pair_pass(field, energy, name):
    """:func:`_pair_pass` for one term's compiled ``field(k, a, b, s, data,
    reverse) -> (Bx, By, Bz)`` (the field on spin a from spin b over pair k,
    ``reverse`` when a is the pair's second atom) and ``energy(k, i, j, s,
    data) -> (e, fx, fy, fz, dx, dy, dz)``, cached on disk under a name that
    changes with their code."""
    return compile_with(_pair_pass, {"pair_field": field, "pair_energy": energy}, name,
                        parallel=True)


class PairSpinTerm(SpinTerm):
    """A spin term that is a sum over pairs, built on :func:`_pair_pass`.

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
    """The operator of a pair spin term built on :func:`_pair_pass`: per-pair
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
