"""Exchange constants from TB2J (DFT, magnetic force theorem) in ase_spin's convention."""

from __future__ import annotations

import os
import re
from dataclasses import dataclass

import numpy as np
from ase import Atoms
from ase.data import atomic_numbers

from ..terms.pair_couplings import PairCouplings, merge_directions
from ..terms.tabulated import ShellExchange
from ..validate import warn_user

__all__ = ["read_tb2j", "read_tb2j_pairs", "TB2JExchange"]

#: TB2J's J_iso are in meV over ordered pairs; ase_spin's J in eV over unordered ones.
MEV = 1e-3

#: Pairs whose lattice image R has a component beyond this (cells) are refused.
MAX_TB2J_CELLS = 1000

#: The start of a pair line: an atom label (``Fe1``, or the older ``0(Fe1``).
_PAIR_START = re.compile(r"^\s*(?:\d+\(\s*[A-Za-z]+\d+|[A-Za-z]+\d+(?=\s|$))")

_PAIR = re.compile(
    r"^\s*(?:\d+\(\s*)?([A-Za-z]+\d+)\s*\)?\s+(?:\d+\(\s*)?([A-Za-z]+\d+)\s*\)?\s+"
    r"\(\s*(-?\d+)\s*,\s*(-?\d+)\s*,\s*(-?\d+)\s*\)\s+(\S+)\s+"
    r"\(\s*(\S+?)\s*,\s*(\S+?)\s*,\s*(\S+?)\s*\)\s+(\S+)\s*$")


@dataclass
class TB2JExchange:
    """Isotropic exchange read from TB2J, in ase_spin's convention.

    ``atoms``: the cell and atoms of the calculation (``initial_magmoms`` from
    TB2J's Wannier moments). Pairs (one row per unordered pair, each once):
    atoms ``i``, ``j`` (indices in ``atoms``), lattice image ``R`` (j is in
    the cell shifted by R·cell), ``distance`` (Å, from the positions) and
    ``J`` (eV): E = −Σ_{i<j} J_ij s_i·s_j, J > 0 ferromagnetic.
    """

    atoms: Atoms
    i: np.ndarray
    j: np.ndarray
    R: np.ndarray
    distance: np.ndarray
    J: np.ndarray

    def __len__(self):
        return len(self.J)

    def shells(self, tol=1e-3):
        """Pairs grouped by species pair and distance (within ``tol`` Å):
        {(sym_a, sym_b): [(distance, J mean, J min, J max, pairs), ...]}, J in eV.
        J min ≠ J max flags pairs at one distance that are not equivalent
        (different J), which one constant per shell cannot represent."""
        symbols = self.atoms.get_chemical_symbols()
        species = [tuple(sorted((symbols[a], symbols[b]))) for a, b in zip(self.i, self.j)]
        out = {}
        for key in sorted(set(species)):
            sel = np.array([s == key for s in species])
            d, J = self.distance[sel], self.J[sel]
            order = np.argsort(d)
            d, J = d[order], J[order]
            starts = np.concatenate([[0], np.nonzero(np.diff(d) > tol)[0] + 1, [len(d)]])
            out[key] = [(float(d[a:b].mean()), float(J[a:b].mean()), float(J[a:b].min()),
                         float(J[a:b].max()), int(b - a))
                        for a, b in zip(starts[:-1], starts[1:])]
        return out

    def exchange(self, rmax=None, tol=0.1, spread=1e-4, offset=False):
        """A :class:`~ase_spin.ShellExchange` with TB2J's constants per shell
        (species pair and distance), up to ``rmax`` Å (default: all). A shell
        whose pairs' J differ by more than ``spread`` eV gets their mean, with
        a warning naming it."""
        table = {}
        for key, shells in self.shells().items():
            rows = []
            for d, J, lo, hi, n in shells:
                if rmax is not None and d > rmax:
                    continue
                if hi - lo > spread:
                    warn_user(
                        f"TB2J: the {n} {key[0]}-{key[1]} pairs at {d:.4f} Å have J from "
                        f"{lo:.6g} to {hi:.6g} eV (not equivalent): ShellExchange uses their "
                        f"mean {J:.6g} eV")
                rows.append((d, J))
            table[key] = rows or None
        return ShellExchange(table, tol=tol, offset=offset)


