"""LAMMPS SPIN's text dumps read back as ASE Atoms: positions, velocities,
spins in ``initial_magmoms``, forces, magnetic forces and energies as
calculator results (the conventions of :mod:`ase_spin.interop.lammps`)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from ase import Atoms

from ..constants import HBAR_LAMMPS
from ..validate import warn_user
from .lammps import HEADER, PS

__all__ = ["LammpsDumpWarning", "read_lammps_spin_dump"]


def _read_data_header(path):
    """(symbols by type, rotation or None) from a data file written here, or
    from its Atom Type Labels section (rotation None) for any other."""
    lines, _ = _read_text(path, "a LAMMPS data file")
    text = "\n".join(lines) + "\n"
    first = lines[0] if lines else ""
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


class LammpsDumpWarning(UserWarning):
    """A dump whose last frame is cut short (the run is still going or was
    killed): the complete frames before it are read, the cut one is left out."""


def _read_text(path, what):
    """A text file's lines, and whether its last line is cut (no newline at
    the end: LAMMPS writes whole lines)."""
    with open(path, "rb") as fh:
        raw = fh.read()
    if b"\0" in raw:
        raise ValueError(f"{path}: not a text file (contains NUL bytes); expected {what}")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as err:
        raise ValueError(f"{path}: not a text file (byte {err.start} is not UTF-8); "
                         f"expected {what}") from None
    return text.splitlines(), bool(text) and not text.endswith(("\n", "\r"))


class _Cut(Exception):
    """The file ends inside a frame."""


def _frames(path):
    """Each complete frame of a LAMMPS text dump: (timestep, box lines, bounds
    header, columns, rows, first row's line number). A frame cut short by the
    end of the file (a run still going or killed) is left out with a
    :class:`LammpsDumpWarning` naming it; anything else malformed is a
    ValueError naming the file and the line."""
    lines, last_cut = _read_text(path, "a LAMMPS text dump")
    usable = len(lines) - 1 if last_cut else len(lines)  # complete lines
    frames = []
    k = 0

    def line(j, what):
        if j >= usable:
            raise _Cut(what)
        return lines[j]

    def item(j, name):
        text = line(j, f"the line 'ITEM: {name}'")
        if not text.startswith(f"ITEM: {name}"):
            raise ValueError(f"{path}: line {j + 1} should be 'ITEM: {name}' "
                             f"(frame {len(frames)}), got {text[:80]!r}")
        return text

    def integer(j, what):
        text = line(j, what).strip()
        try:
            return int(text)
        except ValueError:
            raise ValueError(f"{path}: line {j + 1}: {what} must be an integer, got "
                             f"{text[:80]!r}") from None

    while k < len(lines):
        if not lines[k].strip() and all(not x.strip() for x in lines[k:]):
            break  # blank lines at the end
        start = k
        step = None
        try:
            item(k, "TIMESTEP")
            step = integer(k + 1, "the timestep")
            item(k + 2, "NUMBER OF ATOMS")
            n = integer(k + 3, "the number of atoms")
            if n < 0:
                raise ValueError(f"{path}: line {k + 4}: the number of atoms is {n}")
            bounds = item(k + 4, "BOX BOUNDS")
            box = [line(k + 5 + d, "the box") for d in range(3)]
            columns = item(k + 8, "ATOMS").split()[2:]
            rows = []
            for r in range(n):
                j = k + 9 + r
                if j < len(lines) and lines[j].startswith("ITEM:"):
                    raise ValueError(
                        f"{path}: frame {len(frames)} (timestep {step}, line {start + 1}) says "
                        f"{n} atoms, but line {j + 1} starts the next item after {r} rows")
                text = line(j, f"row {r + 1} of {n}")
                rows.append(text)
        except _Cut as cut:
            what = f"frame {len(frames)}" + (f" (timestep {step})" if step is not None else "")
            message = (f"{path}: {what}, from line {start + 1}, is cut short: the file ends "
                       f"before {cut.args[0]} (the run is still going or was killed, or "
                       f"its atom count is too large)")
            if not frames:
                raise ValueError(message + "; no frame is complete") from None
            warn_user(f"{message}; it is left out, the complete frames before it "
                      f"({len(frames)}) are read", LammpsDumpWarning)
            break
        frames.append((step, bounds, box, columns, rows, k + 10))
        k += 9 + n
    if not frames:
        raise ValueError(f"{path}: no frame in it (an empty file)")
    return frames


def _numbers(path, rows, first_line, what, width):
    """Rows of ``width`` words as a float array; a row of another length, a
    word that is not a number, or NaN/inf is a ValueError naming its line."""
    words = [r.split() for r in rows]
    for r, w in enumerate(words):
        if len(w) != width:
            raise ValueError(f"{path}: line {first_line + r}: {what}: {len(w)} values, "
                             f"expected {width}")
    try:
        table = np.array(words, dtype=float).reshape(len(rows), width)
    except ValueError:
        table = None
    if table is None or not np.isfinite(table).all():
        for r, row in enumerate(words):
            for word in row:
                try:
                    value = float(word)
                except ValueError:
                    value = None
                if value is None or not np.isfinite(value):
                    raise ValueError(f"{path}: line {first_line + r}: {what}: {word!r} is not "
                                     f"a finite number") from None
    return table


def _integers(path, values, name, first_line):
    """A column that must hold integers (ids, types)."""
    bad = np.flatnonzero(values != np.rint(values))
    if len(bad):
        raise ValueError(f"{path}: line {first_line + bad[0]}: the {name} "
                         f"{float(values[bad[0]])!r} is not an integer")
    return values.astype(np.int64)


def _box(bounds, box, path, first_line):
    """Cell vectors and pbc from a dump's BOX BOUNDS (LAMMPS's bounding-box form
    for triclinic boxes); positions in dumps are absolute, the origin is not needed."""
    words = bounds.split()[3:]
    tilted = "xy" in words
    rows = _numbers(path, box, first_line, f"the box ({bounds.strip()})", 3 if tilted else 2)
    flags = [w for w in words if w not in ("xy", "xz", "yz")]
    if len(flags) != 3:
        raise ValueError(f"{path}: line {first_line - 1}: expected three boundary flags in "
                         f"{bounds.strip()!r}")
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

    A last frame cut short by the end of the file (a run still going, or
    killed) is left out with a :class:`LammpsDumpWarning` naming it, and the
    complete frames are read (a ValueError if none is complete). Anything else
    malformed is a ValueError naming the file and the line: a frame with
    fewer rows than its atom count before the next item, rows of the wrong
    length, words that are not finite numbers, no ``id``, ``type`` or
    position columns, an atom id twice, ids or types that are not integers.
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
        lines, cut = _read_text(energy_file, "an energy file (step, pe, ke)")
        for n, line in enumerate(lines[:-1] if cut else lines):  # a cut last line: not yet
            if line.strip() and not line.startswith("#"):
                words = line.split()
                values = _numbers(energy_file, [" ".join(words[:3])], n + 1, "step pe ke", 3)
                if values[0, 0] != int(values[0, 0]):
                    raise ValueError(f"{energy_file}: line {n + 1}: expected a step (an "
                                     f"integer), the potential and the kinetic energy, got "
                                     f"{line[:80]!r}")
                energies[int(values[0, 0])] = (float(values[0, 1]), float(values[0, 2]))
    if isinstance(index, str):
        index = string2index(index)
    frames = _frames(path)
    chosen = frames[index] if isinstance(index, slice) else [frames[index]]
    out = []
    for step, bounds, box, columns, rows, first in chosen:
        col = {c: k for k, c in enumerate(columns)}
        for need in ("id", "type"):
            if need not in col:
                raise ValueError(f"{path}: line {first - 1}: no '{need}' column in the frame "
                                 f"of timestep {step} ({' '.join(columns)})")
        if len(col) != len(columns):
            raise ValueError(f"{path}: line {first - 1}: a column is named twice "
                             f"({' '.join(columns)})")
        table = _numbers(path, rows, first, f"the columns {' '.join(columns)}",
                         len(columns))
        ids = _integers(path, table[:, col["id"]], "atom id", first)
        _integers(path, table[:, col["type"]], "atom type", first)
        order = np.argsort(ids, kind="stable")
        twice = np.flatnonzero(np.diff(ids[order]) == 0)
        if len(twice):
            a, b = sorted(order[twice[0]:twice[0] + 2])
            raise ValueError(f"{path}: lines {first + a} and {first + b}: atom id "
                             f"{ids[order[twice[0]]]} appears twice (timestep {step})")
        table = table[order]

        def get(*names):
            if all(nm in col for nm in names):
                return table[:, [col[nm] for nm in names]]
            return None

        cell, pbc = _box(bounds, box, path, first - 4)
        pos = get("xu", "yu", "zu")
        if pos is None:
            pos = get("x", "y", "z")
        if pos is None:
            raise ValueError(f"{path}: line {first - 1}: no positions (columns xu yu zu or "
                             f"x y z) in the frame of timestep {step}")
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
