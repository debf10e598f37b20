"""The small-system paths: the fused kick–drift pass, serial heavy kernels for
tiny systems, and the integrators' direct use of the operators' contract. Each
must give bitwise the results of the general path it replaces."""

import numpy as np
import pytest
from ase import units
from ase.constraints import FixAtoms

from ase_spin.md import policy
from ase_spin import CollectivePRK, SpinLatticeCalculator, SuzukiTrotter, Want, get_spins
from ase_spin._jit import threads
from ase_spin.md import fused, kernels
from ase_spin.md.collective import SpinConvergenceError
from ase_spin.neighbors import max_displacement
from ase_spin.scenes import fcc_cobalt, field_anisotropy_terms, paper_chain, paper_chain_terms
from ase_spin.terms import Cubic, Exchange, LennardJones, lennard_jones

from conftest import general_path_only, interrupted_at, spy_fused


def test_fused_step_of_small_systems_is_taken_in_a_short_first_run(monkeypatch):
    """64–1 500 atoms: the fused step and blocks of them are the default path
    whatever the run's length (its compilation paid by ``ase-spin compile`` or
    the first run that reaches it, not by running slower)."""
    used = spy_fused(monkeypatch)
    atoms = fcc_cobalt(3)
    assert 64 <= len(atoms) < threads.SERIAL_BELOW
    dyn = CollectivePRK(atoms, 0.1 * units.fs)
    dyn.run(5)
    assert used["done"] > 0 and used["blocks"] > 0


@pytest.mark.parametrize("nthreads", [1, 2, 3])
@pytest.mark.parametrize("twin", ["serial", "parallel"])
def test_kick_drift_is_kick_then_drift_bitwise(nthreads, twin):
    """One pass, the same arithmetic: P, q̃ and both carries equal kick then
    drift bit for bit, and the three maxima equal max_displacement,
    max_abs_difference and max|q| (any chunk count, either twin)."""
    rng = np.random.default_rng(1)
    n = 37
    p, f, cp, q, cq = (rng.normal(size=(n, 3)) for _ in range(5))
    cp *= 1e-17
    cq *= 1e-16
    q *= 30.0
    m = rng.uniform(1.0, 60.0, n)
    ref = q + 1e-3 * rng.normal(size=(n, 3))
    a, h = 0.37, 0.74
    P0, mid0, qt0, cq0 = (np.empty((n, 3)) for _ in range(4))
    kernels.kick(p, a, f, cp, P0, mid0)
    kernels.drift(q, P0, m, h, cq, qt0, cq0)
    P1, mid1, qt1, cq1 = (np.empty((n, 3)) for _ in range(4))
    kernel = getattr(kernels.kick_drift, twin)
    moved, atom, apart, largest = kernel(nthreads, p, a, f, cp, P1, mid1, q, m, h, cq, qt1,
                                         cq1, ref)
    for x, y in ((P0, P1), (mid0, mid1), (qt0, qt1), (cq0, cq1)):
        assert np.array_equal(x, y)
    assert (moved, atom) == max_displacement(q, qt0)
    assert apart == kernels.max_abs_difference(qt0, ref)
    assert largest == np.abs(q).max()




@pytest.mark.parametrize("nthreads", [1, 2, 3])
@pytest.mark.parametrize("bad", [0, 17, 36])
def test_a_nan_is_not_lost_by_the_maxima(nthreads, bad):
    """A NaN anywhere (first row, middle, last) makes every maximum NaN, the
    displacement's atom the NaN's: a later finite value must not replace it
    (``not x <= max`` alone forgets a NaN as soon as the next value comes)."""
    n = 37
    q = np.zeros((n, 3))
    p, f, cp, cq = (np.zeros((n, 3)) for _ in range(4))
    m = np.ones(n)
    p[:, 0] = np.linspace(0.1, 1.0, n)  # finite moves after the NaN, larger ones
    p[bad, 1] = np.nan
    q[bad, 2] = np.nan
    P, mid, qt, cqt = (np.empty((n, 3)) for _ in range(4))
    moved, atom, apart, largest = kernels.kick_drift.parallel(
        nthreads, p, 0.5, f, cp, P, mid, q, m, 1.0, cq, qt, cqt, np.zeros((n, 3)))
    assert np.isnan(moved) and atom == bad and np.isnan(apart) and np.isnan(largest)
    moved, atom = max_displacement(qt, np.zeros((n, 3)))
    assert np.isnan(moved) and atom == bad
    assert np.isnan(kernels.max_abs_difference(qt, np.zeros((n, 3))))
