"""The symmetric Suzuki–Trotter splitting of LAMMPS ``fix nve/spin``: the baseline.

Tranchida, Plimpton, Thibaudeau & Thompson, J. Comput. Phys. 372, 406 (2018);
Omelyan, Mryglod & Folk (2001). The same step as LAMMPS, compiled, on the same
Hamiltonian interface as :class:`~ase_spin.md.collective.CollectivePRK`, so the
two families of methods can be compared on any scene, including ones LAMMPS
cannot express (the paper's chain with its cubic J).
"""

from __future__ import annotations

import numba as nb
import numpy as np
from ase import units

from .._jit.cloning import compile_with
from ..terms.skeletons import linear_pair_field
from . import kernels
from .base import SpinLatticeDynamics
from .errors import UnstableStepError

#: Largest rotation (rad) of one spin in one sweep before the step is refused:
#: far beyond it the splitting is meaningless (the Cayley rotation saturates at π).
MAX_SWEEP_ROTATION = 1.0

__all__ = ["SuzukiTrotter"]


class SuzukiTrotter(SpinLatticeDynamics):
    r"""Spin–lattice dynamics by the symmetric splitting LAMMPS ``fix nve/spin`` uses.

    One step of size h, for the same equations of motion as
    :class:`CollectivePRK` (ds_i/dt = ω_i × s_i with ω_i = −(σ/ħ) B_i):

    1. p ← p + h/2 F(q, s)
    2. spins by h/2: a forward sweep i = 0 … N−1 then a backward sweep
       i = N−1 … 0, each spin rotated by h/4 about its field ω_i computed from
       the current (partly updated) spins at q
    3. q ← q + h p/m
    4. spins by h/2 again, at the new q
    5. p ← p + h/2 F(q, s)

    Second order and symmetric; each sweep is sequential (one spin at a time).
    ``rotation="cayley"`` is LAMMPS's rotation,

    .. math:: \mathbf s' = \frac{\mathbf s + \boldsymbol\theta\times\mathbf s
        + \tfrac12[\boldsymbol\theta(\boldsymbol\theta\cdot\mathbf s)
        - \tfrac12 \mathbf s\,\theta^2]}{1 + \tfrac14\theta^2},
        \qquad \boldsymbol\theta = \boldsymbol\omega_i\, h/4,

    a rotation by 2 arctan(θ/2); ``rotation="exact"`` rotates by θ itself.
    With ``rotation="cayley"`` and LAMMPS's ħ it reproduces LAMMPS step for step.
    ``order`` 4 and 6 compose the step as for :class:`CollectivePRK`.

    Any spin terms whose operators offer a per-spin field (``site``; every term
    in this package does), up to :data:`MAX_SITE_TERMS` of them. A scene
    with exchange alone runs a cached compiled sweep; other combinations
    compile theirs on first use in each process (about a second).
    """

    half_lists = False  # the sweeps gather each spin's field from a full list

    def __init__(self, atoms, timestep, *, hbar=None, precession=None,
                 gyromagnetic=None, g=None, rotation="cayley", order=2, composition=None,
                 lattice="moving", **kwargs):
        if not isinstance(rotation, str) or rotation not in ("cayley", "exact"):
            raise ValueError(f'rotation must be "cayley" or "exact", got {rotation!r}')
        self.rotation = rotation
        super().__init__(atoms, timestep, hbar=hbar, precession=precession,
                         gyromagnetic=gyromagnetic, g=g, order=order,
                         composition=composition, lattice=lattice, **kwargs)

    def todict(self):
        return {**super().todict(), "rotation": self.rotation}

    def _prepare(self, st):
        st.end_forces = None

    def _substep(self, h, stage, want_energy):
        st = self._state
        if not self.magnetic:
            self._lattice_step(h, want_energy)
            return 0, 0
        if self.frozen:
            self._spin_half_step(st.ops, h)
            self._spin_half_step(st.ops, h)
            return 0, 0
        ev = self.ev
        # F(q, s) from the end of the last (sub)step, else computed
        F = st.end_forces if st.end_forces is not None else self._spin_forces(st.ops, st.s,
                                                                              st.FL)
        # the kick and the drift in one pass (the spin half step between them
        # touches neither q nor p)
        qt, P, st.carry_q, moved, atom, _, _ = self._kick_drift(F, st.q, h, st.q)
        self._spin_half_step(st.ops, h)
        self._check_moved(moved, atom, h)
        st.ops = ev.spin_operators(qt, out=st.ops, half=False)
        self._spin_half_step(st.ops, h)
        self._lattice_at(qt, want_energy)
        F = self._spin_forces(st.ops, st.s, st.FL)
        kernels.kick(P, 0.5 * h, self._md_forces(F, qt), st.carry_mid, P, st.carry_p)
        st.q, st.p = qt, self._adjust_momenta(P, qt)
        st.end_forces = F
        return 0, 1

    def _spin_half_step(self, operators, h):
        tau = (-0.25 * h * self.sigma / self.hbar) * self._state.rate
        exact = self.rotation == "exact"
        s = self._state.s
        if len(operators) == 1 and operators[0].linear:
            pairs, J = operators[0].linear_pairs()
            angle = rotate_sweeps(pairs.row, pairs.j, J, s, tau, exact)
        else:
            functions, data = _site_arguments(operators)
            angle = rotate_sweeps_sites(functions)(s, tau, exact, *data)
        if not angle <= MAX_SWEEP_ROTATION:
            raise UnstableStepError(
                f"a spin was to rotate by {angle:.3g} rad in one sweep (h/4·|B|/ħ) at step "
                f"{self.nsteps}; above {MAX_SWEEP_ROTATION} rad the splitting is "
                f"meaningless. Reduce the timestep (now {self.dt / units.fs:.4g} fs) or "
                f"check hbar ({self.hbar:.4g}). The atoms keep the state before this step.")


