"""Describe the machine a benchmark ran on."""

import os
import platform


def describe():
    import numba
    import numpy

    import ase_spin

    cpu = platform.processor() or "unknown CPU"
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return (f"# machine: {cpu}, {cores} cores available, {platform.system()} "
            f"{platform.release()}, Python {platform.python_version()}\n"
            f"# numba {numba.__version__} ({numba.config.NUMBA_NUM_THREADS} threads, "
            f"layer {numba.threading_layer() if _threads_started() else 'not started'}), "
            f"numpy {numpy.__version__}, ase_spin {ase_spin.__version__}")


def _threads_started():
    import numba

    try:
        numba.threading_layer()
        return True
    except ValueError:
        return False


def best_time(f, natoms, reps=3):
    """The shortest of ``reps`` timed calls of ``f()`` (s), after one untimed
    call, with the threads the integrators run at ``natoms`` atoms."""
    import time

    from ase_spin._jit import threads

    with threads.threads_for(natoms):
        f()
        times = []
        for _ in range(reps):
            t = time.perf_counter()
            f()
            times.append(time.perf_counter() - t)
    return min(times)


def core_speeds(rounds=4, calls=300):
    """µs of one Lennard-Jones pass of fcc Co N = 500 on one thread (numba's
    active threads set to one: the pair kernel is threaded at every size),
    this process pinned to each core in turn, for ``rounds`` rounds: whether
    the cores run alike, and whether each keeps its speed (on a shared VM they
    need not)."""
    import time

    import numba
    import numpy as np

    from ase_spin.scenes import fcc_cobalt
    from ase_spin.terms.base import Want

    atoms = fcc_cobalt(5)
    ev, _ = atoms.calc.bound_evaluator(atoms)
    q = atoms.positions.copy()
    forces = np.zeros_like(q)
    cores = sorted(os.sched_getaffinity(0))
    rows = []
    active = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        ev.lattice(q, Want(forces=True), forces=forces)
        for _ in range(rounds):
            row = []
            for core in cores:
                os.sched_setaffinity(0, {core})
                t = time.perf_counter()
                for _ in range(calls):
                    ev.lattice(q, Want(forces=True), forces=forces)
                row.append(1e6 * (time.perf_counter() - t) / calls)
            rows.append(row)
    finally:
        os.sched_setaffinity(0, cores)
        numba.set_num_threads(active)
    return cores, rows


if __name__ == "__main__":
    import argparse

    parser = argparse.ArgumentParser(description="Describe this machine; with --cores, time "
                                     "one pair pass on one thread pinned to each core in turn.")
    parser.add_argument("--cores", action="store_true")
    parser.add_argument("--rounds", type=int, default=4)
    args = parser.parse_args()
    print(describe())
    if args.cores:
        cores, rows = core_speeds(args.rounds)
        print("# one Lennard-Jones pass on one thread, fcc Co N = 500 (µs), pinned to core: "
              + ", ".join(str(c) for c in cores))
        for k, row in enumerate(rows):
            print(f"round {k + 1}: " + "  ".join(f"{t:7.1f}" for t in row))
