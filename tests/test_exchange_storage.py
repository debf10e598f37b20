"""The exchange operators keep, from exchange.PAIR_VECTORS_BELOW atoms on, one
double per pair, g = J'(r)/r, and their own copy of the positions, from which
the force and virial passes recompute d_ij = (r_j − r_i) + S_ij; below, the
vector G = J'(r) d/r (three doubles per pair) and the copy, from which the
virial recomputes d. Either must give the bits of the form the operators had
before: G and d both stored per pair.

The reference here is that stored form, built in this module: g from an
operator in the g form, d from the positions with numpy (independently of the
kernels' ``separation``), G = g d per pair, and the passes that read G and d
(the kernels as they were, verbatim but for their names). Runs of CollectivePRK
and Langevin with the package's terms, in either form, and with these reference
terms must agree bit for bit: positions, momenta, spins, forces, magnetic
forces and stress.
"""

import contextlib

import numba as nb
import numpy as np
import pytest
from ase import units

from ase_spin import CollectivePRK, Langevin, SpinLatticeCalculator, Want, get_spins, set_spins
from ase_spin._jit import threads
from ase_spin.md import fused
from ase_spin._jit.reductions import (balanced_chunks, reduce_threads, reduce_threads_serial,
    sum_over_threads)
from ase_spin.scenes import cone, fcc_cobalt, fcc_cobalt_terms
from ase_spin.terms import BetheSlater, BiquadraticExchange, Cubic, Exchange
from ase_spin.terms import exchange as exchange_module
from ase_spin.terms.base import SpinOperator, SpinTerm
from ase_spin._jit.threads import threaded

#: exchange.PAIR_VECTORS_BELOW for the package's operators in each form
FORMS = {"G": 10**12, "g": 0}


@contextlib.contextmanager
def _g_form():
    """Operators prepared inside are in the g form, whatever the system's size."""
    saved = exchange_module.PAIR_VECTORS_BELOW
    exchange_module.PAIR_VECTORS_BELOW = 0
    try:
        yield
    finally:
        exchange_module.PAIR_VECTORS_BELOW = saved


# -- the stored form: G = J'(r) d/r and d per pair, and the passes reading them -----------


@threaded()
def _stored_pass(nthreads, row, nbr, J, G, D, s, c, B, F, energies,
                 want_b, want_f, want_energy, want_energies, want_virial):
    """Full list, gather into i: B_i += Σ_j J s_j, F_i −= Σ_j w G,
    e_i −= ½ Σ_j J w, W −= ½ Σ w G ⊗ d (w = s_i·s_j − c), G and d read per pair."""
    bounds = balanced_chunks(row, nthreads)
    acc = np.zeros((nthreads, 7))
    need_dot = want_f or want_energy or want_energies or want_virial
    for t in nb.prange(nthreads):
        e = 0.0
        vxx = 0.0
        vyy = 0.0
        vzz = 0.0
        vyz = 0.0
        vxz = 0.0
        vxy = 0.0
        for i in range(bounds[t], bounds[t + 1]):
            sx = s[i, 0]
            sy = s[i, 1]
            sz = s[i, 2]
            bx = 0.0
            by = 0.0
            bz = 0.0
            fx = 0.0
            fy = 0.0
            fz = 0.0
            ei = 0.0
            for k in range(row[i], row[i + 1]):
                j = nbr[k]
                Jk = J[k]
                tx = s[j, 0]
                ty = s[j, 1]
                tz = s[j, 2]
                bx += Jk * tx
                by += Jk * ty
                bz += Jk * tz
                if need_dot:
                    w = sx * tx + sy * ty + sz * tz - c
                    fx -= w * G[k, 0]
                    fy -= w * G[k, 1]
                    fz -= w * G[k, 2]
                    ei -= 0.5 * Jk * w
                    if want_virial:
                        h = -0.5 * w
                        vxx += h * G[k, 0] * D[k, 0]
                        vyy += h * G[k, 1] * D[k, 1]
                        vzz += h * G[k, 2] * D[k, 2]
                        vyz += h * G[k, 1] * D[k, 2]
                        vxz += h * G[k, 0] * D[k, 2]
                        vxy += h * G[k, 0] * D[k, 1]
            if want_b:
                B[i, 0] += bx
                B[i, 1] += by
                B[i, 2] += bz
            if want_f:
                F[i, 0] += fx
                F[i, 1] += fy
                F[i, 2] += fz
            if want_energies:
                energies[i] += ei
            if want_energy:
                e += ei
        acc[t, 0] = e
        acc[t, 1] = vxx
        acc[t, 2] = vyy
        acc[t, 3] = vzz
        acc[t, 4] = vyz
        acc[t, 5] = vxz
        acc[t, 6] = vxy
    out = sum_over_threads(acc)
    return out[0], out[1], out[2], out[3], out[4], out[5], out[6]


