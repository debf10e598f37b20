"""The midpoint solvers of CollectivePRK: the locally exact spin update, Anderson
acceleration, and where each converges (docs/dynamics.md, "The midpoint solver")."""

import numpy as np
import pytest
from ase import units
from scipy.optimize import root

import ase_spin
from ase_spin.md import policy
from ase_spin import CollectivePRK, SpinLatticeCalculator
from ase_spin.md import SpinConvergenceError
from ase_spin.md.kernels import local_midpoint
from ase_spin.scenes import fcc_cobalt, fcc_cobalt_terms, field_anisotropy_terms
from ase_spin._jit.threads import chunks

pytestmark = pytest.mark.filterwarnings("ignore::ase_spin.md.errors.TimestepWarning")


def unit(v):
    return v / np.linalg.norm(v)


def test_local_midpoint_solves_one_spin_exactly():
    """W = (2p + c W × b)/|2p + c W × b| to round-off, for spins of any length,
    either sign of c and up to half a turn per step; no root only where none
    exists (p ⊥ b, |c b| ≥ 2|p|)."""
    rng = np.random.default_rng(3)
    worst = 0.0
    for _ in range(2000):
        p = rng.normal(size=3) * rng.uniform(0.5, 2.0)
        b = rng.normal(size=3)
        c = rng.uniform(-3.0, 3.0)
        w = np.array(local_midpoint(*p, *b, c)[:3])
        assert local_midpoint(*p, *b, c)[3]
        worst = max(worst, abs(np.linalg.norm(w) - 1.0),
                    float(np.abs(w - unit(2 * p + c * np.cross(w, b))).max()))
    assert worst < 1e-13
    p = np.array([1.0, 0.0, 0.0])
    assert not local_midpoint(*p, 0.0, 0.0, 1.0, 2.5)[3]       # |cb| = 2.5 > 2|p|
    assert local_midpoint(*p, 0.0, 0.0, 1.0, 1.5)[3]


def frozen_step_reference(dt_fs):
    """The midpoint spins of one frozen-lattice step, solved by scipy's root
    finder (MINPACK hybrid Powell) to xtol 1e-15: s̃ = 2(s·W)W − s."""
    dyn = CollectivePRK(fcc_cobalt(2, conventions="lammps"), dt_fs * units.fs, lattice="frozen", solver="jacobi")
    dyn._sync()
    st = dyn._state
    c = (dt_fs * units.fs * dyn.sigma / dyn.hbar) * st.rate[:, None]
    s = st.s.copy()

    def residual(x):
        W = x.reshape(-1, 3)
        B = np.zeros_like(W)
        for op in st.ops:
            op.field(W, B)
        v = 2 * s + c * np.cross(W, B)
        return (v / np.linalg.norm(v, axis=1)[:, None] - W).ravel()

    sol = root(residual, s.ravel(), method="hybr", options={"xtol": 1e-15})
    W = sol.x.reshape(-1, 3)
    W /= np.linalg.norm(W, axis=1)[:, None]
    assert np.abs(residual(W.ravel())).max() < 1e-13
    return 2 * np.einsum("ij,ij->i", s, W)[:, None] * W - s


@pytest.mark.parametrize("solver", ["anderson", "local", "auto"])
def test_converges_where_jacobi_fails_to_the_reference_solution(solver):
    """At 4 fs on a frozen fcc Co lattice (h|B|/ħ ≈ 2 rad) the Jacobi iteration
    diverges; the other solvers give the midpoint solution of an independent
    root finder to round-off, spins of unit length."""
    with pytest.raises(SpinConvergenceError, match="jacobi"):
        CollectivePRK(fcc_cobalt(2, conventions="lammps"), 4 * units.fs, lattice="frozen",
                      solver="jacobi").run(1)
    reference = frozen_step_reference(4.0)
    atoms = fcc_cobalt(2, conventions="lammps")
    dyn = CollectivePRK(atoms, 4 * units.fs, lattice="frozen", solver=solver)
    dyn.run(1)
    s = ase_spin.get_spins(atoms)
    assert np.abs(s - reference).max() < 1e-13
    assert np.abs(np.linalg.norm(dyn._state.s, axis=1) - 1).max() < 1e-15


@pytest.mark.parametrize("dt_fs", [0.1, 0.5, 2.0])
def test_solvers_agree_and_anderson_needs_fewer_sweeps(dt_fs):
    """The same steps to round-off from every solver (they solve one equation),
    and fewer sweeps from the locally exact one, fewer still with Anderson
    acceleration, than from Jacobi (fcc Co, 100 K lattice moving)."""
    runs = {}
    for solver in ("jacobi", "local", "anderson"):
        atoms = fcc_cobalt(2, conventions="lammps")
        dyn = CollectivePRK(atoms, dt_fs * units.fs, solver=solver)
        dyn.run(10)
        runs[solver] = (dyn.mean_iterations, atoms.positions.copy(), ase_spin.get_spins(atoms))
    for solver in ("local", "anderson"):
        assert np.abs(runs[solver][1] - runs["jacobi"][1]).max() < 1e-11
        assert np.abs(runs[solver][2] - runs["jacobi"][2]).max() < 1e-11
    assert runs["local"][0] < runs["jacobi"][0]
    assert runs["anderson"][0] <= runs["local"][0]


