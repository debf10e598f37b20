"""Lennard-Jones pair potential, the spin-independent (lattice) term."""

from __future__ import annotations

import numba as nb
import numpy as np

from .._jit import threads
from .._jit.reductions import (add_row, reduce_scatter, reduce_threads, reduce_threads_serial,
                               scatter_buffers, store_sums, sub_row)
from .._jit.threads import threaded
from ..neighbors import separation
from ..validate import length
from .base import Term
from .lammps_form import LammpsPair, number_text
from .parameters import is_pair_mapping, pair_values, real_or_none, resolve_pairs

__all__ = ["LennardJones"]

_PLAIN, _SHIFT, _SMOOTH = 0, 1, 2
_MODES = {"plain": _PLAIN, "shift": _SHIFT, "smooth": _SMOOTH}
# Columns of the per-species-pair table.
_RC2, _EPS4, _SIG2, _MODE, _E0, _RO2 = range(6)


def _length_or_none(value, what):
    return None if value is None else length(value, what)


class LennardJones(Term):
    r"""Lennard-Jones pair potential (LAMMPS ``lj/cut``)

    .. math::

        u(r) = 4\varepsilon\left[(\sigma/r)^{12} - (\sigma/r)^{6}\right], \qquad r < r_c,

    summed once over every pair, :math:`E = \sum_{i<j} u(r_{ij})`.

    ``cutoff`` says what happens at :math:`r_c`:

    - ``"plain"``: plain truncation, :math:`u = 0` beyond :math:`r_c`; the energy
      jumps at :math:`r_c` (LAMMPS ``lj/cut`` default).
    - ``"shift"``: :math:`u(r) - u(r_c)`, continuous energy (LAMMPS
      ``pair_modify shift yes``; ASE's ``LennardJones(smooth=False)``).
    - ``"smooth"``: :math:`u(r)\,S(r)` with the switching function of ASE's
      ``LennardJones(smooth=True)`` (from jax-md / HOOMD-blue), in :math:`x = r^2`,

      .. math::

          S = 1 \ (r < r_o), \qquad
          S = \frac{(r_c^2 - r^2)^2 (r_c^2 + 2r^2 - 3r_o^2)}{(r_c^2 - r_o^2)^3}
          \ (r_o \le r < r_c), \qquad S = 0 \ (r \ge r_c),

      so energy and forces are continuous; the switch starts at ``r_on``
      (default ``0.66 * rc``, ASE's default).

    ``epsilon`` (eV), ``sigma`` (Å), ``rc`` (Å) and ``r_on`` are each either one
    number for all pairs or a mapping keyed by pairs of chemical symbols,
    ``{("Fe", "Fe"): 0.4, ("Fe", "Co"): 0.3, ...}``; ``epsilon=0`` or ``None``
    switches a pair off.
    """

    name = "lennard_jones"
    spin_dependent = False
    half_list = True

    _parameters = {"epsilon": "epsilon", "sigma": "sigma", "rc": "rc", "cutoff": "mode",
                   "r_on": "r_on"}

    def __init__(self, epsilon, sigma, rc, cutoff="plain", r_on=None):
        if not isinstance(cutoff, str) or cutoff not in _MODES:
            raise ValueError(f"LennardJones cutoff must be one of {sorted(_MODES)}, "
                             f"got {cutoff!r}")
        self.epsilon = pair_values(epsilon, "LennardJones epsilon", real_or_none)
        self.sigma = pair_values(sigma, "LennardJones sigma", _length_or_none)
        self.rc = pair_values(rc, "LennardJones rc", length)
        self.r_on = pair_values(r_on, "LennardJones r_on", real_or_none)
        self.mode = cutoff
        if (self.sigma is None and not is_pair_mapping(self.epsilon)
                and self.epsilon not in (None, 0.0)):
            raise ValueError(f"LennardJones sigma is None but epsilon is {self.epsilon}: "
                             "give sigma > 0 (or epsilon None to switch the term off)")
        rcs = list(self.rc.values()) if is_pair_mapping(self.rc) else [self.rc]
        if not rcs:
            raise ValueError("LennardJones rc: the mapping is empty")
        self.cutoff = float(max(rcs))
        self._finish()

    def __repr__(self):
        return (
            f"LennardJones(epsilon={self.epsilon!r}, sigma={self.sigma!r}, rc={self.rc!r}, "
            f"cutoff={self.mode!r})"
        )

    def bind(self, system):
        symbols = system.species.symbols
        eps = resolve_pairs(self.epsilon, symbols, "LennardJones epsilon")
        sig = resolve_pairs(self.sigma, symbols, "LennardJones sigma")
        rcs = resolve_pairs(self.rc, symbols, "LennardJones rc")
        ron = resolve_pairs(self.r_on, symbols, "LennardJones r_on")
        nt = len(symbols)
        table = np.zeros((nt, nt, 6))
        for a in range(nt):
            for b in range(nt):
                e, s, rc, ro = eps[a, b], sig[a, b], rcs[a, b], ron[a, b]
                if e is None or e == 0.0:
                    continue
                if s is None:
                    raise ValueError(
                        f"LennardJones sigma for the pair {symbols[a]}-{symbols[b]} is None "
                        f"but its epsilon is {e}: give sigma > 0 (or epsilon None)")
                ro = 0.66 * rc if ro is None else float(ro)
                if self.mode == "smooth" and not 0.0 <= ro < rc:
                    raise ValueError(f"LennardJones: need 0 <= r_on < rc, got r_on={ro}, rc={rc}")
                with np.errstate(over="ignore", invalid="ignore"):
                    sr6 = (np.float64(s) / rc) ** 6
                    row = (rc * rc, 4.0 * e, s * s, _MODES[self.mode],
                           4.0 * e * (sr6 * sr6 - sr6), ro * ro)
                if not np.isfinite(row).all():
                    raise ValueError(
                        f"LennardJones {symbols[a]}-{symbols[b]}: epsilon={e}, sigma={s}, "
                        f"rc={rc} overflow (4ε(σ/rc)¹² is not finite)")
                table[a, b] = row
        return table

    def lammps(self, types):
        """``pair_style lj/cut`` with one ``pair_coeff I J ε σ rc`` per pair of
        types (a switched-off pair: ε = 0); ``"shift"`` is ``pair_modify shift
        yes``. ``"smooth"`` is refused: LAMMPS's smoothed LJ styles (lj/smooth,
        lj/smooth/linear, lj/gromacs) switch the force, not the energy by this S(r)."""

        if self.mode == "smooth":
            raise NotImplementedError(
                'cutoff="smooth" (ASE\'s energy switching) has no LAMMPS pair style; '
                'use cutoff="shift" (pair_modify shift yes) or "plain"')
        symbols = types.symbols
        eps = resolve_pairs(self.epsilon, symbols, "LennardJones epsilon")
        sig = resolve_pairs(self.sigma, symbols, "LennardJones sigma")
        rcs = resolve_pairs(self.rc, symbols, "LennardJones rc")
        coeffs = []
        for i, j, _, _ in types.pairs():
            e, s, rc = eps[i - 1, j - 1], sig[i - 1, j - 1], rcs[i - 1, j - 1]
            if e is None or e == 0.0 or s is None:
                e, s = 0.0, 1.0
            coeffs.append((i, j, f"{number_text(e)} {number_text(s)} {number_text(rc)}"))
        return [LammpsPair("lj/cut", number_text(self.cutoff), coeffs,
                           ["shift yes"] if self.mode == "shift" else [])]

    def compute(self, positions, pairs, types, table, forces, energies, want):
        """Add this term's forces (and energies) into the given arrays.

        ``want`` is a :class:`~ase_spin.hamiltonian.Want`. Returns (energy, virial
        in Voigt order xx yy zz yz xz xy, eV).
        """
        out = _lj_kernel(threads.all_threads(), positions, pairs.row, pairs.j, pairs.image,
                     pairs.images, types, table, forces, energies, want.forces,
                     want.energy, want.energies, want.virial)
        return out[0], out[1:]

    def compiled_lattice(self, pairs, types, table):
        """The forces of :meth:`compute` as a compiled piece (see
        :meth:`Term.compiled_lattice`): the kernel's serial twin in a tiny
        system, else its threaded one, as :meth:`compute` runs it."""
        return _lj_forces, (threads.all_threads(), pairs.row, pairs.j, pairs.image,
                            pairs.images, types, table, threads.tiny())


