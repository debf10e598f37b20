"""The one way this package makes a kernel from another: a copy of a Python
function's code under a name of its own, with some of its global names bound to
other objects, then compiled by numba.

numba caches a compiled function on disk by its module and qualified name, and
compiles a function's globals as constants. A copy with a new name and new
globals is therefore how a kernel gets a serial twin (its threaded helpers
swapped for serial ones), a specialisation (a request's flags as constants: the
work not asked for drops out) or a skeleton with a term's compiled pieces bound
in (numba cannot cache a kernel that takes functions as arguments or is built
in a closure).
"""

from __future__ import annotations

import hashlib
import types

import numba as nb

from .cache import source_digest

__all__ = ["clone", "serial_twin", "kernel_twin", "compile_with", "prange_only"]


def clone(fn, name, replace, qualname=None):
    """A copy of the Python function ``fn`` named ``name`` (qualified name
    ``qualname``, default ``fn``'s with the same suffix), its globals updated
    with ``replace``; the same code, defaults and closure."""
    glob = dict(fn.__globals__)
    glob.update(replace)
    twin = types.FunctionType(fn.__code__, glob, name, fn.__defaults__, fn.__closure__)
    twin.__qualname__ = qualname or fn.__qualname__ + name[len(fn.__name__):]
    twin.__module__ = fn.__module__
    twin.__doc__ = fn.__doc__
    return twin


def prange_only():
    """numba's ``parallel=`` option for this package's threaded kernels: only
    the explicit ``prange`` loops run on threads.

    With ``parallel=True`` numba also turns every array expression and
    allocation (``np.zeros`` of the per-thread buffers, ``.max()``, ...) into
    a parallel loop of its own, each compiled as a separate threaded function;
    the kernels here split their work into fixed chunks by hand and gain
    nothing from those, while each of them adds compile time to the largest
    kernels (Lennard-Jones and exchange; ``benchmarks/first_use.py``,
    docs/benchmarks.md, "First use: compilation"). A new dict per call: numba
    consumes it."""
    return dict(prange=True, comprehension=False, reduction=False, inplace_binop=False,
                setitem=False, numpy=False, stencil=False, fusion=False)


def serial_twin(dispatcher, **replace):
    """``dispatcher``'s Python function compiled again without ``parallel``,
    under its own name (so numba's on-disk cache keeps the two apart), with
    global names in ``replace`` swapped (e.g. a threaded helper it calls for its
    serial twin)."""
    fn = dispatcher.py_func
    twin = clone(fn, fn.__name__ + "_serial", replace)
    # the numpy error model, as the threaded kernels have: 1/0 gives inf, not an exception
    return nb.njit(cache=True, error_model="numpy")(twin)


def kernel_twin(fn, suffix, **constants):
    """``fn`` (a kernel's Python function) with the module constants
    ``constants`` replaced (e.g. a request's flags, which numba then compiles
    as constants: the work not asked for drops out), under a name of its own
    (numba's disk cache keeps the twins apart)."""
    return clone(fn, fn.__name__ + suffix, constants)


def compile_with(skeleton, functions, name, parallel=False, error_model="python"):
    """``skeleton`` compiled with the compiled ``functions`` (a mapping from
    the global names it calls to dispatchers) bound in, cached on disk.

    numba cannot cache a kernel that takes functions as arguments or is built
    in a closure; a copy of the skeleton's code with the functions as globals
    and a name of its own can be. The name carries a hash of the functions'
    names and code and of the package's source files (numba keys a cached
    kernel by its own file only, while the functions bound here are compiled
    into the skeleton with the helpers they call, from other files), so a
    cached skeleton does not outlive an edit of anything it runs, and two
    combinations never share a cache entry. ``parallel``: threaded (its
    ``prange`` loops, :func:`prange_only`; numpy's error model, as every
    threaded kernel has), else serial with numba's ``error_model`` (numpy's
    for the chunk of a threaded kernel: the same arithmetic as its loop)."""
    code = hashlib.sha1(source_digest())
    for key, f in sorted(functions.items()):
        py = f.py_func
        code.update(f"{key}={py.__module__}.{py.__qualname__}".encode())
        code.update(py.__code__.co_code)
        code.update(repr((py.__code__.co_consts, py.__code__.co_names)).encode())
    fn = clone(skeleton, f"{skeleton.__name__}_{name}", functions,
               qualname=f"{skeleton.__name__}_{name}_{code.hexdigest()[:12]}")
    if parallel:
        return nb.njit(cache=True, parallel=prange_only(), error_model="numpy")(fn)
    return nb.njit(cache=True, error_model=error_model)(fn)
