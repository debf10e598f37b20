"""Threaded kernels, each with a serial twin for small systems.

Every numba parallel region has a fixed cost to start (waking the worker
threads and meeting at its barrier), whatever its size. A step of a small
system (the paper's 30-atom chain, fcc Co with 500 atoms) runs dozens of them,
so there the launches cost more than the work. Each kernel is therefore
compiled twice from one source: threaded (``prange`` over threads) and serial
(``prange`` read as ``range``). Code that evaluates a system says how large it
is with :func:`threads_for`; kernels called inside pick their twin from that.

The work of one chunk of the heavier kernels' ``prange`` loops is a function
of its own (``_<kernel>_chunk``, taking the chunk's index as an int64): numba
compiles it once, and the threaded kernel and its serial twin are thin loops
calling it, rather than each compiling the whole body again (numba turns a
``prange`` loop into a function of its own as well). The same arithmetic in
the same order: the same bits.
The serial twins exist only for speed: ``benchmarks/small_systems.py`` shows
what they save (docs/benchmarks.md, "Why each fast path exists").
"""

from __future__ import annotations

import os
import threading
import time

import numba as nb

from .cloning import prange_only, serial_twin

__all__ = ["SERIAL_BELOW", "SERIAL_ALL_BELOW", "threads_for", "count", "small", "tiny",
           "threaded", "AdaptiveThreads"]

#: Systems with fewer atoms than this run the serial twins: below it the
#: parallel regions' start-up costs more than the threads save on the light
#: kernels (``benchmarks/small_systems.py``; docs/benchmarks.md, "Why each fast
#: path exists").
SERIAL_BELOW = 1500
#: Systems with fewer atoms than this (and than :data:`SERIAL_BELOW`) run even
#: the ``always`` kernels serially: with so few pairs, starting the parallel
#: region costs more than even a pair pass's work (``benchmarks/small_systems.py``;
#: docs/benchmarks.md, "Why each fast path exists").
SERIAL_ALL_BELOW = 64


class _Mode(threading.local):
    serial = False
    tiny = False


_mode = _Mode()


class threads_for:
    """``with threads_for(natoms):`` runs the kernels called inside threaded, or
    serial for a small system. (A class, not a generator: it is entered several
    times per step of a small system, where a generator's cost shows.)"""

    __slots__ = ("natoms", "_previous")

    def __init__(self, natoms):
        self.natoms = natoms

    def __enter__(self):
        mode = _mode
        self._previous = (mode.serial, mode.tiny)
        mode.serial = self.natoms < SERIAL_BELOW
        mode.tiny = self.natoms < SERIAL_ALL_BELOW
        return self

    def __exit__(self, *exc):
        _mode.serial, _mode.tiny = self._previous
        return False


def chunks():
    """Chunks the threaded kernels split their work into: numba's configured
    thread count, fixed for the process (not the active count, which
    :class:`AdaptiveThreads` may lower)."""
    return nb.config.NUMBA_NUM_THREADS


def tiny():
    """Inside :func:`threads_for` of a system small enough for every kernel
    to run serially (fewer than :data:`SERIAL_ALL_BELOW` atoms)."""
    return _mode.serial and _mode.tiny


def small():
    """Inside :func:`threads_for` of a system small enough for the light
    kernels to run serially (fewer than :data:`SERIAL_BELOW` atoms)."""
    return _mode.serial


def count():
    """Chunks of work for the current kernels (1 when serial)."""
    return 1 if _mode.serial else chunks()


class _Threaded:
    """A kernel callable from Python that runs its threaded or serial twin."""

    def __init__(self, fn, replace, always):
        self.parallel = nb.njit(cache=True, parallel=prange_only())(fn)
        self.always = always
        self._replace = replace
        self._serial = None
        self.__doc__ = fn.__doc__
        self.__name__ = fn.__name__
        self.__wrapped__ = fn

    @property
    def serial(self):
        if self._serial is None:  # built on first use: module globals are complete then
            replace = {name: resolve() for name, resolve in self._replace.items()}
            self._serial = serial_twin(self.parallel, **replace)
        return self._serial

    def __call__(self, *args):
        mode = _mode
        if mode.serial and (mode.tiny or not self.always):
            return (self._serial or self.serial)(*args)
        return self.parallel(*args)