@nb.njit(cache=True, inline="always")
def _lj_pair(r2, sig2, eps4, mode, e0, rc2, ro2):
    """u(r) and (du/dr)/r for one pair (r2 < rc²), from its row of the table.
    Scalars only: an array passed into an inlined function with branches
    costs a reference-count increment and decrement (two atomic calls) per
    pair, which numba's pruning does not remove (docs/benchmarks.md)."""
    sr2 = sig2 / r2
    sr6 = sr2 * sr2 * sr2
    u = eps4 * (sr6 * sr6 - sr6)
    du_r = eps4 * (6.0 * sr6 - 12.0 * sr6 * sr6) / r2
    if mode == _SHIFT:
        u -= e0
    elif mode == _SMOOTH and r2 > ro2:
        inv = 1.0 / ((rc2 - ro2) * (rc2 - ro2) * (rc2 - ro2))
        a = rc2 - r2
        sw = a * a * (rc2 + 2.0 * r2 - 3.0 * ro2) * inv
        dsw_dr2 = 6.0 * a * (ro2 - r2) * inv
        # d/dr (u S) / r = (du/dr / r) S + u dS/dr / r, with dS/dr / r = 2 dS/dr²
        du_r = du_r * sw + 2.0 * dsw_dr2 * u
        u *= sw
    return u, du_r


