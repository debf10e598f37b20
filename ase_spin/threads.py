"""Threaded kernels, each with a serial twin for small systems.

Every numba parallel region costs a few microseconds to start, whatever its
size. A step of a small system (the paper's 30-atom chain, fcc Co with 500
atoms) runs dozens of them, so there the launches cost more than the work. Each
kernel is therefore compiled twice from one source: threaded (``prange`` over
threads) and serial (``prange`` read as ``range``). Code that evaluates a system
says how large it is with :func:`threads_for`; kernels called inside pick their
twin from that.
"""

from __future__ import annotations

import threading
import types
from contextlib import contextmanager

import numba as nb

__all__ = ["SERIAL_BELOW", "threads_for", "count", "threaded", "serial_twin"]

#: Systems with fewer atoms than this run the serial twins.
SERIAL_BELOW = 1500


class _Mode(threading.local):
    serial = False


_mode = _Mode()


@contextmanager
def threads_for(natoms):
    """Run the kernels called inside threaded, or serial for a small system."""
    previous = _mode.serial
    _mode.serial = natoms < SERIAL_BELOW
    try:
        yield
    finally:
        _mode.serial = previous


def count():
    """Threads the current kernels use (1 when serial)."""
    return 1 if _mode.serial else nb.get_num_threads()


def serial_twin(dispatcher, **replace):
    """``dispatcher``'s Python function compiled again without ``parallel``,
    under its own name (so numba's on-disk cache keeps the two apart), with
    global names in ``replace`` swapped (e.g. a threaded helper it calls for its
    serial twin)."""
    fn = dispatcher.py_func
    glob = dict(fn.__globals__)
    glob.update(replace)
    twin = types.FunctionType(fn.__code__, glob, fn.__name__ + "_serial", fn.__defaults__,
                              fn.__closure__)
    twin.__qualname__ = fn.__qualname__ + "_serial"
    twin.__module__ = fn.__module__
    twin.__doc__ = fn.__doc__
    # the numpy error model, as the threaded kernels have: 1/0 gives inf, not an exception
    return nb.njit(cache=True, error_model="numpy")(twin)


class _Threaded:
    """A kernel callable from Python that runs its threaded or serial twin."""

    def __init__(self, fn, replace, always):
        self.parallel = nb.njit(cache=True, parallel=True)(fn)
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
        return (self.serial if _mode.serial and not self.always else self.parallel)(*args)


def threaded(always=False, **replace):
    """Decorator for a kernel called from Python: ``@threaded()``, or
    ``@threaded(reduce_threads=lambda: reduce_threads_serial)`` when it calls
    another threaded function that its serial twin must not. ``always=True``
    for kernels with enough work per call to gain from threads even in a small
    system (pair potentials and exp() over every pair: measured at N = 500,
    Lennard-Jones 89 against 200 µs, exchange geometry 86 against 139 µs);
    such kernels take their thread count from :func:`all_threads`."""

    def wrap(fn):
        return _Threaded(fn, replace, always)

    return wrap


def all_threads():
    """numba's thread count, whatever the system size."""
    return nb.get_num_threads()
