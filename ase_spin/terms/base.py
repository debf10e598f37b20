"""What every Hamiltonian term shares: its interface and per-species parameters."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Term", "Species", "pair_key", "resolve_pairs"]


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
    return isinstance(value, dict)


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
class Species:
    """Chemical species of a bound system: ``symbols[types[i]]`` is atom i's symbol."""

    symbols: tuple
    types: np.ndarray

    @classmethod
    def from_symbols(cls, chemical_symbols):
        symbols, types = np.unique(np.asarray(chemical_symbols, dtype=str), return_inverse=True)
        return cls(tuple(str(s) for s in symbols), types.astype(np.int64))


class Term:
    """A term of the Hamiltonian.

    Subclasses define ``cutoff`` (Å, the range of the term), ``spin_dependent``
    and ``name`` (the key in ``calc.results['energy_terms']``), and implement
    :meth:`bind` to turn their parameters into per-species-pair tables.
    """

    name = "term"
    spin_dependent = False
    cutoff = 0.0

    def bind(self, species):
        """Return the term's parameter table for these species."""
        raise NotImplementedError

    def __repr__(self):
        return f"{type(self).__name__}(...)"
