"""Where the memory of a CollectivePRK run goes: peak and retained resident
memory per phase (neighbour-list build, operators, midpoint solve, ...) and the
arrays the run keeps, on the fcc Co scene (dt = 0.1 fs, order 2).

    python benchmarks/memory.py [--n 40] [--steps 3] [--rebuild-at K]

Each phase is a function wrapped so that, on entry, the kernel's peak-RSS mark
is reset (``/proc/self/clear_refs``, Linux) and on exit the peak reached inside
is read (``VmHWM``): this sees every allocation, numpy's, numba's and vesin's
alike. Nested phases fold their peaks into the enclosing ones. Printed per
phase: calls, the largest rise of the peak above the RSS at entry (MB), and
the RSS retained after the last call relative to its entry (MB). ``--rebuild-at K``
makes step K rebuild the neighbour list (as a long run does every few hundred
steps): its operators are prepared anew on the new list.
"""

from __future__ import annotations

import argparse
import functools
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))


def _status(key):
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(key):
                return int(line.split()[1]) / 1024.0  # MB
    raise KeyError(key)


def _reset_peak():
    with open("/proc/self/clear_refs", "w") as f:
        f.write("5")


class Phases:
    def __init__(self):
        self.stack = []  # [label, rss at entry, running peak]
        self.rows = {}   # label -> [calls, max rise, last retained, total s]

    def _fold(self):
        hwm = _status("VmHWM")
        for entry in self.stack:
            entry[2] = max(entry[2], hwm)

    def wrap(self, owner, name, label=None):
        label = label or f"{owner.__name__}.{name}"
        original = getattr(owner, name)
        phases = self

        @functools.wraps(original)
        def wrapped(*args, **kwargs):
            phases._fold()
            rss = _status("VmRSS")
            _reset_peak()
            phases.stack.append([label, rss, rss])
            t0 = time.perf_counter()
            try:
                return original(*args, **kwargs)
            finally:
                dt = time.perf_counter() - t0
                phases._fold()
                _, rss0, peak = phases.stack.pop()
                after = _status("VmRSS")
                row = phases.rows.setdefault(label, [0, 0.0, 0.0, 0.0])
                row[0] += 1
                row[1] = max(row[1], peak - rss0)
                row[2] = after - rss0
                row[3] += dt

        setattr(owner, name, wrapped)


def arrays_held(obj, seen=None, path="", out=None, depth=0):
    """(path, MB) of every numpy array reachable from obj's attributes."""
    import numpy as np

    if seen is None:
        seen, out = set(), []
    if id(obj) in seen or depth > 12:
        return out
    seen.add(id(obj))
    if isinstance(obj, np.ndarray):
        base = obj if obj.base is None else None
        if base is not None and obj.nbytes > 1 << 20:
            out.append((path, obj.nbytes / 2**20))
        return out
    if isinstance(obj, dict):
        items = obj.items()
    elif isinstance(obj, (list, tuple)) or type(obj).__name__ == "deque":
        items = enumerate(obj)
    elif hasattr(obj, "__dict__") or hasattr(obj, "__slots__"):
        names = list(getattr(obj, "__dict__", {}))
        for cls in type(obj).__mro__:
            names += [s for s in getattr(cls, "__slots__", ()) if isinstance(s, str)]
        items = [(k, getattr(obj, k, None)) for k in names]
    else:
        return out
    for k, v in items:
        if isinstance(v, (str, bytes, int, float, bool, type(None))):
            continue
        if type(v).__module__.startswith(("ase.", "numba", "vesin")) and not isinstance(
                v, np.ndarray) and type(v).__name__ not in ("Atoms",):
            continue
        arrays_held(v, seen, f"{path}.{k}" if path else str(k), out, depth + 1)
    return out


def main(argv=None):
    parser = argparse.ArgumentParser()
    parser.add_argument("--n", type=int, default=40, help="fcc Co repeats (4n³ atoms)")
    parser.add_argument("--steps", type=int, default=3)
    parser.add_argument("--rebuild-at", type=int, default=0)
    args = parser.parse_args(argv)
    sys.path.insert(0, HERE)
    from machine import describe

    import numba
    from ase import units

    from ase_spin import CollectivePRK, neighbors, hamiltonian, scenes
    from ase_spin.md import base, collective

    phases = Phases()
    phases.wrap(scenes, "fcc_cobalt")
    phases.wrap(neighbors.NeighborCache, "update", "neighbour list: update (all)")
    phases.wrap(neighbors.NeighborCache, "_search", "neighbour list: search")
    phases.wrap(neighbors.NeighborCache, "sublist", "neighbour list: sublist")
    phases.wrap(hamiltonian.Evaluator, "lattice", "Evaluator.lattice")
    phases.wrap(hamiltonian.Evaluator, "spin_operators", "Evaluator.spin_operators")
    phases.wrap(hamiltonian.Evaluator, "spin", "Evaluator.spin")
    phases.wrap(base.SpinLatticeDynamics, "_initialize", "dynamics: initialize")
    phases.wrap(base.SpinLatticeDynamics, "_check_timestep", "dynamics: check timestep")
    phases.wrap(collective.CollectivePRK, "_solve", "CollectivePRK: midpoint solve")
    phases.wrap(collective.CollectivePRK, "_coupled_step", "CollectivePRK: coupled step")
    phases.wrap(base.SpinLatticeDynamics, "_step", "dynamics: step (all)")

    print(describe())
    start = _status("VmRSS")
    t0 = time.perf_counter()
    atoms = scenes.fcc_cobalt(args.n)
    dyn = CollectivePRK(atoms, 0.1 * units.fs)
    if 0 < args.rebuild_at <= args.steps:
        dyn.run(args.rebuild_at - 1)
        # the list's reference moved away: the next step's refresh rebuilds it
        dyn.ev.neighbors._reference += dyn.ev.neighbors.skin
        builds = dyn.ev.neighbors.builds
        dyn.run(args.steps - args.rebuild_at + 1)
        assert dyn.ev.neighbors.builds == builds + 1, "no rebuild"
    else:
        dyn.run(args.steps)
    wall = time.perf_counter() - t0
    n = len(atoms)
    import resource

    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(f"# fcc Co, N = {n}, {numba.get_num_threads()} threads, {args.steps} steps "
          f"(list rebuilt in step {args.rebuild_at or 'none'}), "
          f"{wall:.1f} s; RSS before the scene {start:.0f} MB, at the end "
          f"{_status('VmRSS'):.0f} MB, process peak {peak:.0f} MB = "
          f"{peak * 2**20 / n:.0f} bytes/atom")
    print(f"{'phase':34s} {'calls':>5s} {'peak rise MB':>12s} {'retained MB':>11s} "
          f"{'s':>7s}")
    for label, (calls, rise, kept, secs) in phases.rows.items():
        print(f"{label:34s} {calls:5d} {rise:12.0f} {kept:11.0f} {secs:7.2f}")
    held = arrays_held({"dyn": dyn, "ev": dyn.ev})
    print("# arrays kept by the integrator and evaluator (> 1 MB):")
    total = 0.0
    for path, mb in sorted(held, key=lambda x: -x[1]):
        total += mb
        print(f"  {path:60s} {mb:8.1f} MB  {mb * 2**20 / n:7.1f} B/atom")
    print(f"  {'total':60s} {total:8.1f} MB  {total * 2**20 / n:7.1f} B/atom")


if __name__ == "__main__":
    main()
