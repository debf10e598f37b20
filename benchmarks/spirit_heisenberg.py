"""Pure-spin Heisenberg ferromagnet: ase_spin's CollectivePRK (and its
SuzukiTrotter splitting) against Spirit (spirit-code, ``pip install spirit``):
one scene in both codes, one process.

    PYTHONPATH=. python benchmarks/spirit_heisenberg.py [--sizes 8 32] [--threads 1 2]
        [--repeats 3] [--budget 30] [--long-steps 100000 2000] [--tol T] [--quick]

The scene (spirit_peer.SpiritHeisenberg): simple cubic, a = 2.5 Å, periodic,
n³ spins, nearest-neighbour exchange J = 10 meV, E = −Σ_<ij> J s_i·s_j with each
pair once, moments μ = 2 μB, frozen lattice, no field, anisotropy, damping or
temperature. Initial spins uniform in a 30° cone about z (seeded): every wave vector
is excited; the fastest spin precesses with a period of ≈ 70 fs.

The equation of motion, in Spirit's units (meV, ps, μB):

    ds_i/dt = −(γ/μB)(1/μ_i) s_i × B_i,      B_i = −∂E/∂s_i = Σ_j J s_j,

with γ/μB from Spirit's constants; in ase_spin ``CollectivePRK(...,
precession="moment", gyromagnetic="moment", g=γħ/μB, hbar=ħ, lattice="frozen")``
(docs/conventions.md). Before measuring, the script checks the conventions: the
initial energies agree, and Spirit's RK4 and CollectivePRK order 4 converge to the
same DOP853 trajectory as dt → 0 (asserted).

Work–precision: every final state (t = --t-end ps) against one DOP853 solution
(rtol 1e-13) of the equation above: RMS over spins of |s_i − s_ref,i|. Steps are
powers of two of a picosecond (Spirit's set_timestep passes a C float). Wall time
covers the steps only: Spirit's ``simulation.n_shot`` after
``simulation.start(single_shot=True)`` (solver allocation, first field), ase_spin's
``dyn.run`` after the integrator has prepared its pair operators. Medians of
--repeats, the codes alternated within each repeat (all methods at one dt, then
the next dt). A method's ladder stops after a run longer than --budget s or an
error below 3e-12 (the reference's own accuracy). Each run's result also goes to stderr as it
finishes (progress).

Threads: the Spirit wheel on PyPI is built without OpenMP and without C++
threads (printed below): it runs on one thread. ase_spin runs with ``threads=1``
(equal footing) and ``threads=2``; systems under ``ase_spin._jit.threads.SERIAL_BELOW``
atoms run serial whatever is asked, so there only threads=1 is measured.
SuzukiTrotter (order 2 and 4, LAMMPS's Cayley rotation) sweeps the spins one
after the other: one thread.

The one-sweep floor (last table): each CollectivePRK order's cost at each error
if every midpoint solve took a single sweep, from its own error ladder and one
fit of µs per step against sweeps per step (solver_floor_table): how much of the
gap to Spirit is the method's error constant and how much its solver.

Energy: --long-steps steps (one count per size) at dt = 2⁻¹⁰ ps ≈ 0.98 fs
(Spirit's default step is 1 fs), every code's spins evaluated by ase_spin's
evaluator in double precision (Spirit's ``system.get_energy`` is a float32) 50
times along the run: max |E(t) − E(0)| per spin, and the value at the end.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
import warnings

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))
# the drivers of LAMMPS and Spirit (lammps_peer, spirit_peer) live with the tests
sys.path.insert(0, os.path.join(os.path.dirname(__file__), os.pardir, "tests"))

from ase_spin import CollectivePRK, SuzukiTrotter  # noqa: E402
from ase_spin.terms.base import Want  # noqa: E402
from ase_spin.md.errors import TimestepWarning  # noqa: E402
from ase_spin.md.compositions import composition_coefficients  # noqa: E402
from ase_spin.md.ode import reference_solution  # noqa: E402
from ase_spin.scenes import cone  # noqa: E402
from ase_spin.spins import get_spins  # noqa: E402
from spirit_peer import (SOLVERS, SpiritHeisenberg, load_spirit, run_collective, run_splitting,
    spirit_available)
from ase_spin._jit.threads import SERIAL_BELOW  # noqa: E402
from machine import describe  # noqa: E402

CONE_DEG = 30.0
SEED = 7
PS = 1000.0 * __import__("ase").units.fs
FLOOR = 3e-12

#: log2(1/dt in ps), largest step first; the ladders stop early (--budget, FLOOR)
SPIRIT_LADDERS = {"RK4": range(6, 17), "Heun": range(8, 17), "Depondt": range(7, 17),
                  "SIB": range(7, 17)}
PRK_LADDERS = {2: range(7, 17), 4: range(6, 16), 6: range(6, 15)}
#: ase_spin's SuzukiTrotter (LAMMPS's splitting, sequential sweeps, one thread)
SPLITTING_LADDERS = {2: range(6, 17), 4: range(5, 16)}


def rms(a, b):
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


def energy_eV(atoms, s):
    ev, _ = atoms.calc.bound_evaluator(atoms)
    return ev.evaluate(atoms.positions, s, Want(energy=True)).energy


def reference(scene, s0, t_end_ps):
    atoms = scene.atoms(s0)
    o = scene.integrator_options()
    t0 = time.perf_counter()
    _, _, s = reference_solution(atoms, t_end_ps * PS, hbar=o["hbar"], precession="moment",
                                 gyromagnetic="moment", g=o["g"], frozen_lattice=True)
    return s, time.perf_counter() - t0


def check_conventions(scene, s0, s_ref, t_end_ps):
    """Same energy, and both codes' trajectories converge to one DOP853 solution as
    dt → 0 (a wrong sign, factor 2, ħ or γ would leave an O(1) difference)."""
    atoms = scene.atoms(s0)
    e_ours = energy_eV(atoms, s0) * 1e3
    scene.set_spins(s0)
    e_spirit = scene.energy_meV()
    print(f"# conventions, N = {scene.nos}: initial energy ase_spin {e_ours:.6f} meV, "
          f"Spirit {e_spirit:.6f} meV (float32)")
    assert abs(e_ours - e_spirit) <= 1e-6 * abs(e_ours), (e_ours, e_spirit)
    errors = {}
    for k in (10, 11, 12):
        dt = 2.0**-k
        steps = int(round(t_end_ps / dt))
        s_sp, _ = scene.run("RK4", dt, steps, s0)
        s_pr, _, _ = run_collective(scene, s0, 4, dt, steps, threads=1)
        errors[k] = (rms(s_sp, s_ref), rms(s_pr, s_ref), rms(s_sp, s_pr))
        print(f"#   dt = 2^-{k} ps: |Spirit RK4 − ref| {errors[k][0]:.2e}, "
              f"|CollectivePRK 4 − ref| {errors[k][1]:.2e}, |Spirit − ase_spin| "
              f"{errors[k][2]:.2e}")
    moved = rms(s0, s_ref)
    assert moved > 0.1, moved
    for code in (0, 1):  # fourth order: 16× per halving (≥ 8× asked)
        assert errors[10][code] > 8 * errors[11][code] > 64 * errors[12][code], errors
        assert errors[12][code] < 1e-6 * moved, errors
    print(f"#   the spins moved by {moved:.3f} (RMS) in {t_end_ps} ps; both codes converge "
          "at fourth order to the same trajectory: conventions agree")


def work_precision(scene, s0, s_ref, t_end_ps, threads, repeats, budget, quick, tol):
    """Rows (code, method, threads, dt_ps, steps, error, median wall, sweeps/step)."""
    jobs = [("Spirit", solver, solver, 1, k)
            for solver, ks in SPIRIT_LADDERS.items() for k in ks]
    jobs += [("ase_spin", f"CollectivePRK order {order}", order, th, k)
             for order, ks in PRK_LADDERS.items() for th in threads for k in ks]
    jobs += [("ase_spin", f"SuzukiTrotter order {order}", order, 1, k)
             for order, ks in SPLITTING_LADDERS.items() for k in ks]
    if quick:
        jobs = [j for j in jobs if j[4] <= 9]
    order_of_runs = sorted(jobs, key=lambda j: (j[4], j[0], str(j[1]), j[3]))
    done, stopped = {}, set()
    for rep in range(repeats):
        for job in order_of_runs:
            code, label, what, th, k = job
            if rep == 0 and (code, label, th) in stopped:
                continue
            if rep > 0 and job not in done:
                continue
            dt = 2.0**-k
            steps = int(round(t_end_ps / dt))
            if code == "Spirit":
                s, wall = scene.run(what, dt, steps, s0)
                sweeps = float("nan")
            else:
                try:
                    if label.startswith("Suzuki"):
                        s, wall, sweeps = run_splitting(scene, s0, what, dt, steps)
                    else:
                        s, wall, sweeps = run_collective(scene, s0, what, dt, steps,
                                                         threads=th, tol=tol)
                except Exception as exc:  # the midpoint iteration may fail at large dt
                    if rep == 0:
                        print(f"# {label}, dt = 2^-{k} ps: {type(exc).__name__}: "
                              f"{str(exc)[:120]}")
                    continue
            err = rms(s, s_ref)
            if not np.isfinite(err) or err > 1.0:
                continue
            done.setdefault(job, []).append((err, wall, sweeps, steps))
            print(f"  [{rep + 1}/{repeats}] {code} {label}, {th} thread(s), dt = 2^-{k} ps: "
                  f"error {err:.2e}, {wall:.3g} s", file=sys.stderr, flush=True)
            if rep == 0 and (err < FLOOR or wall > budget):
                stopped.add((code, label, th))
    rows = []
    for (code, label, what, th, k), vals in done.items():
        rows.append((code, label, th, 2.0**-k, vals[0][3], vals[0][0],
                     float(np.median([v[1] for v in vals])), vals[0][2]))
    rows.sort(key=lambda r: (r[0] != "Spirit", r[1], r[2], -r[3]))
    return rows


def print_rows(rows, n):
    print(f"\n### work–precision, N = {n} spins\n")
    print("| code | method | threads | dt (fs) | steps | spin error (RMS) | wall (s) "
          "| µs/spin-step | sweeps/step |")
    print("|---|---|---|---|---|---|---|---|---|")
    for code, label, th, dt, steps, err, wall, sweeps in rows:
        sw = "" if not np.isfinite(sweeps) else f"{sweeps:.1f}"
        print(f"| {code} | {label} | {th} | {dt * 1e3:.4g} | {steps} | {err:.2e} | {wall:.4g} "
              f"| {wall / steps / n * 1e6:.3g} | {sw} |")


def wall_at(rows, target):
    """Wall time of one method at a given error: log-log interpolated between the
    two steps that bracket it; if even its largest working step is more accurate,
    the cheapest run (an upper bound, flagged); None if it never gets there."""
    pts = sorted((r[5], r[6]) for r in rows)
    for (e0, w0), (e1, w1) in zip(pts, pts[1:]):
        if e0 <= target <= e1 and e0 > 0:
            f = 0.0 if e1 == e0 else np.log(target / e0) / np.log(e1 / e0)
            return float(np.exp(np.log(w0) + f * (np.log(w1) - np.log(w0)))), ""
    if pts and pts[-1][0] < target:
        return min(w for e, w in pts), "≤ "
    return None


def equal_error_table(rows, n, threads):
    """Best Spirit solver against the best CollectivePRK order at each error (and
    against the best ase_spin method, SuzukiTrotter included)."""
    methods = {}
    for r in rows:
        methods.setdefault((r[0], r[1], r[2]), []).append(r)

    def best(select):
        found = [(w[0], w[1], key[1].replace("CollectivePRK ", "")
                  .replace("SuzukiTrotter order ", "splitting ")) for key, v in methods.items()
                 if select(key) for w in [wall_at(v, level)] if w is not None]
        return min(found) if found else None

    def cell(b):
        return f"{b[1]}{b[0]:.3g} ({b[2]})" if b else "not reached"

    print(f"\n### wall time at equal final-state error, N = {n} spins (each method "
          "interpolated along its dt ladder; the best of each code)\n")
    head = ["error", "Spirit, 1 thread (s)"]
    for t in threads:
        head += [f"CollectivePRK, {t} thread{'s' if t > 1 else ''} (s)", "ours / Spirit"]
    head += ["best ase_spin method (s)", "best / Spirit"]
    print("| " + " | ".join(head) + " |")
    print("|---" * len(head) + "|")
    for level in [1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10, 1e-11]:
        sp = best(lambda key: key[0] == "Spirit")
        cells = [f"{level:.0e}", cell(sp)]
        for t in threads:
            ours = best(lambda key, t=t: key[0] == "ase_spin" and key[2] == t
                        and key[1].startswith("CollectivePRK"))
            cells.append(cell(ours))
            cells.append(f"{ours[0] / sp[0]:.2f}" if ours and sp else "—")
        ours = best(lambda key: key[0] == "ase_spin")
        cells += [cell(ours), f"{ours[0] / sp[0]:.2f}" if ours and sp else "—"]
        if sp or any(c != "not reached" for c in cells[2::2]):
            print("| " + " | ".join(cells) + " |")


def solver_floor_table(rows, n, t_end_ps, threads):
    """What CollectivePRK would cost at each error if every midpoint solve took
    one sweep: the steps its error ladder needs there (dt log-log interpolated
    between the two runs that bracket the level) times the cost of a step
    with one sweep per stage, a_order + b · stages, from one least-squares fit
    of µs per step = a_order + b · sweeps per step over the runs of every order
    (a_order: a step's own work, b: a sweep, the same for every order). A
    sweep that moves W cannot also show it settled unless the predictor was
    already within round-off of the solution, so this is a floor no solve to
    round-off goes below, reached only where the steps are small: it separates
    what the method's error constant costs from what its solver costs."""
    print(f"\n### the one-sweep floor of CollectivePRK, N = {n} spins, {threads} thread(s) "
          "(steps the error needs × a step with one sweep per stage)\n")
    by_solver = {}
    for r in rows:
        if r[0] == "Spirit":
            by_solver.setdefault(r[1], []).append(r)
    own = {order: [r for r in rows if r[1] == f"CollectivePRK order {order}"
                   and r[2] == threads and np.isfinite(r[7])] for order in PRK_LADDERS}
    stages = {order: len(composition_coefficients(order)[1]) for order in PRK_LADDERS}
    if sum(len(v) for v in own.values()) < 4:
        return
    orders = [o for o in own if own[o]]
    A = np.array([[float(o == order) for o in orders] + [r[7]]
                  for order in orders for r in own[order]])
    y = np.array([r[6] / r[4] * 1e6 for order in orders for r in own[order]])
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    a, b = dict(zip(orders, coef[:-1])), coef[-1]
    worst = float(np.max(np.abs(A @ coef - y) / y))
    step = {o: a[o] + b * stages[o] for o in orders}
    print(f"µs per step = a + {b:.2f} × sweeps, a = " + ", ".join(
        f"{a[o]:.1f} (order {o})" for o in orders) + f" (fit over {len(y)} runs, largest "
        f"deviation {worst:.0%}); one sweep per stage: " + ", ".join(
        f"order {o} {step[o]:.1f} µs a step" for o in orders))
    head = ["error", "Spirit (s)"]
    for order in orders:
        head += [f"order {order} / Spirit", "its floor / Spirit"]
    print("\n| " + " | ".join(head) + " |")
    print("|---" * len(head) + "|")
    for level in [1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8]:
        found = [w for v in by_solver.values() for w in [wall_at(v, level)]
                 if w is not None and not w[1]]
        if not found:
            continue
        sp = min(found)[0]
        cells = [f"{level:.0e}", f"{sp:.3g}"]
        for order in orders:
            v = own[order]
            pts = sorted((r[5], r[3]) for r in v)  # (error, dt)
            dt = None
            for (e0, d0), (e1, d1) in zip(pts, pts[1:]):
                if e0 <= level <= e1 and 0 < e0 < e1:
                    f = np.log(level / e0) / np.log(e1 / e0)
                    dt = float(np.exp(np.log(d0) + f * (np.log(d1) - np.log(d0))))
            measured = wall_at(v, level) if v else None
            cells.append(f"{measured[0] / sp:.2f}" if measured and not measured[1] else "—")
            floor = None if dt is None else t_end_ps / dt * step[order] * 1e-6
            cells.append("—" if floor is None else f"{floor / sp:.2f}")
        print("| " + " | ".join(cells) + " |")


def long_run(scene, s0, steps, threads):
    """Energy error per spin over ``steps`` steps at dt = 2⁻¹⁰ ps, every method,
    sampled 50 times: the largest |E(t) − E(0)| in the first tenth of the run and
    in all of it (equal for a bounded error, ~10× apart for a linear drift)."""
    dt = 2.0**-10
    chunk = max(1, steps // 50)
    atoms0 = scene.atoms(s0)
    e0 = energy_eV(atoms0, s0)
    out = []

    def sampled(advance, spins):
        errors, wall = [], 0.0
        for _ in range(steps // chunk):
            t0 = time.perf_counter()
            advance(chunk)
            wall += time.perf_counter() - t0
            errors.append(energy_eV(atoms0, spins()) - e0)
        errors = np.array(errors)
        tenth = max(1, len(errors) // 10)
        return np.abs(errors[:tenth]).max(), np.abs(errors).max(), errors[-1], wall

    for solver in SOLVERS:
        scene.set_spins(s0)
        scene.start(solver, dt)
        out.append(("Spirit", solver, 1, *sampled(scene.steps, scene.spins)))
        scene.stop()
    for order in (2, 4, 6):
        atoms = scene.atoms(s0)
        dyn = CollectivePRK(atoms, dt * PS, order=order, threads=threads,
                            **scene.integrator_options())
        try:
            out.append(("ase_spin", f"CollectivePRK order {order}", threads,
                        *sampled(dyn.run, lambda atoms=atoms: get_spins(atoms))))
        except Exception as exc:
            print(f"# energy run, order {order}: {type(exc).__name__}: {str(exc)[:120]}")
    for order in SPLITTING_LADDERS:
        atoms = scene.atoms(s0)
        dyn = SuzukiTrotter(atoms, dt * PS, order=order, **scene.integrator_options())
        out.append(("ase_spin", f"SuzukiTrotter order {order}", 1,
                    *sampled(dyn.run, lambda atoms=atoms: get_spins(atoms))))
    n = scene.nos
    print(f"\n### energy over {steps} steps of 2^-10 ps = {dt * 1e3:.4g} fs "
          f"({steps * dt:.4g} ps), N = {n} spins, |E(0)|/N = {abs(e0) / n * 1e3:.3f} meV\n")
    print("| code | method | threads | max \\|E − E(0)\\|/N, first tenth (meV) "
          "| max \\|E − E(0)\\|/N, whole run (meV) | (E(end) − E(0))/N (meV) "
          "| wall (s) | µs/spin-step |")
    print("|---|---|---|---|---|---|---|---|")
    for code, label, th, first, drift, final, wall in out:
        print(f"| {code} | {label} | {th} | {first / n * 1e3:.2e} | {drift / n * 1e3:.2e} "
              f"| {final / n * 1e3:+.2e} | {wall:.4g} | {wall / steps / n * 1e6:.3g} |")


def loadavg():
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[8, 32],
                    help="lattice edges n (n³ spins); default 8 32 (512 and 32 768 spins)")
    ap.add_argument("--t-end", type=float, default=0.25, help="final time, ps (default 0.25)")
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--budget", type=float, default=30.0,
                    help="stop refining a method's dt after a run this long (s, default 30)")
    ap.add_argument("--long-steps", type=int, nargs="+", default=[100000, 2000],
                    help="steps of the energy run, one count per size (0 skips it)")
    ap.add_argument("--tol", type=float, default=None,
                    help="CollectivePRK's midpoint tolerance (default: its own, 1e-15)")
    ap.add_argument("--quick", action="store_true",
                    help="large steps only, one repeat, 500-step energy run (a smoke test)")
    args = ap.parse_args(argv)
    if not spirit_available():
        sys.exit("Spirit is not installed: pip install spirit (or pip install '.[test]')")
    import numba

    warnings.simplefilter("ignore", TimestepWarning)  # large steps on purpose
    v = load_spirit().version
    threads = [t for t in args.threads if t <= numba.config.NUMBA_NUM_THREADS]
    print(describe())
    print(f"# Spirit {v.version_full}, {v.scalartype}, OpenMP {v.openmp}, C++ threads "
          f"{v.threads}, CUDA {v.cuda}: 1 thread. ase_spin threads: {threads}, "
          f"midpoint tol {args.tol or 'default'}.")
    print(f"# load average at the start: {loadavg()}")
    repeats = 1 if args.quick else args.repeats
    long_steps = list(args.long_steps) + [args.long_steps[-1]] * len(args.sizes)
    cwd = os.getcwd()
    with tempfile.TemporaryDirectory() as work:
        os.chdir(work)  # Spirit stops a run if a file named STOP is in the working directory
        try:
            for n, lsteps in zip(args.sizes, long_steps):
                with SpiritHeisenberg(n) as scene:
                    g = scene.integrator_options()["g"]
                    print(f"\n## N = {scene.nos}: simple cubic a = {scene.a} Å, J = "
                          f"{scene.J_meV} meV, μ = {scene.mu} μB, γħ/μB = {g:.9f}, "
                          f"cone {CONE_DEG}°, t_end = {args.t_end} ps")
                    s0 = cone(scene.nos, np.random.default_rng(SEED), CONE_DEG)
                    s_ref, t_ref = reference(scene, s0, args.t_end)
                    print(f"# DOP853 reference (rtol 1e-13): {t_ref:.1f} s")
                    # compile, and load the compiled blocks of steps (fused.py): the
                    # first step alone, then a block
                    run_collective(scene, s0, 2, 2.0**-8, 4, threads=1)
                    check_conventions(scene, s0, s_ref, args.t_end)
                    th = threads if scene.nos >= SERIAL_BELOW else threads[:1]
                    rows = work_precision(scene, s0, s_ref, args.t_end, th, repeats,
                                          args.budget, args.quick, args.tol)
                    print_rows(rows, scene.nos)
                    equal_error_table(rows, scene.nos, th)
                    solver_floor_table(rows, scene.nos, args.t_end, th[0])
                    if lsteps > 0:
                        long_run(scene, s0, 500 if args.quick else lsteps, th[0])
                    print(f"\n# load average: {loadavg()}")
        finally:
            os.chdir(cwd)


if __name__ == "__main__":
    main()