class _GeneralPath:
    """The step's pieces as they were before the small-system work: the kick,
    the drift and the checks as separate calls, the spin forces through
    Evaluator.spin."""

    def _kick_drift(self, F, q, h, reference, out=None):
        st = self._state
        P = np.empty_like(st.p)
        kernels.kick(st.p, 0.5 * h, self._md_forces(F, q), st.carry_p, P, st.carry_mid)
        qt, P, carry = self._drift(q, P, h)
        moved, atom = max_displacement(q, qt)
        return (qt, P, carry, moved, atom, kernels.max_abs_difference(qt, reference),
                float(np.abs(q).max()))

    def _spin_forces(self, operators, W, FL):
        F = FL.copy()
        self.ev.spin(operators, W, Want(forces=True), forces=F)
        return F


class _GeneralCollective(_GeneralPath, CollectivePRK):
    compiled_step = False  # its own step pieces: the compiled executor must not stand in


class _GeneralSplitting(_GeneralPath, SuzukiTrotter):
    pass


def _trajectory(cls, atoms, dt, steps, **kwargs):
    dyn = cls(atoms, dt, **kwargs)
    dyn.run(steps)
    return (atoms.positions.copy(), atoms.get_momenta(), get_spins(atoms),
            dyn.get_total_energy())


@pytest.mark.parametrize("scene", ["chain", "fcc32", "fcc", "fcc-field", "fixed"])
@pytest.mark.parametrize("fast, general", [(CollectivePRK, _GeneralCollective),
                                           (SuzukiTrotter, _GeneralSplitting)])
def test_fast_step_equals_general_step_bitwise(scene, fast, general, monkeypatch):
    """The fused pieces change no bit of a trajectory: the paper chain and fcc
    Co N = 32 (tiny: CollectivePRK takes one compiled step of serial pieces),
    fcc Co N = 108 with exchange only (one compiled step, the heavy pieces
    threaded) and with a field and anisotropy (several operators: the general
    path), and with fixed atoms (the constrained path, used automatically)."""
    used = _spy_fused(monkeypatch)
    runs = []
    for cls in (fast, general):
        if cls is general:
            general_path_only(monkeypatch)
        if scene == "chain":
            atoms = paper_chain()
            runs.append(_trajectory(cls, atoms, 2.0**-6, 60, hbar=1.0, precession="spin"))
            continue
        n = 2 if scene == "fcc32" else 3
        atoms = fcc_cobalt(n, extra=field_anisotropy_terms() if scene == "fcc-field" else ())
        if scene == "fixed":
            atoms.set_constraint(FixAtoms([0, 7, 20]))
        runs.append(_trajectory(cls, atoms, 0.2 * units.fs, 15))
    for a, b in zip(*runs):
        assert np.array_equal(a, b)
    one_operator = scene in ("chain", "fcc32", "fcc")
    assert (used["done"] > 0) == (one_operator and fast is CollectivePRK)


def _spy_fused(monkeypatch):
    """Count the fused steps taken and given up."""
    return spy_fused(monkeypatch)


class _PlainLJ(LennardJones):
    """Lennard-Jones without its compiled piece: the fused step must not be used."""

    def compiled_lattice(self, pairs, types, table):
        return None


class _PythonCubic(Cubic):
    """The cubic coupling evaluated through values(r) (no compiled form)."""

    _form = 3


