"""The state an integrator holds between steps, and its bond with the Atoms:
the snapshot of what the state was derived from, the check that nothing changed
since (the Atoms, their calculator and its terms), the write-back of a step
whole or not at all, and the restore after a failed or interrupted one.

:class:`AtomsBond` is a part of :class:`~ase_spin.md.base.SpinLatticeDynamics`
(its methods read ``self.atoms``, ``self.ev``, ``self._state``).
"""

from __future__ import annotations

import copy

import numpy as np
from ase import units

from ..spins import name_atoms
from . import kernels
from .errors import IntegrationError

__all__ = ["State", "AtomsBond"]


class State:
    """What an integrator holds between steps (design.md, "one step as data").

    q, p, s, mu: positions, momenta, unit spins, moment magnitudes. FL: lattice
    forces at q. ops: the spin terms prepared at q (SpinOperators). EL, EL_terms: lattice
    energy when it was asked for. carry_*: rounding errors of the compensated
    updates. constraints: the Atoms' constraints on positions, forces and
    momenta (all but FixSpins); pinned: the spins FixSpins pins (a boolean
    (n,) array, or None), pinned_rows: those of them that are magnetic (their
    moments are never written back). Subclasses add their own fields in
    ``_prepare``.
    """

    def __init__(self, **fields):
        self.__dict__.update(fields)

    def __getstate__(self):
        # the fused step's compiled pieces are a cache, rebuilt on use: not data
        state = dict(self.__dict__)
        state.pop("fused", None)
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)


def _same(a, b):
    if a is None or b is None:
        return a is b
    if a.shape != b.shape or a.dtype != b.dtype:
        return False
    if a.nbytes <= 8192 and a.flags.c_contiguous and b.flags.c_contiguous:
        # small arrays: the bytes, cheaper than a compiled call in a small
        # system's step (benchmarks/small_systems.py; stricter too: -0.0 and
        # 0.0 differ, so at worst a needless resync)
        return a.tobytes() == b.tobytes()
    return kernels.same(a, b)


def _equal(x, y):
    """Deep equality of constraint contents (arrays, containers, attributes)."""
    if type(x) is not type(y):
        return False
    if isinstance(x, np.ndarray):
        return x.shape == y.shape and x.dtype == y.dtype and bool(
            np.array_equal(x, y, equal_nan=x.dtype.kind in "fc"))
    if isinstance(x, (list, tuple)):
        return len(x) == len(y) and all(_equal(a, b) for a, b in zip(x, y))
    if isinstance(x, dict):
        return x.keys() == y.keys() and all(_equal(x[k], y[k]) for k in x)
    if hasattr(x, "__dict__") and not callable(x):
        return _equal(vars(x), vars(y))
    try:
        return bool(x == y)
    except Exception:  # noqa: BLE001 - incomparable: treat as changed
        return False


