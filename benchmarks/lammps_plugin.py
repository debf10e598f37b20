"""The ase_spin LAMMPS plugin (fix spin/collective) against CollectivePRK and fix nve/spin.

    python benchmarks/lammps_plugin.py agreement            # the test matrix, with its figures
    python benchmarks/lammps_plugin.py scaling --sizes 6 10 --steps 40 --repeats 3
    python benchmarks/lammps_plugin.py energy --steps 100000 --n 2

agreement: fcc Co (LJ + exchange) and bcc Fe (EAM + exchange), orders 2 and 4, 50
steps of 0.1 fs on 1, 2 and 4 ranks: the plugin's final q, v, s against
CollectivePRK's, the ranks' runs against each other, and fix nve/spin's 1-, 2-
and 4-rank runs against each other. scaling: the peers.md fcc Co scene (4n³
atoms, n in --sizes) on 1 and 2 ranks, plugin and fix nve/spin, the runs
interleaved and the round repeated (--repeats): LAMMPS's loop time (medians,
ranges, the paired 1-to-2-rank speed-ups), and the plugin's own counters
(f_integrate[1], [2], [4] to [7]: sweeps, outer rounds, forward and reverse
ghost exchanges, global reductions a step, ghost atoms a rank) with the
communication cost they would have on a cluster of --latency and --bandwidth,
beside fix nve/spin's 32 sector exchanges a step (4 sweeps × 8 sectors, read
from its source). energy: the field + anisotropy scene
(scenes.field_anisotropy_terms, 4n³ atoms) with both fixes, etotal every 100
steps: the largest |E - E0| over the run and its first and last tenths, and the
fitted trend. Needs lammps, mpich's mpiexec, cmake and a C++ compiler; the
plugin is built into the user cache (ase-spin build-lammps-plugin).
"""

from __future__ import annotations

import argparse
import os
import re
import sys
import tempfile
from pathlib import Path

import numpy as np
from ase import units

sys.path.insert(0, os.path.dirname(__file__))
sys.path.insert(0, os.path.join(os.path.dirname(__file__), os.pardir, "tests"))

import ase_spin  # noqa: E402
from ase_spin.interop.lammps import write_lammps  # noqa: E402
from ase_spin.interop.lammps_plugin import build_plugin  # noqa: E402
from ase_spin.scenes import fcc_cobalt, field_anisotropy_terms  # noqa: E402
from machine import describe  # noqa: E402
import test_lammps_plugin as peer  # noqa: E402  (the scenes and runners of the tests)


def agreement(plugin, tmp):
    print("max |Δq| Å, max |Δv|/max|v|, max |Δs| after 50 steps of 0.1 fs")
    for name, scene in sorted(peer.SCENES.items()):
        for order in (2, 4):
            reference = peer._reference(scene, order)
            runs = peer._plugin_runs(tmp / f"{name}_{order}".replace(" ", "_"), plugin, scene,
                                     order, (1, 2, 4))
            for k, state in runs.items():
                print(f"{name} order {order}, {k} rank(s), plugin vs CollectivePRK: "
                      + ", ".join(f"{d:.1e}" for d in peer._difference(state, reference)))
            for k in (2, 4):
                print(f"{name} order {order}, plugin {k} ranks vs 1: "
                      + ", ".join(f"{d:.1e}" for d in peer._difference(runs[k], runs[1])))
        atoms = scene()
        splitting = ase_spin.SuzukiTrotter(atoms, 0.1 * units.fs, hbar=ase_spin.HBAR_LAMMPS)
        nve = {}
        for k in (1, 2, 4):
            folder = tmp / f"nve_{name}_{k}".replace(" ", "_")
            write_lammps(folder, atoms, splitting, steps=peer.STEPS, dump_interval=peer.STEPS)
            nve[k] = peer._state(peer._run(folder, k))
        for k in (2, 4):
            print(f"{name} fix nve/spin {k} ranks vs 1: "
                  + ", ".join(f"{d:.1e}" for d in peer._difference(nve[k], nve[1])))


def _deck(folder, atoms, dyn, plugin, steps, every, extra=""):
    """write_lammps's deck, its run replaced by a timed one with the fix's counters."""
    files = write_lammps(folder, atoms, dyn, steps=0, dump_interval=max(1, steps),
                         thermo_interval=every, plugin=plugin)
    text = files.input.read_text().rsplit("run 0", 1)[0]
    text += (f"thermo_style custom step pe ke etotal {extra}\nthermo_modify norm no "
             f"format float %.15g\nthermo {every}\nrun {steps}\n")
    files.input.write_text(text)
    return files


