"""relax_spins before and after it took its steps in blocks (issue 36, item 7).

    python benchmarks/relax_spins.py [--cells 4 4 9] [--fmax 1e-6] [--seed 0]
                                     [--before-steps N] [--skip-before]

Scene: fcc Co, a = 3.54 Å, cubic cell repeated ``--cells`` (4 × 4 × 9: 576
atoms), periodic; the Bethe–Slater exchange of ``ase_spin.scenes`` (LAMMPS
examples/SPIN/cobalt_fcc), a uniaxial anisotropy K = 0.01 eV along x and
μ = 1.72 μB; spins drawn uniformly on the sphere (``--seed``). Physical
conventions, frozen lattice (relax_spins does not move atoms), λ = 1 and
relax_spins's own timestep.

"before" is the per-step loop relax_spins ran until issue 36 (reproduced
below, :func:`relax_before`: a probe integrator for the timestep, then one
``dyn.step()`` and one full ``get_magnetic_forces()`` per step); "after" is
``ase_spin.relax_spins`` as it is now (blocks of ``dyn.run(k)``, the torque
from the fields the steps already have). Both start from the same spins. For
scale, a ``Langevin`` (T = 0, λ = 1, frozen lattice) and a ``CollectivePRK``
(frozen lattice) step on the same system at the same timestep, each in one
``run()`` with nothing attached. Printed: the machine, then steps, total
seconds and ms per step (total/steps, set-up included) side by side, the
largest torque at the end and the TimestepWarnings each raised, and the cost
of the set-up of one Langevin. ``--before-steps N`` stops the "before" loop
after N steps (it takes minutes: 35 ms a step) and reports its time per
step only.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings

import numpy as np
from ase import units
from ase.build import bulk

sys.path.insert(0, os.path.dirname(__file__))
sys.path.insert(0, os.environ.get("ASE_SPIN_TREE") or os.path.join(os.path.dirname(__file__), ".."))

import ase_spin  # noqa: E402
from ase_spin import (CollectivePRK, Langevin, SpinLatticeCalculator,  # noqa: E402
                      UniaxialAnisotropy, relax_spins, set_spins)
from ase_spin.md.errors import TimestepWarning  # noqa: E402
from ase_spin.scenes import fcc_cobalt_terms  # noqa: E402
from machine import describe  # noqa: E402


def scene(cells, seed):
    atoms = bulk("Co", "fcc", a=3.54, cubic=True).repeat(tuple(cells))
    atoms.set_masses(np.full(len(atoms), 58.93))
    s = np.random.default_rng(seed).normal(size=(len(atoms), 3))
    set_spins(atoms, s / np.linalg.norm(s, axis=1)[:, None], magnitudes=1.72)
    atoms.calc = SpinLatticeCalculator([*fcc_cobalt_terms(),
                                        UniaxialAnisotropy(0.01, [1.0, 0.0, 0.0])])
    return atoms


def relax_before(atoms, *, fmax=1e-6, damping=1.0, steps=100_000, stop_after=None):
    """relax_spins as it was before issue 36 (its loop, without the restore on
    errors): a probe Langevin at timestep 1 for the fields, then per step one
    full evaluation of the magnetic forces and one ``dyn.step()``. Returns
    (steps taken, largest torque, reached fmax)."""
    probe = Langevin(atoms, 1.0, 0.0, spin_damping=damping, friction=0.0, lattice="frozen")
    B = probe.get_magnetic_forces()
    probe._sync()
    field = float((np.linalg.norm(B, axis=1) * probe._state.rate).max(initial=0.0))
    timestep = 0.2 * probe.hbar / field
    dyn = Langevin(atoms, timestep, 0.0, spin_damping=damping, friction=0.0, lattice="frozen")
    limit = steps if stop_after is None else min(steps, stop_after)
    for n in range(limit + 1):
        B = dyn.get_magnetic_forces()
        torque = float(np.linalg.norm(np.cross(dyn._state.s, B), axis=1).max(initial=0.0))
        if torque <= fmax:
            return n, torque, True
        if n < limit:
            dyn.step()
    return limit, torque, False


def torque_of(atoms):
    B = atoms.calc.get_property("magnetic_forces", atoms)
    return float(np.linalg.norm(np.cross(ase_spin.get_spins(atoms), B), axis=1).max())


def timed(function):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", TimestepWarning)
        t0 = time.perf_counter()
        result = function()
        wall = time.perf_counter() - t0
    return result, wall, sum(isinstance(w.message, TimestepWarning) for w in caught)


def step_cost(atoms, dt, make, steps=200):
    dyn = make(atoms, dt)
    dyn.run(5)  # compiled, predictor history
    t0 = time.perf_counter()
    dyn.run(steps)
    return (time.perf_counter() - t0) / steps


def setup_cost(cells, seed):
    """Seconds to make one Langevin on the scene and bring its state up (pair
    list, operators; the timestep check skipped): paid once by "after", twice
    by "before" (its probe, then the integrator)."""
    atoms = scene(cells, seed)
    t0 = time.perf_counter()
    dyn = Langevin(atoms, 1.0, 0.0, spin_damping=1.0, friction=0.0, lattice="frozen")
    dyn._checked_dt = dyn.dt
    dyn._sync()
    return time.perf_counter() - t0


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--cells", type=int, nargs=3, default=[4, 4, 9])
    ap.add_argument("--fmax", type=float, default=1e-6)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--before-steps", type=int, default=None,
                    help="stop the old loop after this many steps (time per step only)")
    ap.add_argument("--skip-before", action="store_true")
    args = ap.parse_args(argv)
    print(describe(), flush=True)
    atoms = scene(args.cells, args.seed)
    print(f"# fcc Co {'x'.join(map(str, args.cells))}: {len(atoms)} atoms, exchange + "
          f"anisotropy, random spins (seed {args.seed}), fmax = {args.fmax:g} eV, λ = 1",
          flush=True)

    # compile everything both need first (untimed)
    warm = scene(args.cells, args.seed)
    relax_before(warm, stop_after=3)
    relax_spins(scene(args.cells, args.seed), fmax=args.fmax, steps=200_000)

    after_atoms = scene(args.cells, args.seed)
    (n_after), wall_after, warned_after = timed(
        lambda: relax_spins(after_atoms, fmax=args.fmax, steps=200_000))
    rows = [("after (blocks)", n_after, wall_after, True, torque_of(after_atoms),
             warned_after)]
    if not args.skip_before:
        before_atoms = scene(args.cells, args.seed)
        (n_before, torque, reached), wall_before, warned_before = timed(
            lambda: relax_before(before_atoms, fmax=args.fmax, steps=200_000,
                                 stop_after=args.before_steps))
        rows.insert(0, ("before (per step)", n_before, wall_before, reached, torque,
                        warned_before))

    # one step of the integrators on the same system, at relax_spins's timestep
    probe = Langevin(scene(args.cells, args.seed), 1.0, 0.0, spin_damping=1.0, friction=0.0,
                     lattice="frozen")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", TimestepWarning)
        B = probe.get_magnetic_forces()
    probe._sync()
    dt = 0.2 * probe.hbar / float((np.linalg.norm(B, axis=1) * probe._state.rate).max())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", TimestepWarning)
        langevin = step_cost(scene(args.cells, args.seed), dt, lambda a, h: Langevin(
            a, h, 0.0, spin_damping=1.0, friction=0.0, lattice="frozen"))
        nve = step_cost(scene(args.cells, args.seed), dt,
                        lambda a, h: CollectivePRK(a, h, lattice="frozen"))

    setup = min(setup_cost(args.cells, args.seed) for _ in range(3))
    print(f"# timestep {dt / units.fs:.4g} fs; set-up of one Langevin (pair list, operators): "
          f"{1e3 * setup:.0f} ms, in the totals (before: twice)")
    print(f"{'':20s} {'steps':>7s} {'total s':>9s} {'ms/step':>8s} {'reached':>8s} "
          f"{'max torque eV':>14s} {'TimestepWarnings':>17s}")
    for name, n, wall, reached, torque, warned in rows:
        print(f"{name:20s} {n:7d} {wall:9.2f} {1e3 * wall / max(n, 1):8.2f} "
              f"{'yes' if reached else 'no':>8s} {torque:14.3g} {warned:17d}")
    print(f"{'Langevin step':20s} {'':7s} {'':9s} {1e3 * langevin:8.2f}")
    print(f"{'CollectivePRK step':20s} {'':7s} {'':9s} {1e3 * nve:8.2f}")


if __name__ == "__main__":
    main()