@pytest.mark.parametrize("case", ["lattice", "coupling"])
def test_terms_without_compiled_pieces_take_the_general_path(case, monkeypatch):
    """A term that offers no compiled piece (here LJ with compiled_lattice
    None, or exchange with a coupling evaluated in Python) sends every step
    down the general path, automatically, with the same trajectory bit for
    bit as the fused step of the equivalent terms."""
    lj, exchange = paper_chain_terms()
    if case == "lattice":
        terms = [_PlainLJ(lj.epsilon, lj.sigma, lj.rc), exchange]
    else:
        terms = [lj, Exchange(_PythonCubic(exchange.coupling.J0, exchange.coupling.rc))]
    used = _spy_fused(monkeypatch)
    atoms = paper_chain()
    atoms.calc = SpinLatticeCalculator(terms, conventions="paper")
    slow = _trajectory(CollectivePRK, atoms, 2.0**-6, 40, hbar=1.0, precession="spin")
    assert used["done"] == 0 and used["general"] > 0
    fast = _trajectory(CollectivePRK, paper_chain(), 2.0**-6, 40, hbar=1.0, precession="spin")
    assert used["done"] > 0
    for a, b in zip(slow, fast):
        if case == "lattice":
            assert np.array_equal(a, b)
        else:  # numpy's J(r) may differ from the kernel's in the last bit
            assert np.allclose(a, b, rtol=1e-12, atol=1e-12)


def test_subclass_overriding_a_step_piece_keeps_the_general_path(monkeypatch):
    """A subclass that overrides a method the fused step stands in for (here
    the spin forces) and declares it (compiled_step = False) gets the general
    path, so its override is honoured."""
    used = _spy_fused(monkeypatch)
    _trajectory(_GeneralCollective, paper_chain(), 2.0**-6, 5, hbar=1.0, precession="spin")
    assert used["done"] == 0 and used["general"] > 0


def test_two_lattice_terms_give_one_piece_chained_in_their_order(monkeypatch):
    """Two lattice terms: the fused step gets one piece that runs theirs in the
    terms' order (fused.both_lattice), and it adds the general path's lattice
    forces to the bit. (The fused step around it is the one-term step's
    skeleton; a whole run: the slow test below.)"""
    lj, exchange = paper_chain_terms()
    atoms = paper_chain()
    atoms.calc = SpinLatticeCalculator([LennardJones(0.5 * lj.epsilon, lj.sigma, lj.rc),
                                        LennardJones(0.5 * lj.epsilon, 0.9 * lj.sigma, lj.rc),
                                        exchange])
    general_path_only(monkeypatch)  # the piece alone is compiled here
    dyn = CollectivePRK(atoms, 2.0**-6, hbar=1.0, precession="spin")
    dyn.run(2)
    q = dyn._state.q
    with threads.threads_for(len(atoms)):
        fn, data = fused._lattice_pieces(dyn.ev)
        F = np.zeros_like(q)
        fn(q, data, F, False)
        swapped = np.zeros_like(q)
        fn(q, data[::-1], swapped, False)
        general = dyn.ev.lattice(q, Want(forces=True)).forces
    assert fn.py_func.__name__.startswith("both_lattice") and len(data) == 2
    assert np.abs(F).max() > 0.0 and np.array_equal(F, general)
    assert not np.array_equal(swapped, general)  # the order shows in the bits


@pytest.mark.slow
def test_fused_step_composes_several_lattice_terms(monkeypatch):
    """Two lattice terms (their pieces chained in the terms' order) in the
    fused step: bitwise the general path's trajectory (slow: a fused step of
    its own to compile, ~25 s)."""
    lj, exchange = paper_chain_terms()
    half = LennardJones(0.5 * lj.epsilon, lj.sigma, lj.rc)
    runs = []
    used = _spy_fused(monkeypatch)
    for general in (False, True):
        if general:
            general_path_only(monkeypatch)
        atoms = paper_chain()
        atoms.calc = SpinLatticeCalculator([half, LennardJones(0.5 * lj.epsilon, lj.sigma,
                                                               lj.rc), exchange])
        runs.append(_trajectory(CollectivePRK, atoms, 2.0**-6, 40, hbar=1.0,
                                precession="spin"))
    assert used["done"] > 0
    for a, b in zip(*runs):
        assert np.array_equal(a, b)