@threaded(always=True, reduce_threads=lambda: reduce_threads_serial)
def _lj_kernel(nthreads, pos, row, nbr, image, images, types, table, forces, energies,
               want_forces, want_energy, want_energies, want_virial):
    """Over a half pair list (each pair once), d_ij = r_j + S_ij − r_i:

    F_i += (u'(r)/r) d_ij,  F_j −= (u'(r)/r) d_ij,  e_i, e_j += ½ u(r),
    W += (u'(r)/r) d_ij ⊗ d_ij.

    Threads take runs of rows of equal pair count and scatter into their own
    buffers, summed at the end: half the pair work of a full list, no races.
    """
    bounds, fbuf, ebuf, acc = scatter_buffers(row, nthreads, want_forces, want_energies)
    # one species (the common case): no gather of the neighbour's type
    single = table.shape[0] == 1
    for c in nb.prange(nthreads):
        _lj_kernel_chunk(np.int64(c), want_forces, want_energies, bounds, types, want_virial, row,
                         nbr, single, pos, images, table, want_energy, fbuf, ebuf, image, acc)
    return reduce_scatter(reduce_threads, fbuf, forces, ebuf, energies, acc)


@nb.njit(cache=True, error_model="numpy")
def _lj_kernel_chunk(c, want_forces, want_energies, bounds, types, want_virial, row, nbr, single,
                     pos, images, table, want_energy, fbuf, ebuf, image, acc):
    """One chunk ``c`` of :func:`_lj_kernel`'s threaded loop: its work,
    compiled once for the threaded kernel and its serial twin."""
    e = vxx = vyy = vzz = vyz = vxz = vxy = 0.0
    for i in range(bounds[c], bounds[c + 1]):
        ti = types[i]
        fx = fy = fz = ei = 0.0
        for k in range(row[i], row[i + 1]):
            j = nbr[k]
            tj = 0 if single else types[j]
            dx, dy, dz, r2 = separation(pos, images, i, j, image[k])
            rc2 = table[ti, tj, _RC2]
            if r2 >= rc2:
                continue
            u, du_r = _lj_pair(r2, table[ti, tj, _SIG2], table[ti, tj, _EPS4],
                               table[ti, tj, _MODE], table[ti, tj, _E0], rc2,
                               table[ti, tj, _RO2])
            if want_energy or want_energies:
                ei += u
            if want_forces:
                gx = du_r * dx
                gy = du_r * dy
                gz = du_r * dz
                fx += gx
                fy += gy
                fz += gz
                sub_row(fbuf, c, j, 0, gx, gy, gz)
            if want_energies:
                ebuf[c, j, 0] += 0.5 * u
            if want_virial:
                vxx += du_r * dx * dx
                vyy += du_r * dy * dy
                vzz += du_r * dz * dz
                vyz += du_r * dy * dz
                vxz += du_r * dx * dz
                vxy += du_r * dx * dy
        if want_forces:
            add_row(fbuf, c, i, 0, fx, fy, fz)
        if want_energies:
            ebuf[c, i, 0] += 0.5 * ei
        e += ei
    store_sums(acc, c, e, vxx, vyy, vzz, vyz, vxz, vxy)


_lj_serial = _lj_kernel.serial
_lj_parallel = _lj_kernel.parallel


@nb.njit(cache=True)
def _lj_forces(positions, data, forces, serial):
    """F += the Lennard-Jones forces (:func:`_lj_kernel`, the chunks of
    ``data``): the term's piece of the fused step. The kernel's serial twin in
    a tiny system (``tiny``: threads.tiny()) or where the step asks for it
    (``serial``: made on one thread beside other work), else its threaded
    twin, as :meth:`LennardJones.compute` runs it (the same chunks, so the
    same bits); one piece for both, so that one fused step serves every small
    size."""
    nthreads, row, nbr, image, images, types, table, tiny = data
    # the flags are not literals: see md/fused_skeletons.py
    if tiny or serial:
        _lj_serial(nthreads, positions, row, nbr, image, images, types, table, forces,
                   np.zeros(0), np.bool_(True), np.bool_(False), np.bool_(False),
                   np.bool_(False))
    else:
        _lj_parallel(nthreads, positions, row, nbr, image, images, types, table, forces,
                     np.zeros(0), np.bool_(True), np.bool_(False), np.bool_(False),
                     np.bool_(False))
