"""Monte Carlo sweeps against Langevin steps: the simple-cubic Heisenberg
magnet (J = 10 meV, nearest neighbours), MonteCarlo (Metropolis, and with 2
over-relaxation sweeps) and Langevin (frozen lattice, 2 fs).

Two measurements:

- the default, speed: sweeps and steps per second at 0.6 T_C (Langevin with
  λ = 0.5), for a few sizes;

      python benchmarks/montecarlo_cost.py [--sizes 4 8 16] [--seconds 3]

- ``--error``, the work to a given standard error of ⟨|m|⟩ at 0.6 T_C and at
  T_C (T_C = 1.443 J/k_B): per size, temperature and sampler, a series of |m|
  (every sweep or step, after equilibration) for ``--seconds`` of CPU, its
  integrated autocorrelation time τ_int (Sokal's windowing, with its error;
  the blocking estimate beside it), var(|m|) and the CPU time per sweep or
  step, hence the CPU time to reach a standard error σ of ⟨|m|⟩,

      t(σ) = 2 τ_int · (CPU time per sweep or step) · var(|m|)/σ²,

  and the ratio of each sampler's t(σ) to that of the fastest Langevin run.
  Every sampler starts from the same configuration, equilibrated by Monte
  Carlo with over-relaxation (``--pre-sweeps``), and equilibrates again by
  itself for a tenth of its budget. The same series check that Monte Carlo
  and Langevin agree on ⟨|m|⟩ and ⟨E⟩ within their errors (blocking). One
  thread each (``--threads``), so that CPU time is the cost;

      nice -n 5 python benchmarks/montecarlo_cost.py --error [--sizes 8 16]
          [--fractions 0.6 1.0] [--seconds 10] [--langevin-seconds 60]
          [--dampings 0.5 1.0] [--every 5]   (--seconds 0: Langevin only)
"""

import argparse
import os
import sys
import time

import numpy as np

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--error", action="store_true",
                    help="measure the work to a given error of <|m|> (autocorrelation times)")
parser.add_argument("--sizes", type=int, nargs="+", default=None,
                    help="cubes of L^3 spins (default 4 8 16; with --error 8 16)")
parser.add_argument("--seconds", type=float, default=None,
                    help="time per measurement (default 3; with --error CPU seconds per "
                         "Monte Carlo series, 10)")
parser.add_argument("--langevin-seconds", type=float, default=60.0,
                    help="--error: CPU seconds per Langevin series")
parser.add_argument("--every", type=int, default=5,
                    help="--error: Langevin steps between samples of |m| (well below τ_int)")
parser.add_argument("--pre-sweeps", type=int, default=2000,
                    help="--error: sweeps of Monte Carlo (+ 2 OR) equilibrating the start")
parser.add_argument("--fractions", type=float, nargs="+", default=[0.6, 1.0],
                    help="--error: temperatures as fractions of T_C")
parser.add_argument("--dampings", type=float, nargs="+", default=[0.5, 1.0],
                    help="--error: Langevin spin dampings λ")
parser.add_argument("--relative-error", type=float, default=1e-3,
                    help="--error: the target standard error σ of <|m|> relative to <|m|>")
parser.add_argument("--threads", default="1" if "--error" in sys.argv else "auto",
                    help='threads of every sampler (default 1 with --error, else "auto")')
args = parser.parse_args()
os.environ["ASE_SPIN_THREADS"] = str(args.threads)  # read when the samplers are made

from ase import units  # after the thread setting
from ase.build import bulk

import ase_spin
from ase_spin import Langevin, MonteCarlo, ShellExchange, SpinLatticeCalculator
from ase_spin.analysis import autocorrelation_time, block_average

J = 0.010  # eV
TC = J / (0.693035 * units.kB)  # K: Chen, Ferrenberg and Landau 1993, K_c = 0.693035
DT = 2.0 * units.fs


def scene(L, spins=(0, 0, 1)):
    atoms = bulk("Fe", "sc", a=2.5).repeat(L)
    ase_spin.set_spins(atoms, spins, magnitudes=2.0)
    atoms.calc = SpinLatticeCalculator([ShellExchange([(2.5, J)])])
    return atoms


def monte_carlo(L, T, overrelaxation=0, seed=1, spins=(0, 0, 1)):
    return MonteCarlo(scene(L, spins), temperature_K=T, seed=seed,
                      overrelaxation=overrelaxation)


def langevin(L, T, damping=0.5, seed=1, spins=(0, 0, 1)):
    return Langevin(scene(L, spins), DT, temperature_K=T, spin_damping=damping, friction=0.0,
                    lattice="frozen", rng=seed)