#: Spin terms the sequential sweeps take at once.
MAX_SITE_TERMS = 6


@nb.njit(cache=True, inline="always")
def _no_site(i, s, data):
    return 0.0, 0.0, 0.0


_NO_DATA = (np.zeros(0),)


def _site_arguments(operators):
    """((f0, …, f5), (d0, …, d5)): every operator's per-spin field function and
    its data, padded with a function giving zero."""
    if len(operators) > MAX_SITE_TERMS:
        raise ValueError(f"SuzukiTrotter takes at most {MAX_SITE_TERMS} spin terms, "
                         f"got {len(operators)}")
    functions = []
    data = []
    for op in operators:
        if op.site is None:
            why = getattr(op, "site_unavailable", None)
            raise ValueError(f"SuzukiTrotter needs each spin term's field spin by spin; "
                             f"{type(op).__name__} does not offer it (its 'site')"
                             + (f": {why}" if why else ""))
        f, d = op.site
        functions.append(f)
        data.append(d)
    for _ in range(MAX_SITE_TERMS - len(operators)):
        functions.append(_no_site)
        data.append(_NO_DATA)
    return tuple(functions), tuple(data)


@nb.njit(cache=True, inline="always")
def _plus(a, b):
    return a[0] + b[0], a[1] + b[1], a[2] + b[2]


@nb.njit(cache=True, inline="always")
def _rotate(s, i, tx, ty, tz, exact):
    """Rotate spin i in place by θ = (tx, ty, tz) (Cayley or exact); returns θ²."""
    sx = s[i, 0]
    sy = s[i, 1]
    sz = s[i, 2]
    t2 = tx * tx + ty * ty + tz * tz
    cx = ty * sz - tz * sy  # θ × s
    cy = tz * sx - tx * sz
    cz = tx * sy - ty * sx
    ts = tx * sx + ty * sy + tz * sz
    if exact:
        angle = np.sqrt(t2)
        if angle == 0.0:
            return t2
        c = np.cos(angle)
        sn = np.sin(angle) / angle
        f = (1.0 - c) / t2
        s[i, 0] = sx * c + cx * sn + tx * ts * f
        s[i, 1] = sy * c + cy * sn + ty * ts * f
        s[i, 2] = sz * c + cz * sn + tz * ts * f
    else:
        d = 1.0 + 0.25 * t2
        s[i, 0] = (sx + cx + 0.5 * (tx * ts - 0.5 * sx * t2)) / d
        s[i, 1] = (sy + cy + 0.5 * (ty * ts - 0.5 * sy * t2)) / d
        s[i, 2] = (sz + cz + 0.5 * (tz * ts - 0.5 * sz * t2)) / d
    return t2


