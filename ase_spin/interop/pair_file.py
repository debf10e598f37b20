"""A plain text format for pair-resolved couplings (fits, other codes), read
into and written from :class:`~ase_spin.terms.pair_couplings.PairCouplings`.

One pair per line, columns separated by blanks, ``#`` starts a comment::

    i  j  R1 R2 R3  J                                   (6 columns)
    i  j  R1 R2 R3  J  Dx Dy Dz                         (9 columns)
    i  j  R1 R2 R3  J  Dx Dy Dz  Gxx Gxy Gxz Gyx ... Gzz (18 columns)

``i``, ``j``: sites of the reference structure, counted from 0 as in ASE
(UppASD's ``jfile`` counts from 1: subtract 1); ``R``: the integer lattice
vector of j's cell (j at r_j + R·cell); J, D, Γ in the file's unit (eV or
meV), E = −Σ_{i<j} [J s_i·s_j + D·(s_i × s_j) + s_iᵀΓ s_j] with each pair
counted once: a pair may be listed in either direction, or in both (then
both must agree, (j, i, −R) carrying −D and Γᵀ, and it counts once). Γ is
symmetric and traceless: a trace read is added to J, an antisymmetric part
to D (the same energy; a warning beyond 10⁻⁶ eV, more than rounding).
"""

from __future__ import annotations

import os

import numpy as np

from ..terms.pair_couplings import PairCouplings, merge_directions
from ..validate import warn_user

__all__ = ["read_pairs", "write_pairs"]

#: Energy units a pair file may be written in (eV per unit).
UNITS = {"eV": 1.0, "meV": 1e-3}


def _unit(unit):
    if unit not in UNITS:
        raise ValueError(f"pair file unit must be one of {sorted(UNITS)}, got {unit!r}")
    return UNITS[unit]


def read_pairs(path, reference, unit="eV", **kwargs):
    """Pairs of a text file (module docstring) on ``reference`` (ase.Atoms:
    the cell and sites the indices and lattice vectors refer to) as a
    :class:`~ase_spin.terms.pair_couplings.PairCouplings` (``kwargs``: its
    ``decay``, ``shape``, ``rc``, ``tolerance``). ``unit``: "eV" or "meV".
    Lines that do not read as 6, 9 or 18 numbers (indices and R integers) are
    refused with a ValueError naming the file and line."""
    scale = _unit(unit)
    path = os.fspath(path)
    rows, where = [], []
    with open(path, encoding="utf-8") as f:
        for n, line in enumerate(f, 1):
            text = line.split("#", 1)[0].split()
            if not text:
                continue
            if len(text) not in (6, 9, 18):
                raise ValueError(f"{path}: line {n}: expected 6 (i j R1 R2 R3 J), 9 (+ Dx Dy Dz) "
                                 f"or 18 (+ 9 entries of Γ) columns, got {len(text)}: "
                                 f"{line.strip()!r}")
            try:
                ints = [int(x) for x in text[:5]]
                values = [float(x) for x in text[5:]]
            except ValueError:
                raise ValueError(f"{path}: line {n}: i j R1 R2 R3 must be integers and the rest "
                                 f"numbers: {line.strip()!r}") from None
            if not np.isfinite(values).all():
                raise ValueError(f"{path}: line {n}: the couplings must be finite: "
                                 f"{line.strip()!r}")
            rows.append(ints + values + [0.0] * (13 - len(values)))
            where.append(n)
    if not rows:
        raise ValueError(f"{path}: no pairs")
    data = np.array(rows, dtype=float)
    nsites = len(reference)
    ij = data[:, :2].astype(np.int64)
    bad = (ij < 0) | (ij >= nsites)
    if bad.any():
        q = int(np.argmax(bad.any(axis=1)))
        raise ValueError(f"{path}: line {where[q]}: sites {ij[q].tolist()} are not sites of the "
                         f"reference (0 to {nsites - 1}; indices count from 0)")
    R = data[:, 2:5].astype(np.int64)
    J, D, G = scale * data[:, 5], scale * data[:, 6:9], scale * data[:, 9:].reshape(-1, 3, 3)
    i, j, R, J, D, G, _ = merge_directions(ij[:, 0], ij[:, 1], R, J, D, G, path,
                                           atol=1e-9 * max(np.abs(data[:, 5:]).max(), 1.0) * scale)
    # Γ as written (rounded) may carry a trace or an antisymmetric part: they
    # are J and D (the same energy); more than rounding is said
    trace = np.trace(G, axis1=1, axis2=2) / 3.0
    asym = 0.5 * (G - np.swapaxes(G, 1, 2))
    moved = max(np.abs(trace).max(), np.abs(asym).max())
    if moved > _ROUNDING:
        warn_user(f"{path}: Γ is not symmetric and traceless (up to {moved:.3g} eV off): its "
                  "trace is added to J and its antisymmetric part to D (the same energy)")
    J = J + trace
    D = D + np.stack([asym[:, 1, 2], asym[:, 2, 0], asym[:, 0, 1]], axis=1)
    G = G - asym - trace[:, None, None] * np.eye(3)
    return PairCouplings(reference, i, j, R, J, D, G, **kwargs)


#: Parts of Γ (eV) below this are taken as rounding of the written numbers.
_ROUNDING = 1e-6


def write_pairs(path, couplings, unit="eV"):
    """Write the pairs of a :class:`PairCouplings` in the text format (each
    pair once, canonical orientation, 18 columns, numbers that read back to
    the same doubles)."""
    scale = _unit(unit)
    lines = [f"# ase_spin pair couplings: i j R1 R2 R3 J Dx Dy Dz G(3x3); energies in {unit}",
             "# E = -sum_{i<j} [J s_i.s_j + D.(s_i x s_j) + s_i^T G s_j], each pair once"]
    for k in range(len(couplings)):
        values = np.concatenate([[couplings.J[k]], couplings.D[k],
                                 couplings.Gamma[k].ravel()]) / scale
        lines.append(f"{couplings.i[k]} {couplings.j[k]} "
                     + " ".join(str(int(x)) for x in couplings.R[k]) + " "
                     + " ".join(repr(float(x)) for x in values))
    with open(os.fspath(path), "w", encoding="utf-8") as f:
        f.write("\n".join(lines) + "\n")