class AtomsBond:
    """The state's bond with the Atoms (see the module docstring)."""

    def _remember_written(self):
        """Snapshot of everything the cached state was derived from. Kept by
        value (copies), not by identity: Python reuses ids and arrays are edited
        in place."""
        a = self.atoms
        arrays = a.arrays
        self._written = (arrays["positions"].copy(), _copy(arrays.get("momenta")),
                         _copy(arrays.get("initial_magmoms")), _copy(arrays.get("masses")),
                         a.cell.array.copy(), a.pbc.tolist(), a.numbers.copy(),
                         copy.deepcopy(a.constraints) if a.constraints else [],
                         self.ev.state_token)
        # the buffers the next step's snapshot of positions, momenta and moments
        # goes to (_commit: the ones held now stay intact for _restore); kept
        # while the size holds (this also runs after every step that cannot
        # take the compiled commit, e.g. without moments)
        shape = self._written[0].shape
        spare = getattr(self, "_spare", None)
        if spare is None or spare[0].shape != shape:
            self._spare = tuple(np.empty(shape) for _ in range(3))
        # whether the snapshot's positions, momenta and moments are all (n, 3)
        # float64 (only _commit's compiled pass sets it)
        self._snapshot_rows = False

    def _in_sync(self):
        """True if the Atoms, their calculator and its terms are as this
        integrator left them (else every cache is stale: a user moved atoms; set
        spins, momenta, masses, cell or constraints; changed a term's parameter;
        or the calculator served other Atoms in between)."""
        if self._state is None:
            return False
        a = self.atoms
        pos, mom, mag, masses, cell, pbc, numbers, cons, token = self._written
        arrays = a.arrays
        calc = self._calc
        # cheapest tests first: this runs before every step
        if not (a.calc is calc and calc.evaluator is self.ev
                and self.ev.state_token == token and not self.ev.stale()
                and len(a) == len(numbers) and a.pbc.tolist() == pbc
                and _same(a.cell.array, cell)):
            return False
        now = (arrays["positions"], arrays.get("momenta"), arrays.get("initial_magmoms"))
        shape = pos.shape
        if (self._snapshot_rows and _rows3(now[0], shape) and _rows3(now[1], shape)
                and _rows3(now[2], shape)):
            # the three arrays a step writes, in one compiled call
            same = kernels.same_rows(now[0], pos, now[1], mom, now[2], mag)
        else:
            same = _same(now[0], pos) and _same(now[1], mom) and _same(now[2], mag)
        return (same
                and _same(arrays.get("masses"), masses)
                and _same(arrays["numbers"], numbers)
                and (not cons and not a.constraints or _equal(list(a.constraints), cons)))

    def _sync(self):
        if not self._in_sync():
            self._state = None
            self._initialize()
        return self._state

    def _restore(self, snapshot):
        """Put the Atoms back as they were at ``snapshot`` (after a failed or
        interrupted step), in place where possible."""
        pos, mom, mag, *_ = snapshot
        arrays = self.atoms.arrays
        for name, saved in (("positions", pos), ("momenta", mom), ("initial_magmoms", mag)):
            now = arrays.get(name)
            if saved is None:
                arrays.pop(name, None)
            elif now is not None and now.shape == saved.shape and now.dtype == saved.dtype:
                now[:] = saved
            else:
                arrays[name] = saved.copy()

    def _check_state_finite(self):
        st = self._state
        for which, x in enumerate((st.q, st.p, st.s)):
            bad = kernels.first_nonfinite_row(x)
            if bad >= 0:
                self._raise_nonfinite(which, bad)

    def _raise_nonfinite(self, which, row):
        name = ("positions", "momenta", "spins")[which]
        raise IntegrationError(
            f"the step gave non-finite {name} ({name_atoms([row])}) at step "
            f"{self.nsteps}: the forces or fields are not finite or the timestep "
            f"({self.dt / units.fs:.4g} fs) is far too large. The atoms keep the "
            f"state before this step.")

    def _commit(self):
        """Write the new state into the Atoms, if it is finite (else
        :class:`IntegrationError`, nothing written): in place (so references to
        ``atoms.positions`` stay live), float64 whatever dtype the user's arrays
        had (an integer or float32 array is replaced, not truncated)."""
        st = self._state
        arrays = self.atoms.arrays
        written, spare = self._written, self._spare
        shape = st.q.shape
        pos, mom, mag = (arrays["positions"], arrays.get("momenta"),
                         arrays.get("initial_magmoms"))
        if (_rows3(pos, shape) and _rows3(mom, shape) and _rows3(written[1], shape)
                and _rows3(mag, shape) and _rows3(written[2], shape)
                and st.q.flags.c_contiguous and st.p.flags.c_contiguous
                and st.s.flags.c_contiguous):
            # the usual case, one compiled pass: the check, the writes and the
            # snapshot _in_sync compares with next time, into the spare buffers
            # (``written``'s stay as they are: the step's _restore may need them)
            which, row = kernels.commit_state(st.q, st.p, st.s, st.mu, self.magnetic, pos, mom,
                                              mag if self.magnetic else pos, *spare)
            if which >= 0:
                self._raise_nonfinite(which, row)
            moments = spare[2] if self.magnetic else written[2]
            if self.magnetic and st.pinned_rows is not None:
                _keep_pinned(st.pinned_rows, written[2], mag, moments)
            self._spare = (written[0], written[1], written[2] if self.magnetic else spare[2])
            # masses, cell, numbers, constraints: as at the last sync (a step
            # does not change them)
            self._written = (spare[0], spare[1], moments, *written[3:8], self.ev.state_token)
            self._snapshot_rows = True
            st.observables = None
            return
        self._check_state_finite()
        _write(arrays, "positions", st.q)
        _write(arrays, "momenta", st.p)
        if self.magnetic:
            now = arrays.get("initial_magmoms")
            if now is not None and now.dtype == np.float64 and now.shape == st.s.shape:
                np.multiply(st.mu[:, None], st.s, out=now)  # in place, no temporary
            else:
                _write(arrays, "initial_magmoms", st.mu[:, None] * st.s)
            if st.pinned_rows is not None:
                now = arrays["initial_magmoms"]
                _keep_pinned(st.pinned_rows, self._written[2], now, now)
        st.observables = None
        self._remember_written()


def _copy(a):
    return None if a is None else a.copy()


def _keep_pinned(rows, before, *outs):
    """The pinned spins' moments as the Atoms held them (``before``) into each
    of ``outs``: never written back, they stay as the user set them, to the
    bit (μ_i s_i, with s_i and μ_i split from them, may differ from them in
    the last bit; a later sync splits them again the same way)."""
    kept = before[rows]
    for out in outs:
        out[rows] = kept


_F64 = np.dtype(np.float64)


def _rows3(a, shape):
    """``a`` is a C-contiguous, writeable float64 array of ``shape`` ((n, 3)):
    what the compiled commit and check take (the cheap tests first: this runs
    at every step)."""
    return (a is not None and a.dtype is _F64 and a.shape == shape
            and a.flags.c_contiguous and a.flags.writeable)


def _write(arrays, name, values):
    """arrays[name] = values, in place if the array is float64 of that shape."""
    now = arrays.get(name)
    if now is not None and now.dtype == np.float64 and now.shape == values.shape:
        now[:] = values
    else:
        arrays[name] = np.array(values, dtype=np.float64)
