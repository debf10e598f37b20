"""Announce numba's first-use compilation of this package's kernels.

Every hot loop here is compiled by numba with ``cache=True``: the first call of
each kernel in a fresh install compiles it (a scene's whole set takes 10–20 s
on an idle 2-core machine, more on a busy one, see docs/benchmarks.md) and
writes the machine code to numba's on-disk cache; later processes load it in
milliseconds. ``ase-spin compile`` (:mod:`ase_spin.warmup`) does it ahead of
time. Numba says nothing
while it compiles, so a first run looks hung. This module listens to numba's
``numba:compile`` event, which numba raises only when it compiles — a kernel
found in the disk cache raises none — and prints one line to stderr the first
time one of this package's cached kernels is compiled in a process.

Where the cache lives (numba's rule): ``NUMBA_CACHE_DIR`` if set; else the
``__pycache__`` folder beside each module if it is writable (a source tree,
a virtual environment or a user install); else numba's per-user cache folder
(``~/.cache/numba`` on Linux, for a system-wide install a user cannot write).
Set ``ASE_SPIN_QUIET_COMPILE=1`` to silence the line.
"""

from __future__ import annotations

import os
import sys

from numba.core import event

__all__ = ["cache_dir", "install"]

_MESSAGE = ("ase_spin: compiling numba kernels on first use (once per install and CPU; "
            "10-20 s on 2 idle cores); they are cached in {where} and load in about a "
            "second next time (ahead of time: ase-spin compile)")


def _cached_ase_spin_kernel(dispatcher):
    """The numba cache of a dispatcher of this package compiled with cache=True,
    or None."""
    func = getattr(dispatcher, "py_func", None)
    module = getattr(func, "__module__", "") or ""
    if not (module == "ase_spin" or module.startswith("ase_spin.")):
        return None
    cache = getattr(dispatcher, "_cache", None)
    if cache is None or not hasattr(cache, "_cache_path"):  # NullCache: cache=False
        return None
    return cache


class _CompileNotice(event.Listener):
    def __init__(self, stream=None):
        self.stream = stream
        self.announced = False

    def on_start(self, ev):
        if self.announced or os.environ.get("ASE_SPIN_QUIET_COMPILE"):
            return
        data = ev.data if isinstance(ev.data, dict) else {}
        cache = _cached_ase_spin_kernel(data.get("dispatcher"))
        if cache is None:
            return
        self.announced = True
        where = cache._cache_path
        if os.path.basename(where.rstrip(os.sep)) == "__pycache__":  # in the source tree
            package = os.path.dirname(os.path.abspath(__file__))
            where = f"the __pycache__ folders under {package}"
        message = _MESSAGE.format(where=where)
        stream = self.stream or sys.stderr
        tqdm = sys.modules.get("tqdm")
        if tqdm is not None and hasattr(tqdm, "tqdm"):
            tqdm.tqdm.write(message, file=stream)  # above a progress bar, not through it
        else:
            print(message, file=stream, flush=True)

    def on_end(self, ev):
        pass


_notice = None


def install(stream=None):
    """Register the notice (done once when ase_spin is imported). Returns the
    listener; ``listener.announced`` tells whether it has spoken."""
    global _notice
    if _notice is None:
        _notice = _CompileNotice(stream)
        event.register("numba:compile", _notice)
    elif stream is not None:
        _notice.stream = stream
    return _notice


def cache_dir(dispatcher):
    """The folder where numba keeps (or would keep) a cached kernel's machine
    code, e.g. ``cache_dir(ase_spin.md.kernels.kick)``."""
    cache = getattr(dispatcher, "_cache", None)
    if cache is None or not hasattr(cache, "_cache_path"):
        raise ValueError(f"{dispatcher!r} is not compiled with cache=True")
    return cache._cache_path


install()