@threaded(reduce_threads=lambda: reduce_threads_serial)
def _stored_pass_half(nthreads, row, nbr, J, G, D, s, c, B, F, energies,
                      want_b, want_f, want_energy, want_energies, want_virial):
    """Half list, scattering into per-thread buffers: B_i += J s_j, B_j += J s_i,
    F_i −= w G, F_j += w G, e_i, e_j −= ½ J w, W −= w G ⊗ d; G and d read per pair."""
    n = len(row) - 1
    bounds = balanced_chunks(row, nthreads)
    bbuf = np.zeros((nthreads, n if want_b else 0, 3))
    fbuf = np.zeros((nthreads, n if want_f else 0, 3))
    ebuf = np.zeros((nthreads, n if want_energies else 0, 1))
    acc = np.zeros((nthreads, 7))
    need_dot = want_f or want_energy or want_energies or want_virial
    for t in nb.prange(nthreads):
        e = 0.0
        vxx = 0.0
        vyy = 0.0
        vzz = 0.0
        vyz = 0.0
        vxz = 0.0
        vxy = 0.0
        for i in range(bounds[t], bounds[t + 1]):
            sx = s[i, 0]
            sy = s[i, 1]
            sz = s[i, 2]
            bx = 0.0
            by = 0.0
            bz = 0.0
            fx = 0.0
            fy = 0.0
            fz = 0.0
            ei = 0.0
            for k in range(row[i], row[i + 1]):
                j = nbr[k]
                Jk = J[k]
                ux = s[j, 0]
                uy = s[j, 1]
                uz = s[j, 2]
                if want_b:
                    bx += Jk * ux
                    by += Jk * uy
                    bz += Jk * uz
                    bbuf[t, j, 0] += Jk * sx
                    bbuf[t, j, 1] += Jk * sy
                    bbuf[t, j, 2] += Jk * sz
                if need_dot:
                    w = sx * ux + sy * uy + sz * uz - c
                    ei -= Jk * w
                    if want_energies:
                        ebuf[t, j, 0] -= 0.5 * Jk * w
                    gx = w * G[k, 0]
                    gy = w * G[k, 1]
                    gz = w * G[k, 2]
                    if want_f:
                        fx -= gx
                        fy -= gy
                        fz -= gz
                        fbuf[t, j, 0] += gx
                        fbuf[t, j, 1] += gy
                        fbuf[t, j, 2] += gz
                    if want_virial:
                        vxx -= gx * D[k, 0]
                        vyy -= gy * D[k, 1]
                        vzz -= gz * D[k, 2]
                        vyz -= gy * D[k, 2]
                        vxz -= gx * D[k, 2]
                        vxy -= gx * D[k, 1]
            if want_b:
                bbuf[t, i, 0] += bx
                bbuf[t, i, 1] += by
                bbuf[t, i, 2] += bz
            if want_f:
                fbuf[t, i, 0] += fx
                fbuf[t, i, 1] += fy
                fbuf[t, i, 2] += fz
            if want_energies:
                ebuf[t, i, 0] += 0.5 * ei
            e += ei
        acc[t, 0] = e
        acc[t, 1] = vxx
        acc[t, 2] = vyy
        acc[t, 3] = vzz
        acc[t, 4] = vyz
        acc[t, 5] = vxz
        acc[t, 6] = vxy
    reduce_threads(fbuf, F)
    reduce_threads(bbuf, B)
    reduce_threads(ebuf, energies.reshape((energies.shape[0], 1)))
    return sum_over_threads(acc)