@pytest.mark.parametrize("order", [2, 4, 6])
def test_large_steps_run_with_every_order(order):
    """3 fs (Jacobi fails from here, test_md) with orders 2, 4 and 6: the steps
    go through, spins keep their length, the energy stays bounded."""
    atoms = fcc_cobalt(2, conventions="lammps")
    dyn = CollectivePRK(atoms, 3 * units.fs, order=order)
    e0 = dyn.get_total_energy()
    dyn.run(20)
    assert abs(dyn.get_total_energy() - e0) < 5e-3 * len(atoms)
    assert np.abs(np.linalg.norm(dyn._state.s, axis=1) - 1).max() < 1e-14


def test_anderson_with_single_site_terms():
    """The solver over several operators (field, anisotropy): the same steps as
    Jacobi to round-off, fewer sweeps, and a step Jacobi cannot take."""
    runs = []
    for solver in ("jacobi", "anderson"):
        atoms = fcc_cobalt(2, conventions="lammps")
        atoms.calc = SpinLatticeCalculator([*fcc_cobalt_terms(), *field_anisotropy_terms()])
        dyn = CollectivePRK(atoms, 1 * units.fs, solver=solver)
        dyn.run(5)
        runs.append((dyn.mean_iterations, ase_spin.get_spins(atoms)))
    assert np.abs(runs[0][1] - runs[1][1]).max() < 1e-11
    assert runs[1][0] < runs[0][0]
    dyn.dt = 4 * units.fs
    dyn.run(2)


def test_solver_argument_is_checked():
    with pytest.raises(ValueError, match="solver"):
        CollectivePRK(fcc_cobalt(1), 1.0, solver="newton")


@pytest.mark.alone
@pytest.mark.skipif(chunks() < 2, reason="numba has one thread here")
@pytest.mark.parametrize("extra", [False, True])
def test_anderson_is_bitwise_the_same_with_one_thread_or_all(extra):
    """Anderson's inner products are summed over fixed blocks: one thread or
    all give the same bits (N = 4000, threaded kernels; exchange alone, the
    fused solve, or with field and anisotropy, the operators' solve)."""
    runs = []
    for n in (1, chunks()):
        atoms = fcc_cobalt(10)
        if extra:
            atoms.calc = SpinLatticeCalculator([*fcc_cobalt_terms(), *field_anisotropy_terms()])
        dyn = CollectivePRK(atoms, 1.0 * units.fs, solver="anderson", threads=n)
        dyn.run(2)
        runs.append((atoms.positions.copy(), ase_spin.get_spins(atoms), dyn.total_iterations))
    for a, b in zip(*runs):
        assert np.array_equal(a, b)


@pytest.mark.parametrize("order", range(12))
def test_predictor_extrapolates_polynomials_of_its_order_exactly(order):
    """Order k of the predictor continues any polynomial of degree k from its
    last k + 1 values (then renormalised; here on a zero base, so that the
    increments are the values), whatever the older history holds."""
    from collections import deque

    from ase_spin.md import kernels

    rng = np.random.default_rng(order)
    a = rng.normal(size=(order + 1, 20, 3))
    a[0] += 3.0  # rows well away from zero length

    def value(t):  # t = 0 … 1
        return sum(a[j] * t**j for j in range(order + 1))

    depth = kernels.PREDICTOR_DEPTH
    history = deque(maxlen=depth)
    for m in range(depth):  # older than the last order + 1 values: anything
        history.append(value(m / depth) if m >= depth - order - 1 else rng.normal(size=(20, 3)))
    expected = value(1.0)
    expected /= np.linalg.norm(expected, axis=1)[:, None]
    assert np.allclose(kernels.extrapolate(history, order, np.zeros((20, 3))), expected, rtol=0,
                       atol=1e-9)


def test_predictor_least_squares_row_fits_degree_12_through_all_16():
    """The predictor's last row continues any polynomial of degree ≤ 12 from all
    16 values, is the least-squares fit's (the same functional computed in
    floating point by a QR factorisation), and its noise gain Σ|c_m| is
    below a seventh of exact order 12's (8191)."""
    from ase_spin.md import kernels

    depth = kernels.PREDICTOR_DEPTH
    c = kernels.COEFFICIENTS[depth - 1]
    assert depth == 16 and kernels.LEAST_SQUARES_DEGREE == 12
    # rows 12–14 (a full-history choice while the history refills): order 11
    for k in (12, 13, 14):
        assert np.array_equal(kernels.COEFFICIENTS[k], kernels.COEFFICIENTS[11])
    t = -np.arange(depth) / depth  # newest first; the next value at t = 1/depth
    rng = np.random.default_rng(4)
    for degree in range(13):
        a = rng.normal(size=degree + 1)
        values = sum(a[j] * t**j for j in range(degree + 1))
        expected = sum(a[j] * depth ** -j for j in range(degree + 1))
        assert abs(c @ values - expected) <= 1e-10 * np.abs(c).sum()
    from scipy.linalg import solve_triangular

    # c = V (VᵀV)⁻¹ e = Q R⁻ᵀ e (V = QR, condition ~3e9: agreement to ~1e-6)
    q, r = np.linalg.qr(np.vander(t, 13, increasing=True))
    reference = q @ solve_triangular(r.T, depth ** -np.arange(13.0), lower=True)
    assert np.allclose(c, reference, rtol=0, atol=1e-4)
    assert np.abs(c).sum() < 8191 / 7
    # with noise on each value it errs less than exact order 12
    noise = 1e-12 * rng.normal(size=(2000, depth))
    assert np.abs(noise @ c).max() < 0.25 * np.abs(noise @ kernels.COEFFICIENTS[12]).max()


