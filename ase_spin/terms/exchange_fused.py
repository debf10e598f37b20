"""The exchange operator's pieces of the integrators' fused step for small
systems (:meth:`~ase_spin.terms.exchange.ExchangeOperator.compiled`,
:mod:`ase_spin.md.fused`): compiled functions calling the serial twins of the
exchange kernels (the geometry: serial in a tiny system, else threaded, chosen
at run time), as the operator's methods call them at that size. They exist only for the fused step's speed in small
systems (``benchmarks/small_systems.py``; docs/benchmarks.md, "Why each fast
path exists")."""

from __future__ import annotations

import numba as nb
import numpy as np

from .exchange_geometry import geometry_single
from .exchange_passes import add_kept_pass, forces_two_pass, spin_pass_half_kernel

__all__ = ["exchange_forces", "exchange_forces_two", "exchange_add_kept", "exchange_geometry",
           "exchange_couplings"]


_geometry_single_serial = geometry_single.serial
_forces_pass_serial = spin_pass_half_kernel.serial


@nb.njit(cache=True)
def exchange_forces(W, data, F):
    """F += the exchange forces at spins W (:meth:`ExchangeOperator.add`, forces
    only, serial twin, G kept): a piece of the fused step."""
    nthreads, row, nbr, image, images, J, G, Jbar, offset, params, tiny = data
    _forces_pass_serial(nthreads, row, nbr, image, images, J, np.zeros(0), G,
                        np.zeros((0, 3)), W, W, offset, np.zeros((0, 3)), F, np.zeros(0),
                        np.bool_(False), np.bool_(True), np.bool_(False), np.bool_(False),
                        np.bool_(False))  # not literals: see md/fused_skeletons.py


_forces_two_serial = forces_two_pass.serial
_add_kept_serial = add_kept_pass.serial


@nb.njit(cache=True)
def exchange_forces_two(W, data, there, F):
    """F += the exchange forces at spins W (data: the operator at q), and the
    forces of the operator ``there`` (at q̃, the same pairs) as per-thread
    partial sums, returned for :func:`exchange_add_kept`
    (:meth:`ExchangeOperator.forces_here_and_there`, serial twin): a piece of
    the fused step."""
    nthreads, row, nbr, image, images, J, G, Jbar, offset, params, tiny = data
    keep = np.empty((nthreads, len(row) - 1, 6))
    _forces_two_serial(nthreads, row, nbr, G, there[6], W, offset, F, keep, there[5],
                       np.zeros((0, 3)), np.zeros((0, 3)))
    return keep


@nb.njit(cache=True)
def exchange_add_kept(keep, base, out):
    """out = base + the kept partial sums (:func:`add_kept`): a piece of the fused step."""
    _add_kept_serial(keep, base, out)


_geometry_single_parallel = geometry_single.parallel


@nb.njit(cache=True)
def exchange_geometry(positions, data, other, serial):
    """J, G and the midpoint couplings J̄ = ½(J + J_other) at ``positions``
    (:meth:`Exchange.prepare` with ``out`` and ``mean_with``, one species):
    a piece of the fused step. The geometry kernel's serial twin in a tiny
    system (``tiny``: threads.tiny()) or where the step asks for it
    (``serial``: on one thread beside the lattice forces), else its threaded
    twin, as :meth:`Exchange.prepare` runs it (one result per pair: the same
    bits either way); one piece for both, so that one fused step serves every
    small size."""
    nthreads, row, nbr, image, images, J, G, Jbar, offset, params, tiny = data
    rc2, form, p0, p1, p2 = params[0], params[1], params[2], params[3], params[4]
    if tiny or serial:
        _geometry_single_serial(positions, row, nbr, image, images, rc2, form, p0, p1, p2, J,
                                np.zeros(0), G, other[5], Jbar)
    else:
        _geometry_single_parallel(positions, row, nbr, image, images, rc2, form, p0, p1, p2, J,
                                  np.zeros(0), G, other[5], Jbar)


@nb.njit(cache=True)
def exchange_couplings(data):
    """(row, nbr, J̄): the midpoint field B̄_i = Σ_j J̄_ij W_j on the half list."""
    return data[1], data[2], data[7]