@nb.njit(cache=True)
def rotate_sweeps(row, nbr, J, s, tau, exact):
    """A forward then a backward sweep over the spins, in place: spin i is
    rotated about its current field, θ = τ_i B_i with B_i = Σ_j J_ij s_j from the
    spins as they are at that moment (so later spins see earlier updates).
    Cayley rotation (LAMMPS's AdvanceSingleSpin) or the exact one. Spins with
    τ_i = 0 (pinned: ase_spin.FixSpins) are not touched. Returns the
    largest |θ| (NaN if a field was not finite)."""
    n = len(row) - 1
    largest = 0.0
    for sweep in range(2):
        for a in range(n):
            i = a if sweep == 0 else n - 1 - a
            c = tau[i]
            # no spin; or pinned (rate 0): left as it is, to the bit
            if (s[i, 0] == 0.0 and s[i, 1] == 0.0 and s[i, 2] == 0.0) or c == 0.0:
                continue
            tx, ty, tz = linear_pair_field(i, s, row, nbr, J)
            t2 = _rotate(s, i, c * tx, c * ty, c * tz, exact)
            if not t2 <= largest and largest == largest:  # a NaN stays
                largest = t2
    return np.sqrt(largest)


def _sweeps_sites(s, tau, exact, d0, d1, d2, d3, d4, d5):
    """:func:`rotate_sweeps` for any spin terms: B_i is the sum of each term's
    per-spin field ``f_k(i, s, d_k)`` at the spins as they are (the f_k are
    bound as globals by :func:`rotate_sweeps_sites`)."""
    n = s.shape[0]
    largest = 0.0
    for sweep in range(2):
        for a in range(n):
            i = a if sweep == 0 else n - 1 - a
            c = tau[i]
            if (s[i, 0] == 0.0 and s[i, 1] == 0.0 and s[i, 2] == 0.0) or c == 0.0:
                continue  # no spin, or pinned (rate 0)
            t = f0(i, s, d0)  # noqa: F821 - bound per combination of terms
            t = _plus(t, f1(i, s, d1))  # noqa: F821
            t = _plus(t, f2(i, s, d2))  # noqa: F821
            t = _plus(t, f3(i, s, d3))  # noqa: F821
            t = _plus(t, f4(i, s, d4))  # noqa: F821
            tx, ty, tz = _plus(t, f5(i, s, d5))  # noqa: F821
            t2 = _rotate(s, i, c * tx, c * ty, c * tz, exact)
            if not t2 <= largest and largest == largest:  # a NaN stays
                largest = t2
    return np.sqrt(largest)


_SWEEPS = {}


def rotate_sweeps_sites(functions):
    """The compiled :func:`_sweeps_sites` for six per-spin field functions,
    called as ``(s, tau, exact, d0, …, d5)``. Compiled once per combination of
    terms and kept in numba's disk cache (a kernel taking the functions as
    arguments cannot be cached, and was compiled again in every process)."""
    sweeps = _SWEEPS.get(functions)
    if sweeps is None:
        names = "_".join(f.py_func.__name__.strip("_") for f in functions if f is not _no_site)
        sweeps = _SWEEPS[functions] = compile_with(
            _sweeps_sites, {f"f{k}": f for k, f in enumerate(functions)}, names[:60])
    return sweeps