def test_predictor_order_choice_is_the_order_with_the_smallest_error():
    """best_extrapolation_order (one backward-difference table, and the
    least-squares row with a full history) picks the row whose
    coefficient-form extrapolation is closest on the sampled rows."""
    from collections import deque

    from ase_spin.md import kernels

    depth = kernels.PREDICTOR_DEPTH
    rng = np.random.default_rng(5)
    t = np.arange(depth + 1)[:, None, None]
    chosen = set()
    for omega in (0.05, 0.1, 0.3, 1.0):
        for noise in (1e-9, 1e-13):
            phase = rng.uniform(0, 6, size=(1, 40, 3))
            path = np.cos(omega * t + phase) + noise * rng.normal(size=(depth + 1, 40, 3))
            for n in (1, 5, 12, 15, depth):
                history = deque(path[depth - n:depth], maxlen=depth)
                rows = np.arange(0, 40, 3)
                target = path[depth]
                newest_first = [history[-1 - m] if m < n else history[-1] for m in range(depth)]
                candidates = (list(range(min(n, kernels.EXACT_ORDERS)))
                              + ([depth - 1] if n == depth else []))
                errors = [max(abs(sum(c * h[r] for c, h in zip(kernels.COEFFICIENTS[k],
                                                               newest_first)) - target[r]).max()
                              for r in rows) for k in candidates]
                got = kernels.best_extrapolation_order(history, target, rows)
                assert got == candidates[int(np.argmin(errors))]
                chosen.add(got)
    assert depth - 1 in chosen  # the least-squares row wins somewhere


def test_predictor_order_choice_kept_table_is_the_whole_table():
    """best_extrapolation_order with its difference table kept between calls
    (one increment appended each time, the history growing to its depth and
    then dropping its oldest) picks the same order from a table equal bit for
    bit to the one made whole each time; after a history that did not grow
    by one (a reset, a step not taken) the whole table is made again; and
    the kept table is read, not remade, when the history did grow by one."""
    from collections import deque

    from ase_spin.md import kernels

    rng = np.random.default_rng(11)
    n_rows, depth = 40, kernels.PREDICTOR_DEPTH
    rows = np.arange(0, n_rows, 3)
    phase = rng.uniform(0, 6, size=(n_rows, 3))
    kept = kernels.difference_table(len(rows))
    history = deque(maxlen=depth)
    orders = set()
    for t in range(30):
        if t == 20:  # a reset: the kept table must not be taken for it
            history.clear()
            history.append(np.cos(0.3 * t + phase))
            continue
        target = np.cos(0.3 * (t + 1) + phase) + 1e-12 * rng.normal(size=(n_rows, 3))
        if history:
            fresh = kernels.difference_table(len(rows))
            expected = kernels.best_extrapolation_order(history, target, rows, kept=fresh)
            got = kernels.best_extrapolation_order(history, target, rows, kept=kept)
            assert got == expected
            assert kept[1][0] == fresh[1][0] == min(len(history), depth)
            assert np.array_equal(kept[0][:kept[1][0]], fresh[0][:fresh[1][0]]), t
            orders.add(got)
        history.append(np.cos(0.3 * (t + 1) + phase))
    assert len(orders) > 1
    # the history grew by one: the kept rows 1… are read (here spoilt on purpose)
    spoilt = (kept[0].copy(), kept[1].copy())
    spoilt[0][1:] += 1.0
    target = np.cos(0.3 * 31 + phase)
    kernels.best_extrapolation_order(history, target, rows, kept=spoilt)
    fresh = kernels.difference_table(len(rows))
    kernels.best_extrapolation_order(history, target, rows, kept=fresh)
    assert np.array_equal(spoilt[0][:2], fresh[0][:2])  # ∇h_0 needs the kept h_0 only
    assert not np.array_equal(spoilt[0][2:depth], fresh[0][2:depth])


def test_predictor_leaves_one_geometry_and_few_sweeps_per_step():
    """fcc Co, 0.1 fs: the predicted midpoint spins are close enough (≈1e-13)
    that q̃ computed from them settles at once: one pair geometry per step
    (two with the order-3 predictor) and at most three sweeps (eight)."""
    atoms = fcc_cobalt(3)
    dyn = CollectivePRK(atoms, 0.1 * units.fs)
    dyn.run(20)  # the history fills
    sweeps, geometries = [], []
    dyn.attach(lambda: (sweeps.append(dyn.iterations),
                        geometries.append(dyn.geometry_evaluations)), interval=1)
    dyn.run(10)
    assert max(geometries[1:]) == 1
    assert np.mean(sweeps[1:]) <= 3.0


