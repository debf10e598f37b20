"""A term's LAMMPS form: the pair style or fix by which LAMMPS computes the same
term (:meth:`~ase_spin.terms.base.Term.lammps`), gathered into a deck by
:func:`ase_spin.interop.lammps.write_lammps`."""

from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["LammpsPair", "LammpsFix", "LammpsKspace", "number_text", "vector_text"]


def number_text(x):
    """A float as the shortest text that reads back to the same double."""
    return repr(float(x))


def vector_text(v):
    """A vector as :func:`number_text` of each component, space-separated."""
    return " ".join(number_text(x) for x in v)


@dataclass
class LammpsPair:
    """One pair style of a term, as LAMMPS takes it.

    ``style`` (``"lj/cut"``), ``args`` (its global arguments, ``"4.7"``),
    ``coeffs``: (I, J, arguments) for ``pair_coeff I J [style] arguments`` with
    I, J type numbers or ``"*"``; ``modify``: ``pair_modify`` options of this
    style (``"shift yes"``); ``files``: files the coefficients name (potential
    files), copied next to the deck and named there by their base name.
    """

    style: str
    args: str = ""
    coeffs: list = field(default_factory=list)
    modify: list = field(default_factory=list)
    files: list = field(default_factory=list)


@dataclass
class LammpsFix:
    """A fix of a term: ``fix ID group style args`` (``style`` e.g.
    ``"precession/spin"``, ``args`` ``"zeeman 1.0 0 0 1"``); ``energy``: its
    energy is part of the potential energy (``fix_modify ID energy yes``)."""

    style: str
    args: str
    group: str = "all"
    energy: bool = True


@dataclass
class LammpsKspace:
    """The long-range solver of a term: ``kspace_style style args`` and
    ``kspace_modify`` options (``"gewald 0.5 kmax/ewald 6 6 6"``, ``"slab
    3.0"``: a slab, which the deck gives a fixed (``f``) boundary across, as
    LAMMPS asks). One per deck."""

    style: str
    args: str
    modify: list = field(default_factory=list)

    @property
    def slab(self):
        return any(option.split()[0] == "slab" for option in self.modify)