def _find(lines, header, path):
    for k, line in enumerate(lines):
        if line.strip().startswith(header):
            return k
    raise ValueError(f"{path}: no '{header}' section: not a TB2J exchange.out file")


def read_tb2j(path):
    """Read TB2J's ``exchange.out`` (the format TB2J 0.9 writes:
    ``TB2J/io_exchange/io_txt.py``; pair lines ``Fe1 Fe2 (R1, R2, R3) J_iso
    (x, y, z) distance``, also the older ``0(Fe1 )`` labels) into a
    :class:`TB2JExchange`. ``path``: the file, or a directory holding it (or
    ``TB2J_results/exchange.out``).

    Conversion: TB2J writes E = −Σ_{i≠j} J^TB2J_ij S_i·S_j with unit vectors S
    and every ordered pair (i, j) and (j, i) in the sum, J in meV. ase_spin
    counts each pair once, E = −Σ_{i<j} J_ij s_i·s_j, in eV, so

        J_ij = 2 × 10⁻³ × J^TB2J_ij.

    The two directions of a pair (i, j, R) and (j, i, −R) become one row (their
    mean, with a warning when they differ by more than TB2J's printed
    precision); a pair listed in one direction only is kept, with a warning
    counting such pairs (TB2J lists both: a file cut short loses them). Each
    pair's vector and distance are checked against the positions (the file's
    atoms section).

    Refused with a ValueError naming the file and line: binary content, a
    line in the Exchange section that starts like a pair line but does not
    read as one (or ends the file without a newline), labels that name no
    element, NaN/inf numbers, lattice images more than
    :data:`MAX_TB2J_CELLS` cells away.
    """
    path, atoms, i, j, R, J_tb2j, line_no, _, _ = _read_exchange_file(path)
    cell, pos = atoms.cell.array, atoms.positions
    keep = ~((i == j) & (R == 0).all(axis=1))  # TB2J may list an on-site entry

    # one row per unordered pair: (a, b, S) with a < b, or a == b and S > 0
    swap = (j < i) | ((j == i) & _lex_negative(R))
    a = np.where(swap, j, i)[keep]
    b = np.where(swap, i, j)[keep]
    S = np.where(swap[:, None], -R, R)[keep]
    J_tb2j, line_no = J_tb2j[keep], line_no[keep]
    keys = np.column_stack([a, b, S])
    uniq, inv, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    inv = inv.ravel()
    total = np.bincount(inv, weights=J_tb2j)
    lo = np.full(len(uniq), np.inf)
    hi = np.full(len(uniq), -np.inf)
    np.minimum.at(lo, inv, J_tb2j)
    np.maximum.at(hi, inv, J_tb2j)
    if (hi - lo > 2e-4).any():  # meV: twice TB2J's printed precision
        q = int(np.argmax(hi - lo))
        warn_user(f"{path}: the two directions of the pair {uniq[q].tolist()} have J "
                  f"{lo[q]} and {hi[q]} meV; using their mean")
    single = int((counts == 1).sum())
    if single:
        warn_user(f"{path}: {single} of the {len(uniq)} pairs are listed in one direction "
                  f"only (TB2J lists both (i, j, R) and (j, i, -R)): the file may be cut "
                  f"short or edited")
    Jbar = total / counts
    ia, ib, Su = uniq[:, 0], uniq[:, 1], uniq[:, 2:]
    dist = np.linalg.norm(pos[ib] + Su @ cell - pos[ia], axis=1)
    order = np.lexsort((ib, ia, dist))
    return TB2JExchange(atoms=atoms, i=ia[order], j=ib[order], R=Su[order],
                        distance=dist[order], J=2.0 * MEV * Jbar[order])


def _lex_negative(S):
    first = np.argmax(S != 0, axis=1)
    return S[np.arange(len(S)), first] < 0


