"""Pinned spins: :class:`FixSpins`, a constraint on ``atoms.constraints``.

``atoms.set_constraint(FixSpins(indices=[0, 1, 98, 99]))`` holds those atoms'
spins where they are in every integrator (LAMMPS ``fix setforce/spin 0.0 0.0
0.0``, Spirit's pinning): their precession rate is 0, so the spin update leaves
them bitwise as they were, while they still act on their neighbours through
every term (fixed boundary spins of a domain wall or a film). Their atoms still
move (``ase.constraints.FixAtoms`` fixes positions); the calculator's magnetic
forces B = −∂E/∂s stay as they are (LAMMPS zeroes ``fm`` in the integrator only).

An ASE constraint like ``FixAtoms``: ``atoms.copy()``, ``atoms[...]`` (the
pinned atoms of the slice; the constraint is dropped when none is in it),
``atoms.repeat`` and pickling keep it; it acts on no position, force or
momentum and removes no degree of freedom.

Files. ASE writes a constraint into a ``.traj`` (and ``.json``, ``.db``) header
by its ``todict()`` and reads it back with ``ase.constraints.dict2constraint``,
which knows ASE's own classes only: a foreign ``{"name": "FixSpins"}`` would be
written and then make the whole file unreadable (``ValueError``); a constraint
without a ``todict`` method makes ASE's writer drop every constraint of the
Atoms, ``FixAtoms`` included, without a word, and a ``FixConstraint`` subclass
that does not define it cannot be written (``RuntimeError``). So :meth:`FixSpins.todict` gives
a dict that ASE reads as an ASE constraint acting on nothing: ``FixCartesian``
of the same atoms with no direction fixed. It carries the pinned atoms under
the key ``"ase_spin"`` too, and importing ase_spin teaches
``ase.constraints.dict2constraint`` to read such a dict as ``FixSpins``
(:func:`install_reader`; every other dict is passed on untouched). A
trajectory read where ase_spin is imported therefore has its ``FixSpins``
back (a restart pins the same spins); read by plain ASE (``ase gui``, a script
without ase_spin) it opens as before, with that inert ``FixCartesian`` in its
place. ``del atoms[i]`` is refused by ASE for any constraint but ``FixAtoms``
(remove the constraint first); extxyz files keep no constraint of this kind.
"""

from __future__ import annotations

import ase.constraints as ase_constraints
import numpy as np

try:  # ASE from 3.24 (ase.constraints became a package)
    from ase.constraints.constraint import IndexedConstraint
except ImportError:  # ASE 3.23
    from ase.constraints import IndexedConstraint

__all__ = ["FixSpins", "install_reader", "lattice_constraints", "pinned_spins"]

#: The key of :meth:`FixSpins.todict` that names the constraint to ase_spin.
MARK = "ase_spin"


class FixSpins(IndexedConstraint):
    """Pin the spins of chosen atoms: they keep their directions in every
    integrator (precession rate 0), still acting on the others.

    Parameters
    ----------
    indices : sequence of int
        The atoms whose spins are pinned.
    mask : sequence of bool
        One flag per atom, instead of ``indices``.

    Pinning a non-magnetic atom (zero moment) does nothing. The pinned atoms'
    positions and momenta are integrated as any others (add
    ``ase.constraints.FixAtoms`` to hold them too). See docs/dynamics.md,
    "Pinned spins".
    """

    def get_removed_dof(self, atoms):
        """No lattice degree of freedom is removed (the atoms move)."""
        return 0

    def adjust_positions(self, atoms, new):
        pass

    def adjust_forces(self, atoms, forces):
        pass

    def adjust_momenta(self, atoms, momenta):
        pass

    def copy(self):
        return FixSpins(indices=self.index.copy())

    def __repr__(self):
        return f"FixSpins(indices={self.index.tolist()})"

    def todict(self):
        """ASE's serialised form (see the module docstring): an inert
        ``FixCartesian`` of the same atoms for ASE, the pinned atoms under
        ``"ase_spin"`` for ase_spin."""
        indices = self.index.tolist()
        return {"name": "FixCartesian",
                "kwargs": {"a": indices, "mask": [False, False, False]},
                MARK: {"name": "FixSpins", "kwargs": {"indices": indices}}}

    @classmethod
    def fromdict(cls, dct):
        """The constraint of a :meth:`todict` dict."""
        return cls(**dct[MARK]["kwargs"])


def _is_fix_spins_dict(dct):
    mark = dct.get(MARK) if isinstance(dct, dict) else None
    return isinstance(mark, dict) and mark.get("name") == "FixSpins"


def install_reader():
    """Make ``ase.constraints.dict2constraint`` read :meth:`FixSpins.todict`'s
    dicts as :class:`FixSpins` (trajectories, ``.json`` and ``.db`` files,
    ``FixConstraint.copy``); every other dict goes to ASE's own function as
    before. Done once, when ase_spin is imported."""
    current = ase_constraints.dict2constraint
    if getattr(current, "_ase_spin_reader", False):
        return

    def dict2constraint(dct):
        if _is_fix_spins_dict(dct):
            return FixSpins.fromdict(dct)
        return current(dct)

    dict2constraint.__doc__ = current.__doc__
    dict2constraint._ase_spin_reader = True
    dict2constraint.__wrapped__ = current
    ase_constraints.dict2constraint = dict2constraint


install_reader()


def pinned_spins(atoms):
    """A boolean (N,) array, True for the atoms whose spins a :class:`FixSpins`
    of ``atoms.constraints`` pins, or None if none does."""
    pinned = None
    n = len(atoms)
    for c in atoms.constraints:
        if not isinstance(c, FixSpins):
            continue
        index = np.asarray(c.index)
        bad = index[(index >= n) | (index < -n)]
        if bad.size:
            raise IndexError(f"FixSpins pins atom {int(bad[0])}, but the Atoms have {n} atoms")
        if pinned is None:
            pinned = np.zeros(n, dtype=bool)
        pinned[index] = True
    return pinned


def lattice_constraints(atoms):
    """The constraints that act on positions, forces or momenta: all of
    ``atoms.constraints`` but :class:`FixSpins` (a tuple)."""
    return tuple(c for c in atoms.constraints if not isinstance(c, FixSpins))