@pytest.mark.parametrize("fused", [True, False])
def test_auto_solver_keeps_its_first_sweeps_while_they_contract_fast(fused, monkeypatch):
    """fcc Co at 0.1 fs, where a sweep contracts by a few hundredths: "auto"
    keeps its locally exact sweeps over a long run. Most solves take two
    sweeps from a good prediction and observe no contraction (every change
    below 1e3 tol); the estimate kept must be the last one observed, not the
    doubled safety margin of a solve that observed none (which, stored back,
    doubled every step until a three-sweep solve saw it above 0.4 and switched
    to Anderson for good: after ~40 steps, before the fix). Both the general
    and the fused small-system step."""
    from conftest import general_path_only

    if not fused:
        general_path_only(monkeypatch)
    dyn = CollectivePRK(fcc_cobalt(2, conventions="lammps"), 0.1 * units.fs)
    dyn.run(150)
    st = dyn._state
    assert st.modes == {}
    assert 0.0 < st.theta[0] < 0.1


@pytest.mark.parametrize("order, dt_fs", [(2, 0.5), (4, 1.0)])
def test_auto_solver_takes_locally_exact_sweeps(order, dt_fs):
    """"auto" solves with locally exact sweeps until they contract slowly: at
    0.5 fs (order 2) and 1 fs (order 4) on fcc Co, the same steps and sweeps as
    solver="local", fewer sweeps than Jacobi's, the same steps as Jacobi's
    to the tolerance."""
    runs = {}
    for solver in ("auto", "local", "jacobi"):
        atoms = fcc_cobalt(2, conventions="lammps")
        dyn = CollectivePRK(atoms, dt_fs * units.fs, order=order, solver=solver)
        dyn.run(20)
        runs[solver] = (dyn.total_iterations, atoms.positions.copy(),
                        ase_spin.get_spins(atoms), dyn._state.modes)
    assert runs["auto"][3] == {}  # no switch to Anderson
    assert runs["auto"][0] == runs["local"][0]
    assert np.array_equal(runs["auto"][2], runs["local"][2])
    assert runs["auto"][0] < 0.9 * runs["jacobi"][0], (runs["auto"][0], runs["jacobi"][0])
    assert np.abs(runs["auto"][1] - runs["jacobi"][1]).max() < 1e-11
    assert np.abs(runs["auto"][2] - runs["jacobi"][2]).max() < 1e-11


def _run(n, dt_fs, order, steps, heavy=False, **kw):
    atoms = fcc_cobalt(n)
    if heavy:  # q̃ hardly depends on W: the outer iteration settles after one solve
        atoms.set_masses(atoms.get_masses() * 1e10)
    dyn = CollectivePRK(atoms, dt_fs * units.fs, order=order, **kw)
    dyn.run(steps)
    return atoms.positions.copy(), ase_spin.get_spins(atoms), dyn.total_iterations


@pytest.mark.parametrize("n, dt_fs, order, heavy", [(2, 1.0, 4, False), (10, 1.0, 4, False),
                                                    (3, 0.1, 2, False), (2, 1.0, 2, True),
                                                    (10, 1.0, 2, True)])
def test_loose_first_solve_gives_the_same_steps(n, dt_fs, order, heavy, monkeypatch):
    """The first midpoint solve of a step stopped early (policy.first_tolerance)
    changes the steps by the solver tolerance only: the same trajectory to 1e-12
    as with every solve converged to tol, in fewer sweeps. N = 32 takes the fused
    step, N = 108 either (the fused one once compiled), N = 4 000 the general one; ``heavy`` atoms make q̃ settle right after the
    loose solve, which must then be finished at the same couplings."""
    default = _run(n, dt_fs, order, 10, heavy)
    monkeypatch.setattr(policy, "FIRST_SOLVE_FRACTION", 0.0)
    tight = _run(n, dt_fs, order, 10, heavy)
    if heavy:  # every first solve loose, so that the finishing solve runs at every step
        monkeypatch.setattr(policy, "FIRST_SOLVE_FRACTION", 1e300)
        monkeypatch.setattr(policy, "FIRST_SOLVE_LOOSEST", 1e-7)
        loose = _run(n, dt_fs, order, 10, heavy)
        assert np.abs(loose[1] - tight[1]).max() < 1e-12
        assert np.abs(loose[0] - tight[0]).max() < 1e-12
    assert np.abs(default[0] - tight[0]).max() < 1e-12
    assert np.abs(default[1] - tight[1]).max() < 1e-12
    assert default[2] <= tight[2]


def test_predictor_extrapolates_the_increments():
    """W = normalise(s + D), D the polynomial extrapolation of the last increments
    W − s: exact for increments cubic in the step number (order 3), and for
    linear ones from order 1."""
    from collections import deque

    from ase_spin.md import kernels

    rng = np.random.default_rng(3)
    a, b, c, d = (rng.normal(size=(5, 3)) * 0.1 for _ in range(4))
    s = np.array([unit(v) for v in rng.normal(size=(5, 3))])
    for order, coef in ((3, (a, b, c, d)), (1, (a, b, 0 * c, 0 * d))):
        history = deque([coef[0] + k * coef[1] + k**2 * coef[2] + k**3 * coef[3]
                         for k in range(4)], maxlen=4)
        D = coef[0] + 4 * coef[1] + 16 * coef[2] + 64 * coef[3]
        expected = (s + D) / np.linalg.norm(s + D, axis=1)[:, None]
        assert np.abs(kernels.extrapolate(history, order, s) - expected).max() < 1e-12