def _stored_geometry(positions, pairs, g):
    """(G, d) per pair: d = (r_j − r_i) + S with numpy, G = g d."""
    d = (positions[pairs.j] - positions[pairs.i]) + pairs.shift
    return g[:, None] * d, d


class _StoredOperator(SpinOperator):
    """An exchange operator in the stored form: the package's operator (in the g
    form) for J, J̄ and the fields, forces and virial from G and d kept per pair."""

    linear = True  # its field is C s (linear_pairs)

    def __init__(self, op, positions):
        assert not op.stored
        self.op = op
        self.G, self.D = _stored_geometry(positions, op.pairs, op.g)

    def linear_pairs(self, mean=False):
        return self.op.linear_pairs(mean)

    def field(self, W, out, mean=False):
        self.op.field(W, out, mean)

    def add(self, W, want, magnetic_forces, forces, energies):
        p, op = self.op.pairs, self.op
        kernel = _stored_pass_half if p.half else _stored_pass
        out = kernel(threads.count(), p.row, p.j, op.J, self.G, self.D, W, op.offset,
                     magnetic_forces, forces, energies, want.magnetic_forces, want.forces,
                     want.energy, want.energies, want.virial)
        return out[0], np.array(out[1:])


class _StoredExchange(Exchange):
    """Exchange whose operators are :class:`_StoredOperator` (no fused pieces:
    its runs take CollectivePRK's general path)."""

    compute = SpinTerm.compute  # through the operators, as the runs

    def prepare(self, positions, pairs, types, bound, *, virial=False, out=None,
                mean_with=None):
        with _g_form():
            op = super().prepare(positions, pairs, types, bound, virial=virial,
                                 out=out.op if out is not None else None,
                                 mean_with=mean_with.op if mean_with is not None else None)
        return _StoredOperator(op, positions)


@nb.njit(cache=True, inline="always")
def _stored_biquadratic_energy(k, i, j, s, data):
    """e = −[J (w − c) + K (w² − c)], w = s_i·s_j; the force on j,
    f = (w − c) G + (w² − c) H from G = J' d/r and H = K' d/r read per pair; d."""
    J, K, G, H, D, c = data
    w = s[i, 0] * s[j, 0] + s[i, 1] * s[j, 1] + s[i, 2] * s[j, 2]
    a = w - c
    b = w * w - c
    e = -(J[k] * a + K[k] * b)
    fx = a * G[k, 0] + b * H[k, 0]
    fy = a * G[k, 1] + b * H[k, 1]
    fz = a * G[k, 2] + b * H[k, 2]
    return e, fx, fy, fz, D[k, 0], D[k, 1], D[k, 2]


class _StoredBiquadratic(BiquadraticExchange):
    """BiquadraticExchange reading G, H and d stored per pair."""

    pair_energy = _stored_biquadratic_energy

    def prepare(self, positions, pairs, types, bound, *, virial=False, out=None,
                mean_with=None):
        with _g_form():
            op = super().prepare(positions, pairs, types, bound, virial=virial, out=out,
                                 mean_with=mean_with)
        opJ, opK = op.extra
        G, D = _stored_geometry(positions, pairs, opJ.g)
        H, _ = _stored_geometry(positions, pairs, opK.g)
        c = 1.0 if self.offset else 0.0
        mean = (opJ.Jbar, opK.Jbar, G, H, D, c) if opJ.Jbar is not None else None
        stored = self.operator(pairs, (opJ.J, opK.J, G, H, D, c), mean)
        stored.extra = op.extra
        return stored


# -- the runs ------------------------------------------------------------------------------


def _bs():
    return BetheSlater(J1=0.0446928, J2=0.003496, J3=1.4885)


