"""Parameters of terms and couplings: reassignable parameters that make
whatever was built from them stale (:class:`Parameterised`), and values given
per species or per species pair — checked, kept read-only, and expanded into
the tables and per-atom arrays the kernels take."""

from __future__ import annotations

import itertools
from collections.abc import Mapping

import numpy as np

from ..validate import real_scalar

__all__ = ["Parameterised", "PairParameters", "parameter_generation", "pair_values",
           "real_or_none", "pair_key", "is_pair_mapping", "resolve_pairs", "species_values",
           "per_atom"]

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