def test_fused_step_gives_up_where_the_general_path_must_act(monkeypatch):
    """Pair-list rebuilds within a run (a small skin), and a step whose
    midpoint solve fails: the fused step leaves them to the general path —
    the same trajectory bit for bit, and the same error with the atoms as
    they were."""
    used = _spy_fused(monkeypatch)
    runs = []
    for general in (False, True):
        if general:
            general_path_only(monkeypatch)
        atoms = fcc_cobalt(2)
        atoms.calc = SpinLatticeCalculator(atoms.calc.hamiltonian.terms, skin=0.015)
        dyn = CollectivePRK(atoms, 0.5 * units.fs)
        dyn.run(40)
        runs.append((atoms.positions.copy(), atoms.get_momenta(), get_spins(atoms),
                     dyn.ev.neighbors.builds))
    assert runs[0][3] > 3  # rebuilt within the run
    # each rebuild after the first (made before the run) within a step: that step's general
    assert used["done"] > 0 and used["general"] >= runs[0][3] - 1
    for a, b in zip(*runs):
        assert np.array_equal(a, b)
    monkeypatch.undo()
    used = _spy_fused(monkeypatch)
    atoms = paper_chain()
    dyn = CollectivePRK(atoms, 2.0**-6, hbar=1.0, precession="spin")
    dyn.run(3)
    before = (atoms.positions.copy(), get_spins(atoms))
    dyn.max_iter = 1
    with pytest.raises(SpinConvergenceError, match="did not converge"):
        dyn.run(1)
    assert np.array_equal(atoms.positions, before[0])
    assert np.array_equal(get_spins(atoms), before[1])
    assert used["done"] > 0 and used["general"] > 0


def test_a_runs_first_step_is_in_its_compiled_block(monkeypatch):
    """A run's first step (no predictor history yet, no operator made at q̃)
    is taken in the compiled block with the others (W starting at s), bit for
    bit as the general path takes it."""
    used = _spy_fused(monkeypatch)
    runs = []
    for general in (False, True):
        if general:
            general_path_only(monkeypatch)
        atoms = fcc_cobalt(3)
        dyn = CollectivePRK(atoms, 0.2 * units.fs)
        dyn.run(6)
        runs.append((atoms.positions.copy(), atoms.get_momenta(), get_spins(atoms),
                     dyn.total_iterations, dyn._state.predictor_order))
    assert used == {"done": 6, "general": 0, "blocks": 1}
    for a, b in zip(*runs):
        assert np.array_equal(a, b)


def test_constrained_step_takes_the_general_kick_drift(monkeypatch):
    """With constraints the general step does not use the fused kick-drift
    pass (the constraints adjust forces, positions and momenta between kick
    and drift); without, it does."""
    general_path_only(monkeypatch)
    calls = []
    real = kernels.kick_drift

    class Spy:
        def __call__(self, *args):
            calls.append(1)
            return real(*args)

    monkeypatch.setattr(kernels, "kick_drift", Spy())
    atoms = fcc_cobalt(2)
    CollectivePRK(atoms, 0.2 * units.fs).run(2)
    assert calls
    calls.clear()
    atoms = fcc_cobalt(2)
    atoms.set_constraint(FixAtoms([1]))
    CollectivePRK(atoms, 0.2 * units.fs).run(2)
    assert not calls


def test_tiny_systems_run_every_kernel_serially_with_the_same_result(monkeypatch):
    """Below SERIAL_ALL_BELOW atoms even the heavy kernels (Lennard-Jones, the
    exchange geometry) run their serial twins, over the same fixed chunks:
    an evaluation and a trajectory are bitwise those of the threaded twins."""
    used = []
    lj = lennard_jones._lj_kernel
    serial = lj.serial
    monkeypatch.setattr(lj, "_serial", lambda *a: used.append(1) or serial(*a))
    atoms = paper_chain()
    assert len(atoms) < threads.SERIAL_ALL_BELOW
    ev, _ = atoms.calc.bound_evaluator(atoms)
    want = Want(energy=True, forces=True, magnetic_forces=True)
    spins = get_spins(atoms)
    tiny = ev.evaluate(atoms.positions, spins, want)
    assert used
    run_tiny = _trajectory(CollectivePRK, paper_chain(), 2.0**-6, 40, hbar=1.0,
                           precession="spin")
    used.clear()
    monkeypatch.setattr(threads, "SERIAL_ALL_BELOW", 0)
    threaded = ev.evaluate(atoms.positions, spins, want)
    assert not used
    run_threaded = _trajectory(CollectivePRK, paper_chain(), 2.0**-6, 40, hbar=1.0,
                               precession="spin")
    assert tiny.energy == threaded.energy
    assert np.array_equal(tiny.forces, threaded.forces)
    assert np.array_equal(tiny.magnetic_forces, threaded.magnetic_forces)
    for a, b in zip(run_tiny, run_threaded):
        assert np.array_equal(a, b)