def _scene(n, spin_term):
    atoms = fcc_cobalt(n)
    atoms.calc = SpinLatticeCalculator([fcc_cobalt_terms()[0], spin_term])
    return atoms


def _run(atoms, steps, stress, dt=0.2 * units.fs, langevin=False):
    """A CollectivePRK (or Langevin) run; with ``stress``, the calculator's results
    (stress included: every operator's virial) published after every step."""
    if langevin:
        dyn = Langevin(atoms, dt, 300.0, spin_damping=0.1, friction=0.01 / units.fs, rng=3)
    else:
        dyn = CollectivePRK(atoms, dt)
    frames = []
    if stress:
        dyn.attach(lambda: frames.append((atoms.get_stress(), atoms.get_forces(),
                                          atoms.calc.results["magnetic_forces"].copy())),
                   interval=1)
    dyn.run(steps)
    dyn.publish_results()
    r = atoms.calc.results
    return [atoms.positions.copy(), atoms.get_momenta(), get_spins(atoms), r["forces"],
            r["magnetic_forces"], *(x for frame in frames for x in frame)]


@pytest.fixture
def fused_steps(monkeypatch):
    """Let N = 108 take the fused step one step at a time (the blocks of them,
    tested in test_small_systems.py, would compile a loop around every storage
    form's step), and count the fused steps."""
    monkeypatch.setattr(fused, "collective_block", lambda *args: (0, 0, 0, 0))
    from conftest import spy_fused

    used = spy_fused(monkeypatch)
    return used


@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("n, steps, stress, langevin", [
    (3, 20, False, False), (3, 8, True, False), (8, 4, False, False), (8, 3, True, False),
    (3, 10, False, True), (8, 3, False, True)])
def test_run_equals_stored_pair_vectors_bitwise(n, steps, stress, langevin, form, fused_steps,
                                                monkeypatch):
    """fcc Co, LJ + Bethe–Slater exchange, CollectivePRK and Langevin (whose
    steps may end on an operator prepared at a q̃ within 1e-10 Å of the
    final one): N = 108 (the fused step) and 2 048 (the threaded general
    path; the fused step for G without stress), with and without the stress
    published every step, the operators keeping G or g: bit for bit the run
    of the stored form."""
    monkeypatch.setattr(exchange_module, "PAIR_VECTORS_BELOW", FORMS[form])
    runs = []
    for term in (Exchange(_bs(), rc=4.0), _StoredExchange(_bs(), rc=4.0)):
        runs.append(_run(_scene(n, term), steps, stress, langevin=langevin))
        if term.__class__ is Exchange:
            # the fused step takes operators keeping G and no positions only
            assert (fused_steps["done"] > 0) == (n == 3 and not stress and form == "G")
    assert (len(runs[0]) > 5) == stress
    for a, b in zip(*runs):
        assert np.array_equal(a, b)
    if stress:
        assert np.abs(runs[0][5]).max() > 0.0


@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("n, stress", [(3, True), (6, False)])
def test_biquadratic_run_equals_stored_pair_vectors_bitwise(n, stress, form, monkeypatch):
    """LJ + bilinear and biquadratic Bethe–Slater exchange (with offset), 108 and
    864 atoms (threaded passes), operators keeping G or g: bit for bit the run
    of the stored form."""
    monkeypatch.setattr(exchange_module, "PAIR_VECTORS_BELOW", FORMS[form])
    def terms(cls):
        return cls(_bs(), BetheSlater(0.1 * 0.0446928, 0.0, 1.4885), rc=4.0, offset=True)

    runs = [_run(_scene(n, terms(cls)), 6, stress)
            for cls in (BiquadraticExchange, _StoredBiquadratic)]
    for a, b in zip(*runs):
        assert np.array_equal(a, b)


# -- the operators alone: every preparation branch, full and half lists ----------------


class _PythonCubic(Cubic):
    """The cubic coupling through its own values(r) (the user-coupling branch)."""

    _form = 3


