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
