"""Where the memory of the mesh dipolar sum (``Dipolar(method="pme")``) goes,
per atom and per mesh point, on fcc Co (4n³ atoms, rc = 6 Å, accuracy 1e-5).

    PYTHONPATH=TREE python benchmarks/dipolar_memory.py [--sizes 14 22 30]

Each size runs in its own process. Each phase resets the kernel's peak-RSS
mark (``/proc/self/clear_refs``, Linux) and reads the peak reached inside
(``VmHWM``) and the RSS kept after it: binding the term (the influence
function), preparing the operator at positions (pair geometry, spline
weights), one field from it (twice), one energy + forces + magnetic forces
evaluation from scratch. Run it with ``PYTHONPATH`` on two source trees to
compare them.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time


def _status(key):
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(key):
                return int(line.split()[1]) / 1024.0  # MB
    raise KeyError(key)


def _phase(name, f, out):
    with open("/proc/self/clear_refs", "w") as fh:
        fh.write("5")
    before = _status("VmRSS")
    t = time.perf_counter()
    value = f()
    out[name] = (_status("VmHWM") - before, _status("VmRSS") - before, time.perf_counter() - t)
    return value


def child(n):
    import numpy as np

    from ase_spin import Dipolar, Hamiltonian, Want, get_spins
    from ase_spin._jit import threads
    from ase_spin.scenes import fcc_cobalt

    atoms = fcc_cobalt(n)
    s = get_spins(atoms)
    N = len(atoms)
    q = atoms.positions
    term = Dipolar(6.0, "pme", accuracy=1e-5)
    out = {}
    with threads.threads_for(N):
        ev = _phase("bind", lambda: Hamiltonian([term]).bind(atoms.numbers, atoms.cell.array,
                                                               atoms.pbc, np.full(N, 1.72)), out)
        ops = _phase("prepare", lambda: ev.spin_operators(q, half=True), out)
        B = np.zeros_like(s)
        _phase("field", lambda: ops[0].field(s, B), out)
        _phase("field again", lambda: ops[0].field(s, B), out)
        _phase("E+F", lambda: ev.evaluate(q, s, Want(energy=True, forces=True,
                                                      magnetic_forces=True)), out)
    mesh = term.mesh_size(atoms.cell.array)
    M = int(np.prod(mesh))
    print(f"N = {N}, mesh {mesh}: {M / N:.0f} points per atom, peak RSS "
          f"{_status('VmHWM'):.0f} MB")
    for name, (peak, kept, dt) in out.items():
        print(f"  {name:12s} peak +{peak:8.1f} MB ({peak * 2**20 / N:6.0f} B/atom, "
              f"{peak * 2**20 / M:5.2f} B/point), kept +{kept:8.1f} MB, {dt:.2f} s", flush=True)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[14, 22, 30])
    parser.add_argument("--child", type=int)
    args = parser.parse_args()
    if args.child:
        child(args.child)
        return
    for n in args.sizes:
        subprocess.run([sys.executable, __file__, "--child", str(n)], check=False)


if __name__ == "__main__":
    main()