def _read_exchange_file(path):
    """The parts of TB2J's ``exchange.out`` every reader needs: (path, atoms,
    i, j, R, J (meV), line numbers, DMI (meV, (n, 3), NaN where a pair has
    none), J_ani (meV, (n, 3, 3), NaN where none)), each listed pair as
    written, its vector and distance checked against the positions."""
    path = os.fspath(path)
    if os.path.isdir(path):
        for name in ("exchange.out", os.path.join("TB2J_results", "exchange.out")):
            if os.path.isfile(os.path.join(path, name)):
                path = os.path.join(path, name)
                break
        else:
            raise FileNotFoundError(f"no exchange.out in {path}")
    with open(path, "rb") as f:
        raw = f.read()
    if b"\0" in raw:
        raise ValueError(f"{path}: not a text file (contains NUL bytes): not a TB2J "
                         "exchange.out file")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as err:
        raise ValueError(f"{path}: not a text file (byte {err.start} is not UTF-8): not a "
                         "TB2J exchange.out file") from None
    lines = text.splitlines()
    cut = bool(text) and not text.endswith(("\n", "\r"))  # TB2J ends every line

    k = _find(lines, "Cell (Angstrom)", path)
    try:
        cell = np.array([[float(x) for x in lines[k + n].split()] for n in (1, 2, 3)])
    except (ValueError, IndexError):
        raise ValueError(f"{path}: line {k + 2}: the cell must be three rows of three numbers")
    if cell.shape != (3, 3):
        raise ValueError(f"{path}: line {k + 2}: the cell must be three rows of three numbers")
    if not np.isfinite(cell).all():
        raise ValueError(f"{path}: line {k + 2}: the cell must be finite, got {cell.tolist()}")

    k = _find(lines, "Atoms:", path)
    labels, positions, moments = [], [], []
    for n in range(k + 1, len(lines)):
        words = lines[n].split()
        if lines[n].startswith("=") or lines[n].startswith("-"):
            break
        if not words or not re.fullmatch(r"[A-Z][a-z]?\d+", words[0]):
            continue  # the note, the column titles, "Total" lines
        try:
            values = [float(x) for x in words[1:]]
        except ValueError:
            raise ValueError(f"{path}: line {n + 1}: expected a label and numbers: {lines[n]!r}")
        if len(values) not in (5, 7):
            raise ValueError(f"{path}: line {n + 1}: expected x y z charge and a moment "
                             f"(1 or 3 numbers): {lines[n]!r}")
        if not np.isfinite(values).all():
            raise ValueError(f"{path}: line {n + 1}: the position, charge and moment must be "
                             f"finite: {lines[n]!r}")
        symbol = re.match(r"[A-Z][a-z]?", words[0]).group()
        if symbol not in atomic_numbers:
            raise ValueError(f"{path}: line {n + 1}: the label {words[0]!r} names no chemical "
                             f"element ({symbol!r})")
        labels.append(words[0])
        positions.append(values[:3])
        moments.append(values[4] if len(values) == 5 else values[4:7])
    if not labels:
        raise ValueError(f"{path}: no atoms in the Atoms section")
    symbols = [re.match(r"[A-Z][a-z]?", s).group() for s in labels]
    atoms = Atoms(symbols, positions=positions, cell=cell, pbc=True)
    atoms.set_initial_magnetic_moments(np.array(moments))
    index = {s: n for n, s in enumerate(labels)}

    k = _find(lines, "Exchange:", path)
    rows, dmi, jani, unused = [], {}, {}, set()
    for n in range(k + 1, len(lines)):
        if lines[n].startswith("="):
            break
        m = _PAIR.match(lines[n])
        if not m:
            if rows and _pair_detail(lines, n, path, len(rows) - 1, dmi, jani, unused):
                continue
            if _PAIR_START.match(lines[n]):
                raise ValueError(f"{path}: line {n + 1}: a pair line that does not read as "
                                 f"'i j (R1, R2, R3) J_iso (x, y, z) distance': {lines[n]!r}")
            continue
        if cut and n == len(lines) - 1:
            raise ValueError(f"{path}: line {n + 1}: the file ends within this pair line (no "
                             f"newline after it): it may be cut short: {lines[n]!r}")
        a, b = m.group(1), m.group(2)
        for lab in (a, b):
            if lab not in index:
                raise ValueError(f"{path}: line {n + 1}: atom {lab} is not in the Atoms section")
        R = [int(m.group(g)) for g in (3, 4, 5)]
        if max(abs(x) for x in R) > MAX_TB2J_CELLS:
            raise ValueError(f"{path}: line {n + 1}: the lattice image R = {tuple(R)} is more "
                             f"than {MAX_TB2J_CELLS} cells away")
        try:
            J, vx, vy, vz, dist = (float(m.group(g)) for g in (6, 7, 8, 9, 10))
        except ValueError:
            raise ValueError(f"{path}: line {n + 1}: unreadable numbers in {lines[n]!r}")
        if not np.isfinite([J, vx, vy, vz, dist]).all():
            raise ValueError(f"{path}: line {n + 1}: J, the vector and the distance must be "
                             f"finite: {lines[n]!r}")
        rows.append((index[a], index[b], *R, J, vx, vy, vz, dist, n + 1))
    if not rows:
        raise ValueError(f"{path}: no exchange pairs in the Exchange section")
    data = np.array(rows, dtype=float)
    i, j = data[:, 0].astype(int), data[:, 1].astype(int)
    R = data[:, 2:5].astype(int)
    J_tb2j, vec, line_no = data[:, 5], data[:, 6:9], data[:, 10].astype(int)

    pos = atoms.positions
    d = pos[j] + R @ cell - pos[i]
    bad = np.linalg.norm(d - vec, axis=1) > 2e-3  # the file prints 3 decimals
    if bad.any():
        q = int(np.argmax(bad))
        raise ValueError(f"{path}: line {line_no[q]}: the pair's vector {vec[q].tolist()} is not "
                         f"r_j + R·cell − r_i = {np.round(d[q], 4).tolist()} from the atoms section")
    bad = np.abs(np.linalg.norm(d, axis=1) - data[:, 9]) > 2e-3
    if bad.any():
        q = int(np.argmax(bad))
        raise ValueError(f"{path}: line {line_no[q]}: the pair's distance {data[q, 9]} is not "
                         f"|r_j + R·cell − r_i| = {np.linalg.norm(d[q]):.4f} Å")
    if unused:
        warn_user(f"{path}: lines not used by ase_spin: {', '.join(sorted(unused))} (only "
                  "J_iso, DMI and J_ani enter the Hamiltonian)")
    D = np.full((len(rows), 3), np.nan)
    A = np.full((len(rows), 3, 3), np.nan)
    for q, v in dmi.items():
        D[q] = v
    for q, v in jani.items():
        A[q] = v
    return path, atoms, i, j, R, J_tb2j, line_no, D, A