def _loop(folder):
    log = (folder / "log.lammps").read_text()
    m = re.search(r"Loop time of ([0-9.eE+-]+) on (\d+) procs for (\d+) steps", log)
    return float(m.group(1)), log


def _thermo(log):
    rows = []
    for line in log.splitlines():
        parts = line.split()
        if parts and parts[0].isdigit() and len(parts) >= 4:
            try:
                rows.append([float(p) for p in parts])
            except ValueError:
                pass
    return np.array(rows)


#: the plugin's counters (f_integrate[k]) the scaling runs log: sweeps, outer rounds,
#: forward and reverse ghost exchanges and global reductions a step, ghost atoms a rank
COUNTERS = ("sweeps", "rounds", "forward", "reverse", "reductions", "ghosts")


def _one_scaling_run(folder, ranks, steps):
    """(ms a step, the plugin's counters averaged over the logged steps or None)."""
    peer._run(folder, ranks)
    loop, log = _loop(folder)
    rows = _thermo(log)[1:]
    counters = None
    if rows.shape[1] > 4:
        counters = dict(zip(COUNTERS, rows[:, 4:].mean(axis=0)))
    return loop / steps * 1e3, counters


def scaling(plugin, tmp, sizes, steps, repeats, latency_us, bandwidth_GBs):
    """fcc Co (4n³ atoms for n in sizes), order 2, plugin and fix nve/spin on 1 and 2
    ranks: the runs interleaved (size, fix, ranks) and the whole round repeated, so
    that a busy machine's load falls on all alike; medians and ranges of ms/step,
    the 1-to-2-rank speed-up of each repeat (paired), and the plugin's measured
    communication a step with the cost it would have on a cluster of the given
    latency and bandwidth (docs/lammps.md, "The collective integrator in LAMMPS: the ase_spin plugin")."""
    decks = {}
    for n in sizes:
        atoms = fcc_cobalt(n, conventions="lammps")
        for label in ("plugin", "nve/spin"):
            folder = tmp / f"scaling_{n}_{label.replace('/', '_')}"
            if label == "plugin":
                dyn = ase_spin.CollectivePRK(atoms, 0.1 * units.fs, hbar=ase_spin.HBAR_LAMMPS)
                _deck(folder, atoms, dyn, plugin, steps, max(1, steps // 4),
                      " ".join(f"f_integrate[{k}]" for k in (1, 2, 4, 5, 6, 7)))
                decks[n, label] = (folder, steps, len(atoms))
            else:
                dyn = ase_spin.SuzukiTrotter(atoms, 0.1 * units.fs, hbar=ase_spin.HBAR_LAMMPS)
                _deck(folder, atoms, dyn, False, 5 * steps, steps)
                decks[n, label] = (folder, 5 * steps, len(atoms))
    times = {key + (k,): [] for key in decks for k in (1, 2)}
    counters, loads = {}, []
    for r in range(repeats):
        for (n, label), (folder, nsteps, _) in decks.items():
            for k in (1, 2):
                loads.append(os.getloadavg()[0])
                ms, c = _one_scaling_run(folder, k, nsteps)
                times[n, label, k].append(ms)
                if c is not None:
                    counters[n, k] = c
        print(f"repeat {r + 1} of {repeats} done", flush=True)
    print(f"fcc Co, order 2, 0.1 fs; plugin {steps} steps a run, fix nve/spin {5 * steps}; "
          f"{repeats} interleaved repeats; 1-minute load average {min(loads):.1f} to "
          f"{max(loads):.1f} on {os.cpu_count()} cores")
    for (n, label), (_, _, N) in decks.items():
        for k in (1, 2):
            v = np.array(times[n, label, k])
            print(f"N = {N:5d} {label:9s} {k} rank(s): median {np.median(v):8.2f} ms/step "
                  f"(range {v.min():.2f} to {v.max():.2f}), "
                  f"{np.median(v) / N * 1e3:.2f} µs/atom-step")
        speedup = np.array(times[n, label, 1]) / np.array(times[n, label, 2])
        print(f"N = {N:5d} {label:9s} speed-up 1 → 2 ranks: median {np.median(speedup):.2f} "
              f"(range {speedup.min():.2f} to {speedup.max():.2f})")
    for n in sizes:
        N = decks[n, "plugin"][2]
        for k in (1, 2):
            ratio = np.array(times[n, "plugin", k]) / np.array(times[n, "nve/spin", k])
            print(f"N = {N:5d} plugin / nve/spin on {k} rank(s): median {np.median(ratio):.2f} "
                  f"(range {ratio.min():.2f} to {ratio.max():.2f})")
        for k in (1, 2):
            c = counters[n, k]
            # atom_style spin: 7 doubles a ghost forward (x, sp), 9 in reverse (f, fm, fm_long);
            # LAMMPS's brick exchange: 6 messages (two a dimension) an exchange
            volume = 8 * c["ghosts"] * (7 * c["forward"] + 9 * c["reverse"])
            messages = 6 * (c["forward"] + c["reverse"]) + c["reductions"]
            cost = messages * latency_us * 1e-3 + volume / (bandwidth_GBs * 1e9) * 1e3
            print(f"N = {N:5d} plugin {k} rank(s): {c['sweeps']:.1f} sweeps, "
                  f"{c['rounds']:.1f} rounds, {c['forward']:.1f} forward + "
                  f"{c['reverse']:.1f} reverse exchanges and {c['reductions']:.1f} reductions "
                  f"a step, {c['ghosts']:.0f} ghost atoms a rank: {volume / 1e6:.2f} MB and "
                  f"{messages:.0f} messages a step, {cost:.2f} ms a step at "
                  f"{latency_us:g} µs and {bandwidth_GBs:g} GB/s")
        ghosts = counters[n, 2]["ghosts"]
        volume = 8 * ghosts * 7 * 32
        cost = 6 * 32 * latency_us * 1e-3 + volume / (bandwidth_GBs * 1e9) * 1e3
        print(f"N = {N:5d} fix nve/spin on > 1 rank: 32 forward exchanges a step "
              f"(8 sectors, 2 sweeps, 2 half steps; its source), at the same ghosts "
              f"{volume / 1e6:.2f} MB and 192 messages a step, {cost:.2f} ms a step")


def energy(plugin, tmp, n, steps, every=100):
    """Both fixes on the field + anisotropy scene for ``steps`` steps of 0.1 fs, etotal
    every ``every`` steps: max |E - E0| over the run and over its first and last
    tenths (bounded: the two alike; drifting: the last far above), and the
    straight line fitted to E - E0 against time (its change over the run)."""
    atoms = fcc_cobalt(n, extra=field_anisotropy_terms(), conventions="lammps")
    every = max(1, min(every, steps))
    print(f"fcc Co + 10 T field + anisotropy, N = {len(atoms)}, {steps} steps of 0.1 fs, "
          f"etotal every {every} steps")
    results = {}
    for label in ("plugin", "nve/spin"):
        folder = tmp / f"energy_{label.replace('/', '_')}"
        if label == "plugin":
            dyn = ase_spin.CollectivePRK(atoms, 0.1 * units.fs, hbar=ase_spin.HBAR_LAMMPS)
            _deck(folder, atoms, dyn, plugin, steps, every)
        else:
            dyn = ase_spin.SuzukiTrotter(atoms, 0.1 * units.fs, hbar=ase_spin.HBAR_LAMMPS)
            _deck(folder, atoms, dyn, False, steps, every)
        peer._run(folder, 1, timeout=None)
        loop, log = _loop(folder)
        rows = _thermo(log)
        e = rows[:, 3] - rows[0, 3]
        t = rows[:, 0] * 1e-4    # ps
        slope = np.polyfit(t, e, 1)[0]
        tenth = max(1, len(e) // 10)
        results[label] = e
        print(f"{label:9s}: max |E - E0| = {np.abs(e).max():.3e} eV (first tenth "
              f"{np.abs(e[:tenth]).max():.3e}, last tenth {np.abs(e[-tenth:]).max():.3e}), "
              f"fitted trend {slope * t[-1]:+.3e} eV over {t[-1]:g} ps, "
              f"{loop / steps * 1e3:.2f} ms/step")
    return results


def main(argv=None):
    parser = argparse.ArgumentParser()
    parser.add_argument("what", choices=["agreement", "scaling", "energy"])
    parser.add_argument("--n", type=int, default=None)
    parser.add_argument("--steps", type=int, default=None)
    parser.add_argument("--sizes", type=int, nargs="+", default=[6, 10],
                        help="scaling: fcc Co sizes n (4n³ atoms)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--latency", type=float, default=2.0, help="scaling model, µs")
    parser.add_argument("--bandwidth", type=float, default=10.0, help="scaling model, GB/s")
    args = parser.parse_args(argv)
    plugin = build_plugin()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        if args.what == "agreement":
            agreement(plugin, tmp)
        elif args.what == "scaling":
            scaling(plugin, tmp, [args.n] if args.n else args.sizes, args.steps or 40,
                    args.repeats, args.latency, args.bandwidth)
        else:
            energy(plugin, tmp, args.n or 2, args.steps or 100_000)
    print(describe())


if __name__ == "__main__":
    main()