def _couplings(kind):
    if kind == "bethe-slater":
        return _bs(), 4.0
    if kind == "python":
        return _PythonCubic(0.02, 4.0), None
    # two species: the per-pair table branch
    return {("Co", "Co"): _bs(), ("Co", "Fe"): BetheSlater(0.03, 0.01, 1.5),
            ("Fe", "Fe"): Cubic(0.02, 3.9)}, 4.0


@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("kind", ["bethe-slater", "python", "species"])
@pytest.mark.parametrize("half", [True, False])
@pytest.mark.parametrize("n", [3, 8])
def test_operator_equals_stored_pair_vectors_bitwise(kind, half, n, form, monkeypatch):
    """Forces, energies, per-atom energies, magnetic forces and the virial of an
    operator keeping G or g (serial at 108 atoms, threaded at 2 048), on
    rattled positions with atoms outside the cell, equal those of the stored
    form bit for bit; g is J'(r)/r of the coupling. The operator keeps its own
    copy of the positions: the caller's array may change."""
    monkeypatch.setattr(exchange_module, "PAIR_VECTORS_BELOW", FORMS[form])
    coupling, rc = _couplings(kind)
    atoms = fcc_cobalt(n, temperature_K=0.0)
    rng = np.random.default_rng(5)
    atoms.positions += rng.normal(scale=0.05, size=atoms.positions.shape)
    atoms.positions[::7] += atoms.cell[0] * 1.0  # outside the cell
    if kind == "species":
        symbols = atoms.get_chemical_symbols()
        symbols[::3] = ["Fe"] * len(symbols[::3])
        atoms.set_chemical_symbols(symbols)
        set_spins(atoms, cone(len(atoms), rng, 60.0), magnitudes=1.7)
    term = Exchange(coupling, rc=rc, offset=True)
    atoms.calc = SpinLatticeCalculator([term])
    ev, _ = atoms.calc.bound_evaluator(atoms)
    q = atoms.positions.copy()
    s = get_spins(atoms)
    want = Want(energy=True, forces=True, magnetic_forces=True, energies=True, virial=True)
    with threads.threads_for(len(atoms)):
        op = ev.spin_operators(q, virial=True, half=half)[0]
        assert op.stored == (form == "G")
        assert (op.G.shape, op.g.shape) == (((len(op.J), 3), (0,)) if op.stored
                                             else ((0, 3), (len(op.J),)))
        q[:] = 0.0  # the operator keeps its own copy of the positions
        with _g_form():
            stored = _StoredOperator(
                ev.spin_operators(atoms.positions, virial=True, half=half)[0], atoms.positions)
        results = []
        for o in (op, stored):
            B, F, e = np.zeros_like(s), np.zeros_like(s), np.zeros(len(s))
            energy, virial = o.add(s, want, B, F, e)
            results.append((energy, virial, B, F, e))
    for a, b in zip(*results):
        assert np.array_equal(a, b)
    assert np.abs(results[0][1]).max() > 0.0 and np.abs(results[0][3]).max() > 0.0
    # g = J'(r)/r (the coupling's own numpy evaluation; not the same arithmetic)
    d = stored.D
    r = np.sqrt((d * d).sum(axis=1))
    types = ev.types
    inside = r < term.rc
    assert inside.any() and (~inside).any()
    if kind == "species":
        table = {(a, b): c for (a, b), c in coupling.items()}
        table.update({(b, a): c for (a, b), c in coupling.items()})
        symbols = ev.species.symbols
        pi = op.pairs.i
        expect = np.zeros(len(r))
        for k in np.flatnonzero(inside):
            c = table[symbols[types[pi[k]]], symbols[types[op.pairs.j[k]]]]
            expect[k] = c.derivative(r[k]) / r[k]
    else:
        expect = np.where(inside, coupling.derivative(r) / r, 0.0)
    np.testing.assert_allclose(stored.op.g, expect, rtol=1e-12, atol=1e-15)