@pytest.mark.alone
@pytest.mark.skipif(chunks() < 2, reason="numba has one thread here")
def test_default_solver_is_bitwise_the_same_with_one_thread_or_all():
    """solver="auto" with its loose first solves and the increment predictor,
    order 4 at 1.5 fs (Jacobi and Anderson stages): one thread or all give the
    same bits (N = 4000)."""
    runs = [_run(10, 1.5, 4, 3, threads=n) for n in (1, chunks())]
    for a, b in zip(*runs):
        assert np.array_equal(a, b)


@pytest.mark.parametrize("memory, half", [(0, True), (0, False), (3, True)])
def test_a_non_finite_field_is_not_converged(memory, half):
    """A NaN in one coupling spreads through the spins sweep by sweep; the
    solver must say NOT_CONVERGED (its check for a non-finite field), not
    report the dropped rows' change as 0 and converge on NaN spins (a plain
    max(m, d) per row forgets a NaN d)."""
    from ase_spin.md import kernels

    n = 6
    row = np.arange(n + 1) if half else 2 * np.arange(n + 1)
    ring = np.roll(np.arange(n), -1)
    nbr = ring if half else np.stack([ring, np.roll(np.arange(n), 1)], axis=1).ravel()
    J = np.full(len(nbr), 0.01)
    J[2] = np.nan
    rng = np.random.default_rng(0)
    s = rng.normal(size=(n, 3))
    s /= np.linalg.norm(s, axis=1)[:, None]
    W, Wn, st = s.copy(), np.empty_like(s), np.empty_like(s)
    solve = kernels.midpoint_solve_half if half else kernels.midpoint_solve
    its, delta, status, *_ = solve.serial(1, row, nbr.astype(np.int32), J, s, W, Wn, st,
                                          np.full(n, 0.1), 1e-15, 6.4e-14, 50, 0.5,
                                          np.zeros_like(s), np.zeros_like(s), memory, True,
                                          kernels.NO_FIELD, kernels.NO_ORDER, kernels.NO_ORDER,
                                          kernels.NO_FIELD)
    assert status == kernels.NOT_CONVERGED, (its, delta, status)


def test_a_solve_stopped_by_a_non_finite_field_names_the_atom():
    """What CollectivePRK says when its solver stops on a NaN: a non-finite
    field at an atom (IntegrationError), not "reduce the timestep"."""
    from ase_spin.md import IntegrationError

    atoms = fcc_cobalt(2, conventions="lammps")
    dyn = CollectivePRK(atoms, 0.1 * units.fs)
    dyn.run(1)
    st = dyn._state
    W = st.s.copy()
    W[5] = np.nan
    with pytest.raises(IntegrationError, match=r"non-finite spins \(atom 5"):
        dyn._raise_not_converged(st.ops, st.s, W, 3, float("nan"), True)
    with pytest.raises(SpinConvergenceError, match="did not converge"):
        dyn._raise_not_converged(st.ops, st.s, st.s, 50, 1e-3, True)


def _full_fcc(dt_fs=1.0, n=3):
    """fcc Co's exchange on the full pair list, frozen: (dyn, pairs, c)."""
    dyn = CollectivePRK(fcc_cobalt(n), dt_fs * units.fs, lattice="frozen")
    dyn.half_lists = False
    dyn._sync()
    pairs, c = dyn._state.ops[0].linear_pairs(False)
    assert not pairs.half
    return dyn, pairs, c


def _simple_cubic_full(n):
    """(row, nbr) of a periodic simple cubic lattice of n³ sites, nearest
    neighbours, each pair both ways."""
    idx = np.arange(n ** 3).reshape(n, n, n)
    nbr = np.stack([np.roll(idx, shift, axis).ravel() for axis in range(3)
                    for shift in (1, -1)], axis=1)
    return 6 * np.arange(n ** 3 + 1), nbr.ravel().astype(np.int32)


def test_greedy_colouring_pairs_no_two_atoms_of_one_colour():
    """Every atom once in the colour order, no pair within one colour (fcc Co's
    full list, 18 partners an atom, and a random graph with self-images); a
    simple cubic lattice with an even number of cells takes two colours."""
    from ase_spin.neighbors import greedy_colouring

    _, pairs, _ = _full_fcc()
    graphs = [(pairs.row, pairs.j)]
    rng = np.random.default_rng(4)
    n = 60
    edges = {(int(a), int(b)) for a, b in rng.integers(0, n, size=(150, 2))}
    both = sorted(edges | {(b, a) for a, b in edges})
    row = np.searchsorted([a for a, _ in both], np.arange(n + 1))
    graphs.append((row, np.array([b for _, b in both], dtype=np.int32)))
    graphs.append(_simple_cubic_full(4))
    for row, nbr in graphs:
        order, starts = greedy_colouring(row, nbr)
        n = len(row) - 1
        assert np.array_equal(np.sort(order), np.arange(n))
        colour = np.empty(n, dtype=int)
        for c in range(len(starts) - 1):
            colour[order[starts[c]:starts[c + 1]]] = c
        i = np.repeat(np.arange(n), np.diff(row))
        assert not np.any((colour[i] == colour[nbr]) & (i != nbr))
    assert len(greedy_colouring(*_simple_cubic_full(4))[1]) - 1 == 2


