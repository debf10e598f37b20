"""LAMMPS SPIN's text dumps read back as ASE Atoms: positions, velocities,
spins in ``initial_magmoms``, forces, magnetic forces and energies as
calculator results (the conventions of :mod:`ase_spin.interop.lammps`)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from ase import Atoms

from ..constants import HBAR_LAMMPS
from .lammps import HEADER, PS

__all__ = ["read_lammps_spin_dump"]


def _read_data_header(path):
    """(symbols by type, rotation or None) from a data file written here, or
    from its Atom Type Labels section (rotation None) for any other."""
    text = Path(path).read_text()
    first = text.split("\n", 1)[0]
    m = re.match(re.escape(HEADER) + r"; types (.*); rotation (.*)$", first)
    if m:
        rot = m.group(2).strip()
        rotation = None if rot == "none" else np.array(rot.split(), float).reshape(3, 3)
        return tuple(m.group(1).split()), rotation
    labels = re.search(r"Atom Type Labels\s*\n\s*\n((?:\s*\d+\s+\S+\s*\n)+)", text)
    if labels:
        rows = [line.split() for line in labels.group(1).strip().splitlines()]
        return tuple(s for _, s in sorted((int(k), s) for k, s in rows)), None
    raise ValueError(f"{path}: no type labels found; pass symbols= to name the types")


def _frames(path):
    """Each frame of a LAMMPS text dump: (timestep, box lines, bounds header,
    columns, rows)."""
    with open(path) as fh:
        lines = fh.read().splitlines()
    k = 0
    while k < len(lines):
        if not lines[k].startswith("ITEM: TIMESTEP"):
            raise ValueError(f"{path}: line {k + 1} is not a dump frame header: {lines[k]!r}")
        step = int(lines[k + 1])
        n = int(lines[k + 3])
        bounds = lines[k + 4]
        box = lines[k + 5:k + 8]
        columns = lines[k + 8].split()[2:]
        rows = lines[k + 9:k + 9 + n]
        if len(rows) < n:
            return  # a frame cut short: the run is still going or was killed
        yield step, bounds, box, columns, rows
        k += 9 + n


def _box(bounds, box):
    """Cell vectors and pbc from a dump's BOX BOUNDS (LAMMPS's bounding-box form
    for triclinic boxes); positions in dumps are absolute, the origin is not needed."""
    words = bounds.split()[3:]
    rows = np.array([[float(x) for x in line.split()] for line in box])
    flags = [w for w in words if w not in ("xy", "xz", "yz")]
    pbc = [f == "pp" for f in flags]
    if "xy" in words:
        xlo_b, xhi_b, xy = rows[0]
        ylo_b, yhi_b, xz = rows[1]
        zlo, zhi, yz = rows[2]
        xlo = xlo_b - min(0.0, xy, xz, xy + xz)
        xhi = xhi_b - max(0.0, xy, xz, xy + xz)
        ylo = ylo_b - min(0.0, yz)
        yhi = yhi_b - max(0.0, yz)
        cell = np.array([[xhi - xlo, 0, 0], [xy, yhi - ylo, 0], [xz, yz, zhi - zlo]])
    else:
        cell = np.diag(rows[:, 1] - rows[:, 0])
    return cell, pbc


def read_lammps_spin_dump(path, index=":", *, data=None, symbols=None, energy=None):
    """Frames of a LAMMPS text dump with spins as :class:`ase.Atoms`.

    ``initial_magmoms`` (N, 3) = sp (spx, spy, spz), μ_i s_i; positions (the
    unwrapped ``xu yu zu`` if dumped, else ``x y z``), cell and pbc from the box,
    velocities (Å/ps → ASE units), atoms in ID order. Forces (``fx fy fz``),
    magnetic forces B = ħ fm (eV, LAMMPS's ħ; ``fmx fmy fmz`` or the
    ``c_spin_state`` columns written by :func:`write_lammps`) and, when the
    energy file written next to the dump is there, the energy, are
    calculator results (``atoms.get_forces()``, ``atoms.calc.results``).
    ``energy``: the energy file (default ``energy.spin`` next to the dump, if
    there; columns step, potential energy, kinetic energy).

    Types become symbols through ``symbols`` (a sequence, type k+1 =
    symbols[k], or a mapping type -> symbol), else the data file ``data``
    (default: ``atoms.data`` next to the dump, if there) whose rotation is
    also undone. ``index``: an int, a slice or a string such as ":" or "-1".
    """
    from ase.calculators.singlepoint import SinglePointCalculator
    from ase.io.formats import string2index

    path = Path(path)
    rotation = None
    if data is None and symbols is None and (path.parent / "atoms.data").is_file():
        data = path.parent / "atoms.data"
    if data is not None:
        by_type, rotation = _read_data_header(data)
        if symbols is None:
            symbols = by_type
    if symbols is None:
        raise ValueError(f"{path}: give symbols= (by type) or data= (the data file) to name "
                         "the atom types")
    if isinstance(symbols, dict):
        type_symbol = {int(k): v for k, v in symbols.items()}
    else:
        type_symbol = {k + 1: s for k, s in enumerate(symbols)}
    energies = {}
    energy_file = Path(energy) if energy is not None else path.parent / "energy.spin"
    if energy is not None or energy_file.is_file():
        for line in energy_file.read_text().splitlines():
            if line.strip() and not line.startswith("#"):
                step, pe, ke = line.split()[:3]
                energies[int(step)] = (float(pe), float(ke))
    if isinstance(index, str):
        index = string2index(index)
    frames = list(_frames(path))
    chosen = frames[index] if isinstance(index, slice) else [frames[index]]
    out = []
    for step, bounds, box, columns, rows in chosen:
        table = np.array([r.split() for r in rows], dtype=float)
        col = {c: k for k, c in enumerate(columns)}
        table = table[np.argsort(table[:, col["id"]])]

        def get(*names):
            if all(nm in col for nm in names):
                return table[:, [col[nm] for nm in names]]
            return None

        cell, pbc = _box(bounds, box)
        pos = get("xu", "yu", "zu")
        if pos is None:
            pos = get("x", "y", "z")
        unit = get("spx", "spy", "spz")
        mag = get("sp")
        fm = get("fmx", "fmy", "fmz")
        if unit is None and "c_spin_state[1]" in col:
            mag = get("c_spin_state[1]")
            unit = get("c_spin_state[2]", "c_spin_state[3]", "c_spin_state[4]")
            fm = get("c_spin_state[5]", "c_spin_state[6]", "c_spin_state[7]")
        vel = get("vx", "vy", "vz")
        forces = get("fx", "fy", "fz")
        back = (lambda v: v) if rotation is None else (lambda v: v @ rotation.T)
        try:
            syms = [type_symbol[int(t)] for t in table[:, col["type"]]]
        except KeyError as err:
            raise ValueError(f"{path}: atom type {err.args[0]} has no symbol") from None
        atoms = Atoms(syms, positions=back(pos), cell=back(cell), pbc=pbc)
        if vel is not None:
            atoms.set_velocities(back(vel) / PS)
        if unit is not None:
            atoms.set_initial_magnetic_moments(back(unit) * mag)
        results = {}
        if forces is not None:
            results["forces"] = back(forces)
        if step in energies:
            results["energy"] = energies[step][0]
            results["free_energy"] = energies[step][0]
        if results or fm is not None:
            atoms.calc = SinglePointCalculator(atoms, **results)
        if fm is not None:
            # not an ASE property name: set after (SinglePointCalculator refuses it)
            atoms.calc.results["magnetic_forces"] = back(fm) * (HBAR_LAMMPS / PS)
        atoms.info["timestep"] = step
        out.append(atoms)
    return out if isinstance(index, slice) else out[0]