def threaded(always=False, **replace):
    """Decorator for a kernel called from Python: ``@threaded()``, or
    ``@threaded(reduce_threads=lambda: reduce_threads_serial)`` when it calls
    another threaded function that its serial twin must not. ``always=True``
    for kernels with enough work per call to gain from threads even in a small
    system (pair potentials and exp() over every pair, whose work outweighs
    the parallel region's start-up from :data:`SERIAL_ALL_BELOW` atoms on;
    ``benchmarks/small_systems.py``); such kernels take their thread count
    from :func:`all_threads`."""

    def wrap(fn):
        return _Threaded(fn, replace, always)

    return wrap


def all_threads():
    """Chunks of work for kernels threaded whatever the system size."""
    return chunks()


def _threads_setting(value):
    """``threads=``: "auto", or a count from 1 to numba's configured maximum."""
    if value is None:
        value = os.environ.get("ASE_SPIN_THREADS", "auto")
    if isinstance(value, str):
        if value.strip().lower() == "auto":
            return None
        try:
            value = int(value)
        except ValueError:
            raise ValueError(f'threads must be "auto" or a whole number, got {value!r}') from None
    if isinstance(value, bool) or not hasattr(value, "__index__"):
        raise TypeError(f'threads must be "auto" or a whole number, got {value!r}')
    value = int(value.__index__())
    if not 1 <= value <= chunks():
        raise ValueError(f"threads must lie between 1 and {chunks()} (NUMBA_NUM_THREADS), "
                         f"got {value}")
    return value


def _cores():
    try:
        return os.sched_getaffinity(0)
    except AttributeError:  # not Linux
        return range(os.cpu_count() or 1)


def _cpu_busy():
    """Busy CPU time of the whole machine so far, from /proc/stat (clock ticks)."""
    with open("/proc/stat") as f:
        fields = [int(x) for x in f.readline().split()[1:]]
    idle = fields[3] + (fields[4] if len(fields) > 4 else 0)  # idle + iowait
    return sum(fields) - idle


def cpu_snapshot():
    """(machine busy CPU seconds, this process's CPU seconds, wall seconds),
    or None where /proc/stat is not available."""
    try:
        return (_cpu_busy() / os.sysconf("SC_CLK_TCK"), time.process_time(),
                time.perf_counter())
    except (OSError, ValueError, IndexError):
        return None


def taken_between(a, b):
    """Cores kept busy by other processes between two :func:`cpu_snapshot`:
    the machine's busy time less this process's own, per wall second."""
    return max(0.0, ((b[0] - a[0]) - (b[1] - a[1])) / (b[2] - a[2]))


_taken = (-1e9, 0.0)  # (when measured, cores taken by other processes)


def cores_taken_by_others(window=0.05, valid=10.0):
    """How many cores other processes keep busy now (:func:`taken_between`
    over ``window`` seconds), measured at most once per ``valid`` seconds
    (cached). Without /proc/stat: the 1-minute load average less one (this
    process), or 0."""
    global _taken
    now = time.perf_counter()
    if now - _taken[0] < valid:
        return _taken[1]
    start = cpu_snapshot()
    if start is not None:
        time.sleep(window)
        taken = taken_between(start, cpu_snapshot())
    else:
        try:
            taken = max(0.0, os.getloadavg()[0] - 1.0)
        except (AttributeError, OSError):
            taken = 0.0
    _taken = (time.perf_counter(), taken)
    return taken


#: Steps at the start of a run that are not timed: they compile kernels and fill
#: the midpoint predictor's history (its order rises over the first ~12 steps, and
#: with it the sweeps per step fall several-fold), so their times do not compare.
WARMUP = 12

#: A losing probe step is followed by at least this many times its own
#: duration before the next probe: probing costs at most ~1/PROBE_BUDGET.
PROBE_BUDGET = 20.0