#: A pair's DMI line, ``[Testing!] DMI: ( 0.1234 -0.0100  0.0000)`` (meV).
_DMI = re.compile(r"^\s*(?:\[[^\]]*\]\s*)?DMI:\s*\(\s*(\S+?),?\s+(\S+?),?\s+(\S+?)\s*\)\s*$")
#: The header of a pair's anisotropic tensor, ``[Testing!]J_ani:``, then three rows.
_JANI = re.compile(r"^\s*(?:\[[^\]]*\]\s*)?J_ani:\s*$")
#: A row of J_ani as numpy prints it: ``[[ 0.1  0.  -0.2]``, `` [ 0.  0.3  0. ]]``.
_MATRIX_ROW = re.compile(r"^\s*\[?\s*\[[-+0-9.eE\s]*\]\]?\s*$")
#: Other per-pair lines TB2J writes: named in a warning, not used.
_OTHER = re.compile(r"^\s*(?:\[[^\]]*\]\s*)?([A-Za-z][\w/()_]*)\s*:")


def _pair_detail(lines, n, path, q, dmi, jani, unused):
    """Read line n as a detail of pair q (DMI vector, the first row of J_ani,
    another quantity); True if it was one (J_ani's other rows are read here too)."""
    line = lines[n]
    m = _DMI.match(line)
    if m:
        try:
            v = np.array([float(m.group(g)) for g in (1, 2, 3)])
        except ValueError:
            raise ValueError(f"{path}: line {n + 1}: unreadable DMI vector: {line!r}") from None
        if not np.isfinite(v).all():
            raise ValueError(f"{path}: line {n + 1}: the DMI vector must be finite: {line!r}")
        dmi[q] = v
        return True
    if _JANI.match(line):
        try:
            text = " ".join(lines[n + 1:n + 4]).replace("[", " ").replace("]", " ")
            v = np.array([float(x) for x in text.split()]).reshape(3, 3)
        except (ValueError, IndexError):
            raise ValueError(f"{path}: line {n + 2}: J_ani must be three rows of three "
                             f"numbers: {lines[n + 1:n + 4]!r}") from None
        if not np.isfinite(v).all():
            raise ValueError(f"{path}: line {n + 2}: J_ani must be finite")
        jani[q] = v
        return True
    if _MATRIX_ROW.match(line):  # J_ani's rows, already read
        return True
    m = _OTHER.match(line)
    if m and not _PAIR_START.match(line):
        if m.group(1) not in ("J_iso",):
            unused.add(m.group(1))
        return True
    return False