def speed():
    sizes = args.sizes or [4, 8, 16]
    seconds = 3.0 if args.seconds is None else args.seconds
    T = 0.6 * TC

    def rate(run, chunk):
        run(chunk)  # warm-up (compilation, caches)
        n, start = 0, time.perf_counter()
        while time.perf_counter() - start < seconds:
            run(chunk)
            n += chunk
        return n / (time.perf_counter() - start)

    print(f"{'atoms':>6} {'MC sweeps/s':>12} {'MC+2 OR /s':>11} {'Langevin steps/s':>17}   "
          "ns per atom: MC, MC+2 OR, Langevin")
    for L in sizes:
        n = L ** 3
        chunk = max(1, 20000 // n)
        mc = rate(monte_carlo(L, T).run, chunk)
        mcor = rate(monte_carlo(L, T, overrelaxation=2).run, chunk)
        ld = rate(langevin(L, T).run, chunk)
        print(f"{n:6d} {mc:12.1f} {mcor:11.1f} {ld:17.1f}   "
              f"{1e9 / (mc * n):.0f}, {1e9 / (mcor * n):.0f}, {1e9 / (ld * n):.0f}", flush=True)


def series(dyn, seconds, equilibrate, chunk, every=1, energy_every=10):
    """Equilibrate (``equilibrate`` steps, and at least a tenth of the
    budget), then record |m| every ``every`` steps and E every
    ``energy_every`` samples for ``seconds`` of this process's CPU time,
    reading the sampler between ``run(every)`` calls: an observer attached to
    an integrator would have it publish its results (forces, energies) at
    every call, which costs more than a step on a frozen lattice. Returns
    (|m|, E, CPU seconds per step of the recorded run, steps)."""
    m, e = [], []
    dyn.run(min(chunk, equilibrate))  # compilation out of the clock
    start = time.process_time()
    done = min(chunk, equilibrate)
    while done < equilibrate or time.process_time() - start < 0.1 * seconds:
        dyn.run(chunk)
        done += chunk
    start = time.process_time()
    while time.process_time() - start < seconds:
        for _ in range(max(1, chunk // every)):
            dyn.run(every)
            m.append(float(np.linalg.norm(dyn.get_magnetization())))
            if len(m) % energy_every == 1:
                e.append(dyn.get_magnetic_energy())
    cpu = time.process_time() - start
    return np.array(m), np.array(e), cpu / (every * len(m)), every * len(m)


def work(L, fraction):
    """Every sampler at one size and temperature: a row each, the
    agreement of the Langevin runs with Monte Carlo, the ratios."""
    T = fraction * TC
    n = L ** 3
    pre = monte_carlo(L, T, overrelaxation=2, seed=0)
    pre.run(args.pre_sweeps)
    s = ase_spin.get_spins(pre.atoms)
    seconds = 10.0 if args.seconds is None else args.seconds
    samplers = []
    if seconds > 0:
        samplers += [("MC", "sweeps", lambda: monte_carlo(L, T, spins=s), 1, seconds),
                     ("MC + 2 OR", "sweeps", lambda: monte_carlo(L, T, 2, spins=s), 1, seconds)]
    samplers += [(f"Langevin λ={lam:g}", "steps", lambda lam=lam: langevin(L, T, lam, spins=s),
                  args.every, args.langevin_seconds) for lam in args.dampings]
    rows = []
    for name, unit, make, every, budget in samplers:
        dyn = make()
        m, e, cost, steps = series(dyn, budget, equilibrate=1000, chunk=50 * every,
                                   every=every)
        # τ in steps from samples every k steps: k τ_samples (exact to O(k²/τ²))
        tau = autocorrelation_time(m)
        tau = type(tau)(every * tau.value, every * tau.error)
        mean = block_average(m)
        energy = block_average(e / n)
        tau_blocks = every * 0.5 * (mean.error / (m.std() / np.sqrt(len(m)))) ** 2
        sigma = args.relative_error * mean.value
        t_sigma = 2 * tau.value * cost * m.var() / sigma ** 2
        rows.append({"name": name, "unit": unit, "tau": tau, "m": mean, "e": energy,
                     "t": t_sigma})
        print(f"{n:6d} {fraction:5.2f} {name:>16} {steps:9d} {unit:>6} "
              f"τ_int {tau.value:9.1f} ± {tau.error:<7.2g} (blocking {tau_blocks:8.1f}, "
              f"n/τ {steps / tau.value:6.0f})  <|m|> {mean}  var {m.var():.3g}  "
              f"<E>/N {energy.value * 1e3:.4f} ± {energy.error * 1e3:.2g} meV  "
              f"{cost * 1e3:.3f} ms/{unit[:-1]}  t(σ) {t_sigma:.3g} s", flush=True)
    if len(rows) < 2:
        return rows
    reference = min((r for r in rows if r["unit"] == "steps"), key=lambda r: r["t"])
    for r in rows:
        if r is reference:
            continue
        dm = (r["m"].value - reference["m"].value) / np.hypot(r["m"].error, reference["m"].error)
        de = (r["e"].value - reference["e"].value) / np.hypot(r["e"].error, reference["e"].error)
        print(f"{'':12} {r['name']:>16} against {reference['name']}: <|m|> {dm:+.1f} σ, "
              f"<E> {de:+.1f} σ; t(σ) ratio {r['t'] / reference['t']:.3g}", flush=True)
    return rows


def error():
    print(" ".join(sys.argv))
    print(f"load average {os.getloadavg()}, threads {args.threads}, σ = "
          f"{args.relative_error:g} <|m|>", flush=True)
    start = time.process_time(), time.perf_counter()
    for L in args.sizes or [8, 16]:
        for fraction in args.fractions:
            work(L, fraction)
    print(f"load average {os.getloadavg()}; CPU {time.process_time() - start[0]:.0f} s, "
          f"wall {time.perf_counter() - start[1]:.0f} s", flush=True)


if __name__ == "__main__":
    error() if args.error else speed()
