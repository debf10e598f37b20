"""Thread counts: results independent of them, the adaptive choice, the knob."""

import numba as nb
import numpy as np
import pytest
from ase import units

from ase_spin import CollectivePRK, SpinLatticeCalculator, SuzukiTrotter, get_spins
from ase_spin.scenes import fcc_cobalt, fcc_cobalt_terms, field_anisotropy_terms
from ase_spin.terms import DMI
from ase_spin._jit import threads
from ase_spin._jit.threads import AdaptiveThreads, chunks

needs_threads = pytest.mark.skipif(chunks() < 2, reason="numba has one thread here")


@pytest.mark.alone
@needs_threads
@pytest.mark.parametrize("cls", [CollectivePRK, SuzukiTrotter])
def test_trajectory_is_bitwise_the_same_with_one_thread_or_all(cls):
    """Work is cut into fixed chunks whatever number of threads runs them: the
    adaptive choice cannot change a bit. N = 4000 (threaded kernels), every
    kind of term (fused exchange, single-site, pair skeleton)."""
    runs = []
    for n in (1, chunks()):
        atoms = fcc_cobalt(10)
        atoms.calc = SpinLatticeCalculator([*fcc_cobalt_terms(), *field_anisotropy_terms(),
                                            DMI(2e-3, [0, 0, 1], rc=2.7)])
        dyn = cls(atoms, 0.2 * units.fs, threads=n)
        dyn.run(3)
        runs.append((atoms.positions.copy(), atoms.get_momenta(), get_spins(atoms),
                     dyn.get_total_energy()))
    for a, b in zip(*runs):
        assert np.array_equal(a, b)


def test_adaptive_choice_follows_the_faster_setting(monkeypatch):
    """With made-up step times on an idle machine: after the untimed warm-up
    (all threads), both settings are timed, the faster is kept, the other
    re-probed; a single slow step of the current choice (the operating
    system's: threads.OUTLIER) changes nothing, a slowdown that stays
    switches at its second step."""
    monkeypatch.setattr(threads, "cores_taken_by_others", lambda: 0.0)
    control = AdaptiveThreads("auto", probe=1e9)
    control.most = 2
    times = {2: 5.0, 1: 1.0}
    warm = threads.WARMUP
    chosen, probes = [], []
    for k in range(warm + 6):
        n = control._choose()
        chosen.append(n)
        probes.append(control._probing)
        control._record(n, times[n])
        if k == warm - 1:
            assert not control.time  # warm-up: not timed
    assert chosen[:warm] == [2] * warm
    assert chosen[warm:warm + 2] == [2, 1]            # each timed once
    assert chosen[warm + 2] == 2 and probes[warm + 2]  # the first probe, then none for 1e9 s
    assert chosen[warm + 3:] == [1, 1, 1] and not any(probes[warm + 3:])
    control._record(control._choose(), 10.0)  # one slow step alone: not timed
    assert control._choose() == 1 and control.time[1] == 1.0
    control._record(control._choose(), 1.0)
    times[1] = 10.0                           # a core got busy: slow steps from now on
    control._record(control._choose(), times[1])
    assert control._choose() == 1             # the first could be the OS's
    control._record(control._choose(), times[1])
    assert control._choose() == 2             # the second switches


def test_busy_machine_starts_with_one_thread(monkeypatch):
    """Other processes holding the cores at the start: one thread is timed
    first, all threads only once the first probe is due (never within a
    run shorter than the probe interval)."""
    monkeypatch.setattr(threads, "cores_taken_by_others", lambda: 2.0)
    clock = [0.0]
    monkeypatch.setattr(threads.time, "perf_counter", lambda: clock[0])
    control = AdaptiveThreads("auto", probe=1.0)
    control.most = 2
    chosen = []
    steps = threads.WARMUP + 4
    for _ in range(steps):  # 0.05 s per step: within the first probe interval
        n = control._choose()
        chosen.append(n)
        control._record(n, 0.05)
        clock[0] += 0.05
    assert chosen == [1] * steps
    clock[0] = 1.5
    assert control._choose() == 2  # the probe is due


def test_probe_waits_while_other_processes_hold_the_cores(monkeypatch):
    """A probe of all threads that falls due while other processes keep the
    cores busy (machine busy time from made-up /proc/stat snapshots) is put
    off without running; once the machine is quiet, the next due probe runs."""
    monkeypatch.setattr(threads, "cores_taken_by_others", lambda: 2.0)
    clock, machine = [0.0], [0.0]
    monkeypatch.setattr(threads.time, "perf_counter", lambda: clock[0])
    monkeypatch.setattr(threads, "cpu_snapshot", lambda: (machine[0], 0.0, clock[0]))
    control = AdaptiveThreads("auto", probe=1.0)
    control.most = 2
    busy = []
    for _ in range(50):  # 5 s with two cores held by others: never two threads
        busy.append(control._choose())
        control._record(busy[-1], 0.1)
        clock[0] += 0.1
        machine[0] += 0.2
    assert busy == [1] * 50
    quiet = []
    for _ in range(30):  # 3 s of an idle machine: the probe runs
        quiet.append(control._choose())
        control._record(quiet[-1], 0.1 if quiet[-1] == 1 else 0.05)
        clock[0] += 0.1
    assert 2 in quiet and quiet[-1] == 2  # and two threads, now faster, are kept


def test_cores_taken_by_others_is_a_number_of_cores():
    threads._taken = (-1e9, 0.0)  # no cached value
    taken = threads.cores_taken_by_others()
    assert 0.0 <= taken <= (threads.os.cpu_count() or 1) + 1.0


def test_threads_setting_is_checked(monkeypatch):
    assert AdaptiveThreads(1).setting == 1
    assert AdaptiveThreads("auto").setting == "auto"
    monkeypatch.setenv("ASE_SPIN_THREADS", "1")
    assert AdaptiveThreads().setting == 1
    for bad, exc in ((0, ValueError), (chunks() + 1, ValueError), ("many", ValueError),
                     (1.5, TypeError), (True, TypeError)):
        with pytest.raises(exc, match="threads"):
            AdaptiveThreads(bad)


def test_fixed_thread_count_is_used_and_restored():
    atoms = fcc_cobalt(2)
    before = nb.get_num_threads()
    dyn = CollectivePRK(atoms, 0.2 * units.fs, threads=1)
    dyn.run(2)
    assert dyn.threads.choice == 1 and nb.get_num_threads() == before