def test_colour_ordered_sweep_is_gauss_seidel():
    """One locally exact sweep with a colouring: each spin solved exactly
    (local_midpoint) in the field of the spins of earlier colours at their new
    values and of later ones at the iterate's, checked spin by spin."""
    from ase_spin.md import kernels

    dyn, pairs, c = _full_fcc()
    order, starts = pairs.colours()
    assert len(starts) - 1 > 2
    s = dyn._state.s
    n = len(s)
    rng = np.random.default_rng(1)
    W0 = s + 0.05 * rng.normal(size=s.shape)
    W0 /= np.linalg.norm(W0, axis=1)[:, None]
    scale = dyn._scale(2 * units.fs)
    W, Wn, st = W0.copy(), np.zeros_like(s), np.zeros_like(s)
    prow, pnbr, pc = ase_spin.neighbors.rows_in_order(pairs.row, pairs.j, c, order)
    its, _, status, which, *_ = kernels.midpoint_solve.serial(
        1, prow, pnbr, pc, s, W, Wn, st, scale, 3.0, 0.0, 1, 0.5, np.zeros_like(s),
        np.zeros_like(s), 0, True, kernels.NO_FIELD, order, starts,
        kernels.NO_FIELD)  # "converged" after one sweep
    assert its == 1 and status == kernels.CONVERGED
    got = W if which == 0 else Wn
    new = W0.copy()
    for i in order:  # colour by colour
        k = slice(pairs.row[i], pairs.row[i + 1])
        b = (c[k][:, None] * new[pairs.j[k]]).sum(axis=0)
        new[i] = local_midpoint(*s[i], *b, scale[i])[:3]
    assert np.abs(got - new).max() < 1e-14
    # the index order takes the iterate's W for every partner: not the same sweep
    W, Wn = W0.copy(), np.zeros_like(s)
    kernels.midpoint_solve.serial(1, pairs.row, pairs.j, c, s, W, Wn, np.zeros_like(s),
                                  scale, 3.0, 0.0, 1, 0.5, np.zeros_like(s),
                                  np.zeros_like(s), 0, True, kernels.NO_FIELD, kernels.NO_ORDER,
                                  kernels.NO_ORDER, kernels.NO_FIELD)
    assert np.abs(Wn - new).max() > 1e-6


def _colour_solve(chunks_, colours, memory, dt_fs=3.0):
    """fcc Co frozen (108 atoms): one midpoint solve at ``dt_fs`` over the full
    list, in index order (``colours`` None) or colour order: (sweeps, s̃)."""
    from ase_spin.md import kernels

    dyn, pairs, c = _full_fcc()
    s = dyn._state.s
    fn = kernels.midpoint_solve.serial
    W, Wn, st = s.copy(), np.zeros_like(s), np.zeros_like(s)
    args = (chunks_, pairs.row, pairs.j, c, s, W, Wn, st, dyn._scale(dt_fs * units.fs), 1e-15,
            6.4e-14, 100, 0.5, np.zeros_like(s), np.zeros_like(s), memory, True)
    if colours is None:  # index order
        its, _, status, *_ = fn(*args, kernels.NO_FIELD, kernels.NO_ORDER, kernels.NO_ORDER,
                                kernels.NO_FIELD)
    else:  # the rows in colour order
        order, starts = pairs.colours()
        rows = ase_spin.neighbors.rows_in_order(pairs.row, pairs.j, c, order)
        its, _, status, *_ = fn(args[0], *rows, *args[4:], kernels.NO_FIELD, order, starts,
                               kernels.NO_FIELD)
    assert status != kernels.NOT_CONVERGED
    return its, st


@pytest.mark.parametrize("memory", [0, 3])
def test_colour_ordered_solve_reaches_the_index_order_solution_in_fewer_sweeps(memory):
    """fcc Co frozen at 3 fs: the colour-ordered solve reaches the index-order
    solve's end points to its tolerance, in fewer sweeps, with or without
    Anderson; its sweep is serial, so rows split into three chunks (the
    threaded kernel's, in the serial twin) give the same bits as one."""
    its_index, ref = _colour_solve(1, None, memory)
    its_colour, got = _colour_solve(1, True, memory)
    assert its_colour < its_index
    assert np.abs(got - ref).max() < 1e-13
    assert np.array_equal(_colour_solve(3, True, memory)[1], got)