def test_the_form_follows_the_system_size(monkeypatch):
    """G below exchange.PAIR_VECTORS_BELOW atoms, g from it on; an operator
    reused with ``out=`` takes the form of the size it is prepared for."""
    atoms = fcc_cobalt(2)
    ev, _ = atoms.calc.bound_evaluator(atoms)
    q = atoms.positions
    monkeypatch.setattr(exchange_module, "PAIR_VECTORS_BELOW", len(atoms) + 1)
    first = ev.spin_operators(q, half=True)
    assert first[0].stored and first[0].g.size == 0 and first[0].G.shape == (len(first[0].J), 3)
    monkeypatch.setattr(exchange_module, "PAIR_VECTORS_BELOW", len(atoms))
    second = ev.spin_operators(q, half=True, out=first)
    assert not second[0].stored and second[0].G.size == 0
    assert second[0].g.shape == second[0].J.shape and second[0] is not first[0]
    assert first[0].J is None  # the replaced operator's arrays are given up


def test_the_virial_of_an_operator_prepared_without_it_is_an_error(monkeypatch):
    """Keeping G, an operator prepared without ``virial=True`` keeps no positions
    (it needs none for forces): asking it for the virial says so, rather than
    giving zero."""
    monkeypatch.setattr(exchange_module, "PAIR_VECTORS_BELOW", FORMS["G"])
    atoms = fcc_cobalt(2)
    ev, _ = atoms.calc.bound_evaluator(atoms)
    op = ev.spin_operators(atoms.positions, half=True)[0]
    assert op.pos is None
    with pytest.raises(ValueError, match="without virial=True"):
        ev.spin([op], get_spins(atoms), Want(forces=True, virial=True))
    again = ev.spin_operators(atoms.positions, virial=True, half=True, out=[op])[0]
    assert again.pos is not None
    assert np.abs(ev.spin([again], get_spins(atoms), Want(virial=True)).virial).max() > 0.0


@pytest.mark.parametrize("n", [3, 8])
@pytest.mark.parametrize("with_field", [False, True])
def test_forces_here_and_there_are_two_passes_to_the_bit(n, with_field):
    """ExchangeOperator.forces_here_and_there: the forces at q into F and, once
    the kept partial sums are added onto a base (add_kept), the forces at q̃, and
    with u the field B(u) at q̃ — in one pass over the pairs, each the result of
    its own pass (add, forces_and_field) bit for bit; serial at 108 atoms,
    threaded at 2 048. Operators on other lists or without pair vectors: None."""
    from ase_spin.terms.exchange import add_kept

    atoms = fcc_cobalt(n, temperature_K=300.0)
    rng = np.random.default_rng(3)
    term = Exchange(_bs(), rc=4.0, offset=True)
    atoms.calc = SpinLatticeCalculator([term])
    ev, _ = atoms.calc.bound_evaluator(atoms)
    q = atoms.positions.copy()
    qt = q + rng.normal(scale=0.01, size=q.shape)
    W = get_spins(atoms)
    u = cone(len(atoms), rng, 40.0)
    base, FL = rng.normal(size=q.shape), rng.normal(size=q.shape)
    forces = Want(forces=True)
    with threads.threads_for(len(atoms)):
        here = ev.spin_operators(q, half=True)[0]
        ev.refresh(qt)
        there = ev.spin_operators(qt, half=True, mean_with=[here], refreshed=True)[0]
        assert here.pairs_with(there)
        F, B = base.copy(), np.zeros_like(W)
        keep = here.forces_here_and_there(W, F, there, *((u, B) if with_field else ()))
        end = add_kept(keep, FL, np.empty_like(FL))
        F1, F2, B2 = base.copy(), FL.copy(), np.zeros_like(W)
        here.add(W, forces, np.zeros((0, 3)), F1, np.zeros(0))
        if with_field:
            there.forces_and_field(W, F2, u, B2)
        else:
            there.add(W, forces, np.zeros((0, 3)), F2, np.zeros(0))
        full = ev.spin_operators(q, half=False)[0]
    assert np.array_equal(F, F1) and np.array_equal(end, F2) and np.array_equal(B, B2)
    assert np.abs(end - FL).max() > 1e-3  # the forces at q̃ are not nothing
    assert not full.pairs_with(there) and full.forces_here_and_there(W, F, there) is None