def test_threads_for_nests_and_restores():
    with threads.threads_for(10):
        assert threads.count() == 1
        with threads.threads_for(10**6):
            assert threads.count() == threads.chunks()
        assert threads.count() == 1
    assert threads.count() == threads.chunks()


def test_adaptive_step_restores_numba_threads_after_an_error():
    import numba as nb

    control = threads.AdaptiveThreads(1)
    before = nb.get_num_threads()
    with pytest.raises(KeyError):
        with control.step(100):
            assert nb.get_num_threads() == 1 and threads.count() == 1
            raise KeyError
    assert nb.get_num_threads() == before and threads.count() == threads.chunks()
    assert not control.seen  # a failed step is not timed
    with control.step(100):
        pass
    assert control.seen == {1: 1}
    with control.step(10):  # a tiny system: every kernel serial, nothing set or timed
        assert nb.get_num_threads() == before and threads.count() == 1 and threads.tiny()
    assert control.seen == {1: 1}



@pytest.mark.parametrize("n", [2, 3])
def test_langevin_takes_the_fused_step_with_its_own_predictor(n, monkeypatch):
    """Langevin (a CollectivePRK with its own predictor and baths around the
    step) on a tiny (32 atoms) and a small system (108): the fused step,
    bitwise the general path's run."""
    from ase_spin import Langevin

    used = _spy_fused(monkeypatch)
    runs = []
    for general in (False, True):
        if general:
            general_path_only(monkeypatch)
        atoms = fcc_cobalt(n)
        dyn = Langevin(atoms, 0.5 * units.fs, 300.0, spin_damping=0.1,
                       friction=0.01 / units.fs, rng=3)
        dyn.run(10)
        runs.append((atoms.positions.copy(), atoms.get_momenta(), get_spins(atoms)))
    assert used["done"] > 0
    for a, b in zip(*runs):
        assert np.array_equal(a, b)


@pytest.mark.alone
def test_fused_step_above_tiny_threads_its_heavy_pieces_same_bits_any_threads(monkeypatch):
    """Between SERIAL_ALL_BELOW and SERIAL_BELOW atoms the fused step calls the
    threaded twins of Lennard-Jones and the exchange geometry, as the general
    path does there: one thread or all, the same trajectory bit for bit."""
    from ase_spin.terms import exchange_fused

    used = _spy_fused(monkeypatch)
    runs = []
    for n in (1, threads.chunks()):
        atoms = fcc_cobalt(3)
        assert threads.SERIAL_ALL_BELOW <= len(atoms) < threads.SERIAL_BELOW
        dyn = CollectivePRK(atoms, 0.2 * units.fs, threads=n)
        dyn.run(12)
        runs.append((atoms.positions.copy(), atoms.get_momenta(), get_spins(atoms)))
        with threads.threads_for(len(atoms)):
            lattice, data = fused._lattice_pieces(dyn.ev)
            spin = dyn._state.ops[0].compiled()
        # the pieces' last datum: tiny (their serial twins) or not (threaded)
        assert lattice is lennard_jones._lj_forces and data[-1] is False
        assert spin[1] is exchange_fused.exchange_geometry and spin[3][-1] is False
    assert used["done"] > 5 * used["general"]  # the general path: each run's first step
    for a, b in zip(*runs):
        assert np.array_equal(a, b)


def _state_of(atoms, dyn):
    return (atoms.positions.copy(), atoms.get_momenta(), get_spins(atoms), dyn.nsteps,
            dyn.get_time(), dyn.total_iterations, dyn.total_steps)


@pytest.mark.parametrize("scene, order", [("chain", 2), ("chain", 4), ("chain", 6),
                                          ("fcc", 2), ("fcc", 4), ("mixed", 2),
                                          ("frozen", 2), ("frozen", 6), ("frozen-mixed", 4)])