#: A step more than this many times slower than the median of the last steps
#: with its thread count is not timed unless the next one is slow as well: one
#: such step is the operating system's (a worker thread descheduled for a time
#: slice holds every barrier of the step), not the thread count's; without this
#: rule such steps sent runs to one thread needlessly (``benchmarks/busy_machine.py``;
#: docs/benchmarks.md, "Why each fast path exists").
OUTLIER = 1.5


class AdaptiveThreads:
    """The number of threads for the steps of a run, chosen by timing them.

    ``threads="auto"`` (the default; or the environment variable
    ``ASE_SPIN_THREADS``): every step runs with all configured threads or with
    one, whichever was faster in its last measured steps (the median of the
    last three in a row with that count, or the one step of a probe; the first
    :data:`WARMUP` steps are not timed, nor a single step :data:`OUTLIER`
    times slower than the last ones with its count: on a shared machine a
    descheduled worker thread makes an occasional threaded step several times
    slower, which would send the run to one thread until the next probe). The
    current choice is timed at every step, so a core taken by another process
    shows after two steps; the
    other choice is timed again once per ``probe`` seconds of wall time (the
    interval doubles, up to 64 s, while it keeps losing, and is at least
    :data:`PROBE_BUDGET` times the losing step's own time). A machine busy
    at the first step starts with one thread; a probe of all threads is put
    off while other processes hold the cores (:func:`cpu_snapshot`). A busy
    machine thus costs at most about what it costs a single-threaded code,
    and an idle one keeps the threads. A whole number fixes the count. Results are the same
    bit for bit whatever is chosen (see the module's docstring).

    It exists only for speed: on a shared machine fixed threads wait at every
    barrier for a descheduled worker, and one thread wastes an idle core;
    ``benchmarks/busy_machine.py`` runs both fixed counts and this choice side
    by side (docs/benchmarks.md, "Throughput and scaling").
    """

    def __init__(self, threads=None, probe=1.0):
        self.fixed = _threads_setting(threads)
        self.most = chunks()
        self.time = {}  # threads -> its step time as judged (s): see _record
        self.seen = {}  # threads -> steps run
        self.steps = 0
        self.choice = self.fixed or self.most
        self._probe = probe
        self._interval = probe
        self._next_probe = 0.0
        self._probing = False
        self._order = None  # which count is timed first: decided at the first step
        self._sample = None  # cpu_snapshot() at the last look at the machine
        self._recent = {}  # threads -> the last step times (s), outliers included
        self._slow = {}  # threads -> whether its last step was an outlier
        self._stretch = []  # the last (up to 3) step times since the count last changed
        self._stretch_n = None

    @property
    def setting(self):
        return "auto" if self.fixed is None else self.fixed

    def _best(self):
        if len(self.time) < 2:
            return None
        return min(self.time, key=self.time.get)

    def _choose(self):
        self._probing = False
        if self.fixed is not None or self.most == 1:
            return self.fixed or 1
        if self._order is None:
            # a machine busy at the start: one thread first, all threads only
            # when the first probe is due (a short run never pays for them)
            self._order = (self.most, 1)
            if cores_taken_by_others() > self._free_threshold():
                self._order = (1, self.most)
                self._next_probe = time.perf_counter() + self._interval
            self._sample = cpu_snapshot()
        first, second = self._order
        if first not in self.time:
            return first
        if second not in self.time:
            if first == 1 and not self._probe_due():
                return first
            return second
        best = self._best()
        if best == 1:
            if self._probe_due():
                self._probing = True
                return self.most
            return 1
        if time.perf_counter() >= self._next_probe:
            self._probing = True
            return 1
        return best

    def _free_threshold(self):
        """Other processes' load (cores) above which ``most`` threads cannot
        all have a core: all cores but ``most`` − ½."""
        return len(_cores()) - self.most + 0.5

    def _probe_due(self):
        """Whether to time all threads again: the probe interval has passed
        and, since the last look, other processes have left the cores free
        (else the probe is put off by another interval without running: a
        threaded step whose workers cannot all have a core waits at every
        barrier for a descheduled one, and costs many one-thread steps;
        docs/benchmarks.md, "Throughput and scaling")."""
        now = time.perf_counter()
        if now < self._next_probe:
            return False
        snapshot = cpu_snapshot()
        last, self._sample = self._sample, snapshot
        if (last is not None and snapshot is not None and snapshot[2] - last[2] > 0.2
                and taken_between(last, snapshot) > self._free_threshold()):
            self._next_probe = now + self._interval
            return False
        return True

    def _record(self, n, elapsed, steps=1):
        """Judge a step time ``elapsed`` (s; of each of ``steps`` steps taken together)."""
        self.seen[n] = self.seen.get(n, 0) + steps
        self.steps += steps
        if self.steps <= WARMUP:  # compilation, the predictor's history filling
            return
        recent = self._recent.setdefault(n, [])
        typical = sorted(recent)[len(recent) // 2] if len(recent) >= 3 else None
        recent.append(elapsed)
        del recent[:-5]
        if n != self._stretch_n:
            self._stretch_n, self._stretch = n, []
        self._stretch.append(elapsed)
        del self._stretch[:-3]
        if typical is not None and elapsed > OUTLIER * typical and not self._slow.get(n):
            self._slow[n] = True  # one slow step: not timed (see OUTLIER)
            return
        self._slow[n] = False
        before = self._best()
        # the median of the last three steps of this stretch (a probe: its one step),
        # so that one noisy step of the current choice does not lose to a probe
        self.time[n] = sorted(self._stretch)[len(self._stretch) // 2]
        best = self._best()
        if best is None or n == best:
            if self._probing and before is not None:  # a probe that won: probe often again
                self._interval = self._probe
            return
        if self._probing:  # a probe that lost again: probe less often
            self._interval = min(64.0, 2.0 * self._interval)
        # a losing step may cost many good ones (a descheduled thread holds a
        # barrier for a time slice): keep such probes under 1/PROBE_BUDGET of
        # the wall time
        self._next_probe = max(self._next_probe, time.perf_counter() + self._interval,
                               time.perf_counter() + PROBE_BUDGET * elapsed * steps)

    def step(self, natoms):
        """``with adaptive.step(natoms):`` runs one step inside: sets the thread
        count (and the serial twins for a small system), times the step,
        restores numba's setting. Below :data:`SERIAL_ALL_BELOW` atoms every
        kernel runs serially whatever the count: only the serial twins are
        chosen (setting numba's thread count would cost more than the step's
        kernels)."""
        if natoms < SERIAL_ALL_BELOW and natoms < SERIAL_BELOW:
            return threads_for(natoms)
        return _Step(self, natoms)


class _Step:
    """The context of :meth:`AdaptiveThreads.step` (a class: a generator's
    overhead shows in the steps of a small system)."""

    __slots__ = ("adaptive", "n", "previous", "sized", "t0", "steps", "probing")

    def __init__(self, adaptive, natoms):
        self.adaptive = adaptive
        self.sized = threads_for(natoms)
        # steps taken inside (several: a block of small-system steps, timed per step)
        self.steps = 1

    def __enter__(self):
        self.n = n = self.adaptive._choose()
        # a probe of another thread count: a short block at most (SpinLatticeDynamics._irun)
        self.probing = self.adaptive._probing
        self.previous = previous = nb.get_num_threads()
        if n != previous:
            nb.set_num_threads(n)
        self.t0 = time.perf_counter()
        self.sized.__enter__()
        return self

    def __exit__(self, exc_type, exc, tb):
        self.sized.__exit__(exc_type, exc, tb)
        if self.n != self.previous:
            nb.set_num_threads(self.previous)
        if exc_type is None:
            adaptive = self.adaptive
            adaptive.choice = self.n
            if self.steps > 0:
                adaptive._record(self.n, (time.perf_counter() - self.t0) / self.steps,
                                 self.steps)
        return False
