"""The ase_spin LAMMPS plugin (fix spin/collective) against CollectivePRK and fix nve/spin.

    python benchmarks/lammps_plugin.py agreement            # the test matrix, with its figures
    python benchmarks/lammps_plugin.py scaling --n 10 --steps 100
    python benchmarks/lammps_plugin.py energy --steps 100000 --n 5

agreement: fcc Co (LJ + exchange) and bcc Fe (EAM + exchange), orders 2 and 4, 50
steps of 0.1 fs on 1, 2 and 4 ranks: the plugin's final q, v, s against
CollectivePRK's, the ranks' runs against each other, and fix nve/spin's 1-, 2-
and 4-rank runs against each other. scaling: the peers.md fcc Co scene (4n³
atoms) on 1 and 2 ranks, plugin and fix nve/spin: LAMMPS's loop time, and the
plugin's sweeps and outer rounds per step (its f_integrate[1], [2]), hence its
forward communications per step (2 a sweep, 1 a round, 1 at the end: a
cluster's weak-scaling cost is that many ghost exchanges a step against
nve/spin's 4 × 8 sector exchanges). energy: the field + anisotropy scene
(scenes.field_anisotropy_terms) with both fixes: the total energy's largest
error and drift. Needs lammps, mpich's mpiexec, cmake and a C++ compiler; the
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


def scaling(plugin, tmp, n, steps):
    atoms = fcc_cobalt(n, conventions="lammps")
    N = len(atoms)
    print(f"fcc Co N = {N}, {steps} steps of 0.1 fs, order 2")
    for label in ("plugin", "nve/spin"):
        for k in (1, 2):
            folder = tmp / f"scaling_{label.replace('/', '_')}_{k}"
            if label == "plugin":
                dyn = ase_spin.CollectivePRK(atoms, 0.1 * units.fs, hbar=ase_spin.HBAR_LAMMPS)
                _deck(folder, atoms, dyn, plugin, steps, steps // 4 or 1,
                      "f_integrate[1] f_integrate[2]")
            else:
                dyn = ase_spin.SuzukiTrotter(atoms, 0.1 * units.fs, hbar=ase_spin.HBAR_LAMMPS)
                _deck(folder, atoms, dyn, False, steps, steps // 4 or 1)
            peer._run(folder, k)
            loop, log = _loop(folder)
            line = (f"{label:9s} {k} rank(s): {loop / steps * 1e3:.2f} ms/step, "
                    f"{loop / steps / N * 1e6:.2f} µs/atom-step")
            if label == "plugin":
                rows = _thermo(log)[1:]
                sweeps, rounds = rows[:, -2].mean(), rows[:, -1].mean()
                line += (f", {sweeps:.1f} sweeps and {rounds:.1f} rounds a step: "
                         f"{2 * sweeps + rounds + 1:.0f} ghost exchanges a step")
            else:
                line += ", 4 × 8 sector ghost exchanges a step (on > 1 rank)"
            print(line)


def energy(plugin, tmp, n, steps, samples=200):
    atoms = fcc_cobalt(n, extra=field_anisotropy_terms(), conventions="lammps")
    every = max(1, steps // samples)
    print(f"fcc Co + 10 T field + anisotropy, N = {len(atoms)}, {steps} steps of 0.1 fs")
    for label in ("plugin", "nve/spin"):
        folder = tmp / f"energy_{label.replace('/', '_')}"
        if label == "plugin":
            dyn = ase_spin.CollectivePRK(atoms, 0.1 * units.fs, hbar=ase_spin.HBAR_LAMMPS)
            _deck(folder, atoms, dyn, plugin, steps, every)
        else:
            dyn = ase_spin.SuzukiTrotter(atoms, 0.1 * units.fs, hbar=ase_spin.HBAR_LAMMPS)
            _deck(folder, atoms, dyn, False, steps, every)
        peer._run(folder, 1)
        loop, log = _loop(folder)
        rows = _thermo(log)
        e = rows[:, 3] - rows[0, 3]
        t = rows[:, 0] * 1e-4
        slope = np.polyfit(t, e, 1)[0]
        print(f"{label:9s}: max |E - E0| = {np.abs(e).max():.3e} eV, fitted drift "
              f"{slope * t[-1]:+.3e} eV over {t[-1]:g} ps, {loop / steps * 1e3:.2f} ms/step")


def main(argv=None):
    parser = argparse.ArgumentParser()
    parser.add_argument("what", choices=["agreement", "scaling", "energy"])
    parser.add_argument("--n", type=int, default=None)
    parser.add_argument("--steps", type=int, default=None)
    args = parser.parse_args(argv)
    plugin = build_plugin()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        if args.what == "agreement":
            agreement(plugin, tmp)
        elif args.what == "scaling":
            scaling(plugin, tmp, args.n or 10, args.steps or 100)
        else:
            energy(plugin, tmp, args.n or 5, args.steps or 100_000)
    print(describe())


if __name__ == "__main__":
    main()