def test_colour_ordered_sweeps_give_the_same_bits_in_any_chunks():
    """A simple cubic lattice (two colours, random couplings): the
    colour-ordered solve with the colours' boundaries in two or three chunks
    (each colour a parallel region, its spins split among them; threaded twin
    and serial twin) gives the bits of the serial sweep in one chunk."""
    from ase_spin.md import kernels

    row, nbr = _simple_cubic_full(6)
    order, starts = ase_spin.neighbors.greedy_colouring(row, nbr)
    assert len(starts) - 1 == 2
    rng = np.random.default_rng(3)
    n = len(row) - 1
    i = np.repeat(np.arange(n), 6)
    J = 0.01 * (1.0 + 0.3 * rng.random(n * 6))
    J = 0.5 * (J + J[np.lexsort((i, nbr))])  # J_ij = J_ji: a pair's two entries
    s = rng.normal(size=(n, 3)) * 0.3 + [0.0, 0.0, 1.0]
    s /= np.linalg.norm(s, axis=1)[:, None]
    scale = np.full(n, 40.0)  # c|B̄| ~ 2: solves of several sweeps
    rows = ase_spin.neighbors.rows_in_order(row, nbr, J, order)
    results = []
    for fn, nthreads in [(kernels.midpoint_solve.serial, 1), (kernels.midpoint_solve.serial, 3),
                         (kernels.midpoint_solve.parallel, 2)]:
        W, Wn, st, carry = s.copy(), np.zeros_like(s), np.zeros_like(s), np.zeros_like(s)
        its, _, status, which, *_ = fn(nthreads, *rows, s, W, Wn, st, scale, 1e-15,
                                       6.4e-14, 100, 0.5, np.zeros_like(s), carry, 0, True,
                                       kernels.NO_FIELD, order, starts, kernels.NO_FIELD)
        assert status != kernels.NOT_CONVERGED and its > 4
        results.append((its, (W if which == 0 else Wn).copy(), st.copy(), carry.copy()))
    for its, W, st, carry in results[1:]:
        assert its == results[0][0]
        for a, b in zip((W, st, carry), results[0][1:]):
            assert np.array_equal(a, b)


def test_frozen_stages_take_colour_order_where_it_pays():
    """policy.next_sweep_order: a stage tries colour order after an
    index-order solve of 5 sweeps or more, goes back after a colour-ordered
    one of 3 or fewer, and for good when colour order contracts by less than
    the index order's contraction to the power 1.3; Jacobi sweeps change
    nothing. fcc Co frozen: at 2 fs (order 4) every stage keeps colour order
    (contraction ~0.05-0.1 against ~0.2-0.3), at 0.05 fs none (two sweeps a
    solve, once the predictor has its history); a moving lattice never tries
    it; a frozen one of threaded size (4000 atoms) tries it, finds its 12
    colours too many there (CollectivePRK._colour_pairs) and keeps index
    order for good, its full list let go."""

    INDEX, COLOUR, KEPT = policy.INDEX_ORDER, policy.COLOUR_ORDER, policy.INDEX_ORDER_KEPT
    assert policy.next_sweep_order(INDEX, True, 5, 0.2, -1.0) == (COLOUR, 0.2)
    assert policy.next_sweep_order(INDEX, True, 4, -1.0, 0.3) == (INDEX, 0.3)
    assert policy.next_sweep_order(COLOUR, True, 3, 0.01, 0.2) == (INDEX, 0.2)
    assert policy.next_sweep_order(COLOUR, True, 6, 0.2 ** 1.4, 0.2) == (COLOUR, 0.2)
    assert policy.next_sweep_order(COLOUR, True, 6, 0.2 ** 1.2, 0.2) == (KEPT, 0.2)
    assert policy.next_sweep_order(KEPT, True, 9, 0.3, 0.2) == (KEPT, 0.3)
    assert policy.next_sweep_order(COLOUR, False, 1, -1.0, 0.2) == (COLOUR, 0.2)
    for dt, lattice, expected in [(2.0, "frozen", {COLOUR}), (0.05, "frozen", {INDEX, KEPT}),
                                  (2.0, "moving", {INDEX})]:
        dyn = CollectivePRK(fcc_cobalt(3), dt * units.fs, order=4, lattice=lattice)
        dyn.run(12)
        assert set(dyn._state.sweep_order) <= expected, (dt, lattice)
        assert (dyn._state.full_ops is None) == (lattice == "moving")
    dyn = CollectivePRK(fcc_cobalt(10), 2.0 * units.fs, order=4, lattice="frozen")
    dyn.run(3)
    assert set(dyn._state.sweep_order) == {KEPT} and dyn._state.full_ops is None


def test_colour_order_reads_the_full_lists_rows_in_colour_order():
    """fcc Co frozen (108 atoms) at 2 fs, order 4: the stages' colour-ordered
    solves read the full list's rows copied in colour order, kept once (each
    row the same pairs in the same order as the list's own)."""

    dyn = CollectivePRK(fcc_cobalt(3), 2.0 * units.fs, order=4, lattice="frozen")
    dyn.run(12)
    st = dyn._state
    assert policy.COLOUR_ORDER in set(st.sweep_order)
    c, (prow, pnbr, pc) = st.colour_rows
    pairs, J = st.full_ops[0].linear_pairs(False)
    assert c is J
    order, _ = pairs.colours()
    for a in range(len(order)):
        i = order[a]
        k, pk = slice(pairs.row[i], pairs.row[i + 1]), slice(prow[a], prow[a + 1])
        assert np.array_equal(pairs.j[k], pnbr[pk]) and np.array_equal(J[k], pc[pk])