def test_run_in_blocks_equals_step_by_step_bitwise(scene, order, monkeypatch):
    """run() takes the steps between observers as blocks of compiled steps
    (fused.collective_block; a frozen lattice: the spins-only step); every
    state it writes — the final one and the frames an observer every 7 steps
    sees — is bit for bit that of the same steps taken one at a time by the
    general path, with the same counters (steps, time, sweeps)."""
    used = _spy_fused(monkeypatch)
    results = []
    for blocks in (True, False):
        if not blocks:
            general_path_only(monkeypatch)
        if scene == "chain":
            atoms = paper_chain()
            dyn = CollectivePRK(atoms, 2.0**-6, hbar=1.0, precession="spin", order=order)
        else:
            atoms = fcc_cobalt(3)
            if scene.endswith("mixed"):  # every fourth atom without a moment
                moments = atoms.get_initial_magnetic_moments()
                moments[::4] = 0.0
                atoms.set_initial_magnetic_moments(moments)
            frozen = scene.startswith("frozen")
            dyn = CollectivePRK(atoms, (1.0 if frozen else 0.2) * units.fs, order=order,
                                lattice="frozen" if frozen else "moving")
        frames = []
        dyn.attach(lambda: frames.append((dyn.nsteps, atoms.positions.copy(),
                                          get_spins(atoms))), interval=7)
        dyn.run(30)
        dyn.run(12)  # a second run continues the first
        results.append((_state_of(atoms, dyn), frames))
    assert used["blocks"] >= 4
    (end_a, frames_a), (end_b, frames_b) = results
    for a, b in zip(end_a, end_b):
        assert np.array_equal(a, b)
    assert [f[0] for f in frames_a] == [0, 7, 14, 21, 28, 35, 42] == [f[0] for f in frames_b]
    for fa, fb in zip(frames_a, frames_b):
        for a, b in zip(fa[1:], fb[1:]):
            assert np.array_equal(a, b)


def _spy_runners(monkeypatch, name):
    """Record (arguments, result) of every call of the block runners that
    ``fused.<name>`` makes."""
    calls = []
    real = getattr(fused, name)

    def spy(*key):
        run = real(*key)

        def wrapped(*args):
            result = run(*args)
            calls.append((args, result))
            return result

        return wrapped

    monkeypatch.setattr(fused, name, spy)
    return calls


def test_block_gives_up_at_a_later_stage_and_the_general_path_goes_on(monkeypatch):
    """Order 4 with a small skin: pair-list rebuilds make a block stop, also
    at a stage after the first, where the step is undone to its start (the
    operator at q prepared again). The run is bit for bit that of the
    general path."""
    calls = _spy_runners(monkeypatch, "_runner")
    runs = []
    for general in (False, True):
        if general:
            general_path_only(monkeypatch)
        atoms = fcc_cobalt(2)
        atoms.calc = SpinLatticeCalculator(atoms.calc.hamiltonian.terms, skin=0.02)
        dyn = CollectivePRK(atoms, 0.5 * units.fs, order=4)
        dyn.run(60)
        runs.append(_state_of(atoms, dyn) + (dyn.ev.neighbors.builds,))
    assert runs[0][-1] > 3  # rebuilt within the run
    assert any(result[1] > 0 for _, result in calls), calls
    for a, b in zip(*runs):
        assert np.array_equal(a, b)


def test_adaptive_threads_time_a_block_per_step():
    """A block of k steps counts as k steps of the thread count it ran on,
    timed per step."""
    control = threads.AdaptiveThreads(1)
    with control.step(100) as context:
        context.steps = 5
    assert control.seen == {1: 5} and control.steps == 5
    with control.step(100) as context:
        context.steps = 0  # not timed
    assert control.seen == {1: 5}


def test_an_interrupt_anywhere_in_a_block_leaves_the_state_before_or_after_it():
    """Ctrl-C lands in Python code only: at every line ase_spin executes
    while run() takes a block of steps, a KeyboardInterrupt leaves the Atoms
    and the step counter both before the block or both after it, and running
    on gives the uninterrupted run's state to round-off (bit for bit where the
    integrator kept its state; an interrupted block restarts it from the Atoms,
    with a fresh midpoint predictor: W differs within the solver's tolerance)."""

    def make():
        dyn = CollectivePRK(paper_chain(), 2.0**-6, hbar=1.0, precession="spin")
        dyn.run(2)
        return dyn

    def state(dyn):
        return np.concatenate([dyn.atoms.positions, dyn.atoms.get_momenta(),
                               get_spins(dyn.atoms)])

    ref = make()
    before = state(ref)
    ref.run(3)
    after = state(ref)
    ref.run(2)
    final = state(ref)
    k = points = 0
    while True:
        k += 1
        dyn = make()
        done = interrupted_at(k, lambda: dyn.run(3))
        if done:
            break
        points += 1
        now = state(dyn)
        if dyn.nsteps == 2:
            assert np.array_equal(now, before), k
            dyn.run(5)
        else:
            assert dyn.nsteps == 5 and np.array_equal(now, after), k
            dyn.run(2)
        assert np.abs(state(dyn) - final).max() <= 1e-12, k
    assert points > 50
    assert dyn.total_steps == 5 and dyn.nsteps == 5


