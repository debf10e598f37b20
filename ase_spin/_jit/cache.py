"""Announce numba's first-use compilation of this package's kernels.

Every hot loop here is compiled by numba with ``cache=True``: the first call of
each kernel in a fresh install compiles it (how long a scene's whole set
takes: docs/benchmarks.md, "First use: compilation"; ``benchmarks/first_use.py``)
and writes the machine code to numba's on-disk cache; later processes load it
from there instead of compiling. ``ase-spin compile`` (:mod:`ase_spin.app.warmup`)
does it ahead of time. Numba says nothing
while it compiles, so a first run looks hung. This module listens to numba's
``numba:compile`` event, which numba raises only when it compiles — a kernel
found in the disk cache raises none — and prints one line to stderr the first
time one of this package's cached kernels is compiled in a process.

Where the cache lives (numba's rule): ``NUMBA_CACHE_DIR`` if set; else the
``__pycache__`` folder beside each module if it is writable (a source tree,
a virtual environment or a user install); else numba's per-user cache folder
(``~/.cache/numba`` on Linux, for a system-wide install a user cannot write).
Set ``ASE_SPIN_QUIET_COMPILE=1`` to silence the line.

numba keys a cached kernel by its own source file only (a hash of that file):
a kernel that inlines a helper from another module keeps the helper's old
machine code after an edit of that module alone (a ``git pull`` into an
editable install, a developer's change). So that no kernel outlives the source
it was compiled from, importing ase_spin compares a hash of the whole package's
source (:func:`source_digest`) with the one stamped in each of its numba cache
folders and, where they differ, removes this package's cached kernels there
(they are compiled afresh, once) before any is loaded.
"""

from __future__ import annotations

import os
import sys

from numba.core import event

__all__ = ["cache_dir", "clear_stale_caches", "install", "source_digest"]

#: The package's folder (this module is in its _jit/).
PACKAGE_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
#: The file in each numba cache folder holding the source digest its kernels
#: of this package were compiled from.
STAMP = "ase_spin-source.sha1"

_MESSAGE = ("ase_spin: compiling numba kernels on first use (once per install and CPU, "
            "each kernel the first time it is called); they are cached in {where} and "
            "loaded from there next time (to compile ahead of time: ase-spin compile)")


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
            package = PACKAGE_ROOT
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


_digest = None


def source_digest():
    """SHA-1 of every source file of this package (once per process): what a
    compiled kernel may run, through the helpers it inlines from any module."""
    global _digest
    if _digest is None:
        import hashlib
        from pathlib import Path

        digest = hashlib.sha1()
        root = Path(PACKAGE_ROOT)
        for path in sorted(root.rglob("*.py")):
            try:
                digest.update(str(path.relative_to(root)).encode())
                digest.update(path.read_bytes())
            except OSError:  # unreadable: the code hashes alone for it
                pass
        _digest = digest.digest()
    return _digest


def _probe():
    """A function for numba's cache locators to place (they read its first line)."""


def cache_folders():
    """{numba's cache folder: the package folder it caches} for every folder of
    this package's modules, chosen as numba chooses it for a kernel there
    (``NUMBA_CACHE_DIR``, the ``__pycache__`` beside the module if writable, or
    the user's numba cache)."""
    from pathlib import Path

    from numba.core import caching

    impl = getattr(caching, "CacheImpl", None) or getattr(caching, "_CacheImpl")
    folders = {}
    root = Path(PACKAGE_ROOT)
    for folder in sorted({path.parent for path in root.rglob("*.py")}):
        module = str(min(folder.glob("*.py")))
        for locator in impl._locator_classes:
            found = locator.from_function(_probe, module)
            if found is not None:
                folders[found.get_cache_path()] = folder
                break
    return folders


def clear_stale_caches(folders=None, digest=None):
    """Remove this package's cached kernels from every numba cache folder whose
    stamp (:data:`STAMP`) is not the current source digest, then stamp it.
    ``folders``: {cache folder: package folder} (default :func:`cache_folders`).
    Returns the files removed. Best effort: a folder that cannot be read or
    written is left as numba would leave it."""
    digest = (digest or source_digest()).hex()
    removed = []
    for cache, folder in (cache_folders() if folders is None else folders).items():
        stamp = os.path.join(cache, STAMP)
        try:
            with open(stamp) as f:
                if f.read().strip() == digest:
                    continue
        except OSError:
            pass
        modules = {os.path.splitext(name)[0] for name in os.listdir(folder)
                   if name.endswith(".py")}
        try:
            for name in os.listdir(cache):
                # numba's names: <module>.<qualname>-<line>.py<version>.nbi / .nbc
                if name.endswith((".nbi", ".nbc")) and name.split(".", 1)[0] in modules:
                    try:
                        os.remove(os.path.join(cache, name))
                        removed.append(os.path.join(cache, name))
                    except FileNotFoundError:  # another process removed it first
                        pass
            partial = f"{stamp}.{os.getpid()}"
            with open(partial, "w") as f:
                f.write(digest + "\n")
            os.replace(partial, stamp)
        except OSError:
            continue
    return removed


install()
try:
    clear_stale_caches()
except Exception:  # noqa: BLE001 - numba's cache internals moved: its own rules apply
    pass