def read_tb2j_pairs(path, **kwargs):
    """TB2J's ``exchange.out`` pair by pair, with every pair kept (no
    averaging): a :class:`~ase_spin.terms.pair_couplings.PairCouplings` on the
    file's cell with the isotropic J, the DMI vectors D and the anisotropic
    tensors Γ TB2J gives (``kwargs``: the term's ``decay``, ``shape``, ``rc``,
    ``tolerance``). ``path``: the file or a directory holding it.

    Conversion (TB2J: E = −Σ_{i≠j}[J S_i·S_j + D_ij·(S_i × S_j) + S_i J^ani S_j]
    over ordered pairs, meV; ase_spin: each pair once, eV)::

        J = 2·10⁻³ J_iso,  D = 2·10⁻³ D_ij,  Γ = 2·10⁻³ (J^ani − tr J^ani/3),

    the trace of J^ani (isotropic) added to J. Both directions of a pair are
    merged (their mean, a warning when they differ beyond TB2J's printed
    precision; D_ji = −D_ij). Not mapped, with a warning: on-site entries
    (i = j, R = 0; dropped), pairs without a DMI or J_ani line when others
    have them (taken as zero), lines of other quantities (dJ/dx, J_iso(Bruno),
    DMI_NJt, ...: named, not used); a pair listed in one direction only is
    kept with a warning. Errors as :func:`read_tb2j`."""
    path, atoms, i, j, R, J, line_no, D, A = _read_exchange_file(path)
    onsite = (i == j) & (R == 0).all(axis=1)
    if onsite.any():
        warn_user(f"{path}: {int(onsite.sum())} on-site entries (i = j, R = 0) dropped: a "
                  "single-ion term is an anisotropy, not a pair")
    keep = ~onsite
    i, j, R, J, D, A = i[keep], j[keep], R[keep], J[keep], D[keep], A[keep]
    for name, x in (("DMI", D), ("J_ani", A)):
        missing = np.isnan(x.reshape(len(x), -1)).any(axis=1)
        if missing.any() and not missing.all():
            warn_user(f"{path}: {int(missing.sum())} of {len(x)} pairs have no {name} line: "
                      "taken as zero")
    D = np.nan_to_num(D)
    A = np.nan_to_num(A)
    trace = np.trace(A, axis1=1, axis2=2) / 3.0
    if (np.abs(trace) > 1e-3).any():  # meV: J_ani is printed to 3 decimals
        warn_user(f"{path}: J_ani has a trace for {int((np.abs(trace) > 1e-3).sum())} pairs "
                  "(up to {:.3g} meV): moved into J (the same energy)".format(np.abs(trace).max()))
    Gamma = A - trace[:, None, None] * np.eye(3)
    # the symmetric part only: an antisymmetric part of J_ani would be a DMI
    asym = 0.5 * (Gamma - np.swapaxes(Gamma, 1, 2))
    if (np.abs(asym) > 1e-3).any():
        warn_user(f"{path}: J_ani is not symmetric (up to {np.abs(asym).max():.3g} meV off): "
                  "its antisymmetric part is dropped (TB2J gives the DMI apart)")
    Gamma = Gamma - asym
    scale = 2.0 * MEV
    # TB2J prints 4 decimals of meV: directions within twice that agree
    a, b, S, Jm, Dm, Gm, counts = merge_directions(
        i, j, R, scale * (J + trace), scale * D, scale * Gamma, path, atol=scale * 2e-4)
    single = int((counts == 1).sum())
    if single:
        warn_user(f"{path}: {single} of the {len(counts)} pairs are listed in one direction "
                  f"only (TB2J lists both (i, j, R) and (j, i, -R)): the file may be cut "
                  f"short or edited")
    Gm = 0.5 * (Gm + np.swapaxes(Gm, 1, 2))
    Gm -= np.trace(Gm, axis1=1, axis2=2)[:, None, None] / 3.0 * np.eye(3)
    return PairCouplings(atoms, a, b, S, Jm, Dm, Gm, **kwargs)