def test_frozen_block_leaves_the_solver_switch_to_the_general_path(monkeypatch):
    """Frozen lattice, order 4 at 4 fs: the locally exact sweeps of the middle
    stage contract too slowly, the block stops before that step, the general path
    switches the stage to Anderson (solver="auto"), and the blocks after it
    solve that stage with Anderson too: bit for bit the general path's run."""
    used = _spy_fused(monkeypatch)
    runs = []
    for general in (False, True):
        if general:
            general_path_only(monkeypatch)
        atoms = fcc_cobalt(3)
        dyn = CollectivePRK(atoms, 4.0 * units.fs, order=4, lattice="frozen")
        with pytest.warns(UserWarning):
            dyn.run(25)
        runs.append((get_spins(atoms), dyn.total_iterations, dict(dyn._state.modes)))
    assert runs[0][2] and runs[0][2] == runs[1][2]  # a stage switched to Anderson
    assert used["blocks"] >= 1
    assert np.array_equal(runs[0][0], runs[1][0]) and runs[0][1] == runs[1][1]


@pytest.mark.parametrize("lattice", ["frozen", "moving"])
def test_auto_takes_a_jacobi_sweep_after_one_sweep_solves(lattice, monkeypatch):
    """At 0.05 fs the predictor leaves the solves one sweep (frozen) or
    nearly so: once a stage's first solve took one sweep, "auto" makes the
    next with Jacobi sweeps (policy.auto_takes_local: one pass over the spins
    fewer than a locally exact solve's) and goes back to locally exact ones
    after a solve of more. Blocks of compiled steps (frozen: _run_frozen;
    moving: _run) and the general path make the same choices, bit for bit."""
    from ase_spin.md import collective

    runner = "_frozen_runner" if lattice == "frozen" else "_runner"
    calls = _spy_runners(monkeypatch, runner)
    runs = []
    for general in (False, True):
        solvers = []
        if general:
            general_path_only(monkeypatch)
            real = collective.CollectivePRK._run_solver

            def spy(self, *args):
                solvers.append(args[10])  # locally exact sweeps, or Jacobi's
                return real(self, *args)

            monkeypatch.setattr(collective.CollectivePRK, "_run_solver", spy)
        atoms = fcc_cobalt(3)
        dyn = CollectivePRK(atoms, 0.05 * units.fs, lattice=lattice)
        dyn.run(80)
        runs.append((_state_of(atoms, dyn), dyn.total_iterations, solvers))
    assert calls and any(result[0] > 0 for _, result in calls)  # blocks were taken
    assert False in runs[1][2] and True in runs[1][2], set(runs[1][2])
    for a, b in zip(runs[0][0], runs[1][0]):
        assert np.array_equal(a, b)
    assert runs[0][1] == runs[1][1]