def _simple_cubic_atoms(n, threads=None):
    """n³ Fe spins on a periodic simple cubic lattice (a = 2.5 Å), one
    nearest-neighbour exchange J = 10 meV, moments of 2 μB in a 30° cone."""
    from ase import Atoms

    from ase_spin.scenes import cone
    from spirit_peer import ConstantCoupling
    from ase_spin.terms import Exchange

    a = 2.5
    grid = np.stack(np.meshgrid(*[np.arange(n)] * 3, indexing="ij"), -1).reshape(-1, 3)
    atoms = Atoms(f"Fe{n ** 3}", positions=a * grid, cell=np.eye(3) * n * a, pbc=True)
    ase_spin.set_spins(atoms, cone(n ** 3, np.random.default_rng(7), 30.0), magnitudes=2.0)
    atoms.calc = SpinLatticeCalculator([Exchange(ConstantCoupling(0.01, 3.0), rc=3.0)])
    return atoms


@pytest.mark.alone
@pytest.mark.filterwarnings("ignore::ase_spin.md.errors.TimestepWarning")  # 4 fs: on purpose
def test_two_colourable_lattice_of_threaded_size_takes_colour_order():
    """Simple cubic, 12³ = 1 728 spins (threaded size), frozen, order 4 at
    4 fs: its stages take colour order (two colours), in fewer sweeps than
    with index order alone, to the same trajectory; one thread and two give
    the same bits."""
    from ase_spin._jit.threads import SERIAL_BELOW

    assert 12 ** 3 >= SERIAL_BELOW
    runs = {}
    for threads, colour in [(1, True), (2, True), (2, False)]:
        atoms = _simple_cubic_atoms(12)
        dyn = CollectivePRK(atoms, 4.0 * units.fs, order=4, lattice="frozen", threads=threads)
        if not colour:  # index order throughout
            dyn._choose_order = lambda *args: None
        dyn.run(6)
        runs[threads, colour] = (ase_spin.get_spins(atoms), dyn.total_iterations,
                                 set(dyn._state.sweep_order))
    assert policy.COLOUR_ORDER in runs[1, True][2]
    assert np.array_equal(runs[1, True][0], runs[2, True][0])
    assert runs[1, True][1] == runs[2, True][1] < 0.8 * runs[2, False][1]
    assert np.abs(runs[2, True][0] - runs[2, False][0]).max() < 1e-12


def test_predictor_depth_by_stages_and_size():
    """The second-order step keeps 16 increments (the least-squares row) from
    LEAST_SQUARES_FROM atoms, 12 below; compositions fewer; 4 from LARGE_SYSTEM."""
    from ase_spin.md import collective, kernels

    small, large = collective.LEAST_SQUARES_FROM, collective.LARGE_SYSTEM
    assert collective.predictor_depth(1, small - 1) == kernels.EXACT_ORDERS == 12
    assert collective.predictor_depth(1, small) == kernels.PREDICTOR_DEPTH == 16
    assert collective.predictor_depth(1, large - 1) == 16
    assert collective.predictor_depth(5, 500) == 6 and collective.predictor_depth(9, 500) == 4
    assert collective.predictor_depth(1, large) == 4


@pytest.mark.parametrize("n", [30, 500, 2000])
def test_extrapolation_is_the_ordered_sum_to_the_bit(n):
    """kernels.extrapolate (one loop over rows, serial or threaded) gives
    normalise(base + (c_0 h_0 + … + c_15 h_15)),
    each sum taken in that order and rounded as numpy rounds it: bit for bit,
    for the least-squares row and an exact order."""
    from collections import deque

    from ase_spin.md import kernels

    rng = np.random.default_rng(n)
    depth = kernels.PREDICTOR_DEPTH
    history = deque([1e-2 * rng.normal(size=(n, 3)) for _ in range(depth)], maxlen=depth)
    base = rng.normal(size=(n, 3))
    base[0] = 0.0
    history[-1][0] = 0.0  # a row of zero length stays zero
    for order in (depth - 1, 7):
        got = kernels.extrapolate(history, order, base)
        newest = kernels.newest_first(history, order)
        c = kernels.COEFFICIENTS[order]
        total = c[0] * newest[0]
        for m in range(1, depth):
            total = total + c[m] * newest[m]
        v = base + total
        norm = np.sqrt(v[:, 0] * v[:, 0] + v[:, 1] * v[:, 1] + v[:, 2] * v[:, 2])
        expected = np.where(norm[:, None] > 0.0, v / np.where(norm > 0.0, norm, 1.0)[:, None], v)
        assert np.array_equal(got, expected)


def test_round_off_does_not_accumulate_at_tiny_steps():
    """The paper chain over T = 2⁻⁸ at h = 2⁻²⁰ (4096 steps, h² error ~1e-17):
    the state stays within 1e-14 of a DOP853 solution. End points made from
    the rounded unit W alone moved every spin by ~2ε a step (1.4e-12 here):
    the locally exact sweeps keep W's part beyond the spin for them."""
    from ase_spin.md.ode import reference_solution
    from ase_spin.scenes import paper_chain

    t_end = 2.0**-8
    q, p, s = reference_solution(paper_chain(), t_end, rtol=1e-14, atol=1e-16)
    atoms = paper_chain()
    CollectivePRK(atoms, 2.0**-20).run(4096)
    assert np.abs(ase_spin.get_spins(atoms) - s).max() < 1e-14
    assert np.abs(atoms.positions - q).max() < 1e-14