@pytest.mark.parametrize("order, switch_at", [(2, 0.0365), (4, 0.04)])
def test_a_block_stopping_mid_way_hands_that_step_to_the_general_path(order, switch_at,
                                                                      monkeypatch):
    """Frozen lattice at 0.5 fs, the "auto" switch to Anderson lowered to
    ``switch_at``, which a stage's contraction crosses for the first time in
    the 9th (order 2: 0.021–0.038 here, its sweeps in colour order:
    policy.next_sweep_order) or 15th step (order 4: the middle stage's,
    0.016–0.023 in colour order, then 0.047–0.069 in index order once colour
    order is found not to pay; the outer stages' ≤ 0.031 never). A block takes some
    steps, stops before the first step it cannot take (at order 4 in its third
    stage: the state put back to the last whole step), the general path takes
    that step (switching the stage to Anderson), and blocks go on: bit for bit
    the general path's run."""
    calls = _spy_runners(monkeypatch, "_frozen_runner")
    switch = policy.AUTO_SWITCH
    runs = []
    for general in (False, True):
        if general:
            general_path_only(monkeypatch)
        atoms = fcc_cobalt(3, conventions="lammps")  # the contractions the docstring gives
        dyn = CollectivePRK(atoms, 0.5 * units.fs, order=order, lattice="frozen")
        dyn.run(15)
        monkeypatch.setattr(policy, "AUTO_SWITCH", switch_at)
        dyn.run(40)
        monkeypatch.setattr(policy, "AUTO_SWITCH", switch)
        runs.append((get_spins(atoms), dyn.total_iterations, dict(dyn._state.modes)))
    assert any(0 < result[0] < args[0] for args, result in calls), calls
    assert runs[0][2] and runs[0][2] == runs[1][2]
    if order == 4:
        assert [stage for stage, _ in runs[0][2]] == [2]
    assert np.array_equal(runs[0][0], runs[1][0]) and runs[0][1] == runs[1][1]


@pytest.mark.parametrize("dt_fs", [0.1, 0.5])
def test_fused_end_forces_begun_in_the_last_rounds_pass_change_no_bit(monkeypatch, dt_fs):
    """The fused step and its blocks begin the end forces in the pass of the
    outer round the last step settled in, as the general path does
    (CollectivePRK._round_forces; the operator's forces_two and add_kept
    pieces): the same bits as with a pass for each, blocks and single steps."""
    from ase_spin.md import fused

    pieces = fused._pieces

    def go(merge):
        with monkeypatch.context() as m:
            if not merge:
                m.setattr(fused, "_pieces", lambda dyn: (
                    None if pieces(dyn) is None else pieces(dyn)[:4] + (False,) + pieces(dyn)[5:]))
            atoms = fcc_cobalt(3, temperature_K=300)
            dyn = CollectivePRK(atoms, dt_fs * units.fs)
            for _ in range(3):
                dyn.run(5)
                dyn.step()
            return atoms, dyn

    (a, dyn), (b, _) = go(True), go(False)
    assert dyn._state.fused[2]["merge"]
    for x, y in ((a.positions, b.positions), (a.get_momenta(), b.get_momenta()),
                 (a.get_initial_magnetic_moments(), b.get_initial_magnetic_moments())):
        np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("dt_fs, order", [(0.15, 2), (1.0, 4)])
def test_lattice_forces_beside_the_solve_change_no_bit(monkeypatch, dt_fs, order):
    """The fused step makes F_L on one thread while the other makes the
    couplings and solves (coupled_step's ``overlap``, taken above the tiny
    systems): the same bits as one after the other, on two threads and on one,
    and as the general path, which takes F_L at the same q̃ (the last
    geometry's); at 1 fs, order 4, a stage takes two geometries, and only the
    F_L of the last is kept."""
    from ase_spin.md import fused

    pieces = fused._pieces
    seen = []

    def go(overlap, n):
        with monkeypatch.context() as m:
            def spy(dyn):
                got = pieces(dyn)
                if got is None:
                    return None
                seen.append(got[5])
                return got[:5] + (overlap and got[5],)
            m.setattr(fused, "_pieces", spy)
            atoms = fcc_cobalt(3, temperature_K=300)
            dyn = CollectivePRK(atoms, dt_fs * units.fs, order=order, threads=n)
            dyn.run(10)
            dyn.step()
            return atoms, dyn

    runs = [go(True, 2), go(False, 2), go(True, 1)]
    assert all(seen) and len(seen) >= 2 * len(runs)  # taken at this size
    # the last step's geometries: more than one a stage at order 4
    assert runs[0][1].geometry_evaluations > (5 if order == 4 else 0)
    atoms = fcc_cobalt(3, temperature_K=300)
    general_path_only(monkeypatch)
    CollectivePRK(atoms, dt_fs * units.fs, order=order).run(11)
    for other in [r[0] for r in runs[1:]] + [atoms]:
        for x, y in ((runs[0][0].positions, other.positions),
                     (runs[0][0].get_momenta(), other.get_momenta()),
                     (runs[0][0].get_initial_magnetic_moments(),
                      other.get_initial_magnetic_moments())):
            np.testing.assert_array_equal(x, y)
