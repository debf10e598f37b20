"""Compile the kernels ahead of time: ``ase-spin compile``.

numba compiles each kernel the first time a process calls it and keeps the
machine code in its disk cache (see :mod:`ase_spin._jit.cache`). This module
makes those first calls on purpose, so that a later run starts warm: on a
cluster's login node before jobs are submitted, in a container image, after an
install. It runs, for every scene, one evaluation through the calculator
(energy, forces, stress, magnetic forces) and four steps of an integrator
(a small system's last three as one block of compiled steps, as ``run``
takes them), writing nothing: exactly the kernels that scene needs.

Without input files it runs a built-in set: fcc Co with Lennard-Jones and
Bethe–Slater exchange, alone and with a Zeeman field and uniaxial anisotropy,
at 108 atoms (the serial kernels of small systems) and 2048 atoms (the
threaded ones), through ``CollectivePRK`` (orders 2 and 4, and with a frozen
lattice), ``SuzukiTrotter`` and ``Langevin``; and every other spin term
(cubic anisotropy, DMI, biquadratic and shell exchange) through
``CollectivePRK`` and ``Langevin``, whose kernels then serve any combination
of terms; and the dipolar Ewald sum over k-vectors and on a mesh
(:func:`~ase_spin.scenes.dipolar_sums`: 108 atoms, the mesh at 2048 atoms
too). EAM compiles on first use, or give an input file that uses it.

The tasks after the first run in ``jobs`` processes at once (numba compiles
on one core); the first one, alone, compiles the kernels every scene shares.
"""

from __future__ import annotations

import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

import ase_spin

from .._jit import cache as compilation
from .._jit.reductions import balanced_chunks
from ..neighbors import NeighborCache
from ..scenes import dipolar_sums, fcc_cobalt, field_anisotropy_terms, other_spin_terms
from .inputs import build_integrator, build_scene, in_folder, load_input

__all__ = ["BUILTIN", "compile_kernels"]

_BATH = {"temperature_K": 100.0, "spin_damping": 0.01, "friction": 0.01, "rng": 0}

#: The spin terms a built-in task adds to fcc Co's exchange, by name.
EXTRA_TERMS = {"none": tuple, "field": field_anisotropy_terms, "all": other_spin_terms,
               "dipolar": dipolar_sums, "mesh": lambda: dipolar_sums(("pme",))}

#: The built-in tasks: (label, cells per edge (4n³ atoms), the spin terms beside
#: exchange (a key of EXTRA_TERMS), integrator, keywords). The first runs alone
#: (the kernels every scene shares); then the small and the large systems, one process each
#: (serial kernels for one, threaded for the other: little shared work).
BUILTIN = [
    [("calculator, 108 atoms", 3, "none", None, {})],
    [("CollectivePRK, 108 atoms", 3, "none", "CollectivePRK", {}),
     ("CollectivePRK order 4, 108 atoms", 3, "none", "CollectivePRK", {"order": 4}),
     ("CollectivePRK, frozen lattice, 108 atoms", 3, "none", "CollectivePRK",
      {"lattice": "frozen"}),
     ("SuzukiTrotter, 108 atoms", 3, "none", "SuzukiTrotter", {}),
     ("Langevin, 108 atoms", 3, "none", "Langevin", _BATH),
     ("CollectivePRK + field + anisotropy, 108 atoms", 3, "field", "CollectivePRK", {}),
     ("SuzukiTrotter + field + anisotropy, 108 atoms", 3, "field", "SuzukiTrotter", {}),
     ("CollectivePRK + every spin term, 108 atoms", 3, "all", "CollectivePRK", {}),
     ("Langevin + every spin term, 108 atoms", 3, "all", "Langevin", _BATH),
     ("CollectivePRK + dipolar Ewald and mesh sums, 108 atoms", 3, "dipolar", "CollectivePRK",
      {}),
     ("Langevin + dipolar Ewald and mesh sums, 108 atoms", 3, "dipolar", "Langevin", _BATH)],
    [("calculator, 2048 atoms", 8, "none", None, {}),
     ("CollectivePRK, 2048 atoms", 8, "none", "CollectivePRK", {}),
     ("CollectivePRK order 4, 2048 atoms", 8, "none", "CollectivePRK", {"order": 4}),
     ("Langevin, 2048 atoms", 8, "none", "Langevin", _BATH),
     ("CollectivePRK + field + anisotropy, 2048 atoms", 8, "field", "CollectivePRK", {}),
     ("CollectivePRK + every spin term, 2048 atoms", 8, "all", "CollectivePRK", {}),
     ("Langevin + every spin term, 2048 atoms", 8, "all", "Langevin", _BATH),
     ("CollectivePRK + dipolar mesh sum, 2048 atoms", 8, "mesh", "CollectivePRK", {})],
]


def _exercise_lists(atoms):
    """The pair lists' later life, which four steps do not reach: sub-lists
    filtered again, and checked against two sets of positions
    (:class:`~ase_spin.neighbors.NeighborCache`)."""
    cache = NeighborCache(4.7, 0.3)
    cell, pbc = atoms.cell.array, atoms.pbc
    cache.update(atoms.positions, cell, pbc)
    cache.sublist(4.0, half=True)
    moved = atoms.positions + [0.1, 0.0, 0.0]
    for _ in range(2):
        cache.update(moved, cell, pbc, also=atoms.positions)
        cache.sublist(4.0, half=True)


def _exercise(atoms, dyn):
    atoms.get_potential_energy()
    atoms.get_forces()
    atoms.get_stress()
    atoms.calc.get_magnetic_forces(atoms)
    if dyn is None:
        _exercise_lists(atoms)
    if dyn is not None:
        # the first step alone, then a block: for a small system its fused step
        # and a block of them (md/fused.py), compiled here rather than in a
        # user's first run
        dyn.run(4)
        # and a step that ends in a frame (a trajectory, any observer but the
        # log line): it asks the spin operators for the energy and the virial
        dyn.attach(lambda: None, interval=1)
        dyn.run(1)
        dyn.get_spin_temperature_sums()  # the log line's Ts (the terms' self_curvature)


def _builtin(task):
    from ase import units

    label, n, extra, integrator, keywords = task
    atoms = fcc_cobalt(n, extra=EXTRA_TERMS[extra]())
    atoms.rattle(0.02, seed=1)
    dyn = None
    if integrator is not None:
        dyn = getattr(ase_spin, integrator)(atoms, 0.1 * units.fs, **keywords)
    _exercise(atoms, dyn)


def _input(path):

    path = Path(path).resolve()
    spec = load_input(path)
    with in_folder(path.parent):
        atoms = build_scene(spec)
        dyn, _ = build_integrator(atoms, spec, {"trajectory": None, "log": None}, 1, 2)
        _exercise(atoms, dyn)


def _run(kind, task):
    """One task in this process: (label, seconds, kernels compiled)."""
    from numba.core import event

    compiled = []

    class Count(event.Listener):
        def on_start(self, ev):
            pass

        def on_end(self, ev):
            d = ev.data.get("dispatcher") if isinstance(ev.data, dict) else None
            module = getattr(getattr(d, "py_func", None), "__module__", "") or ""
            if module.startswith("ase_spin"):
                compiled.append(d)

    listener = Count()
    t0 = time.perf_counter()
    with event.install_listener("numba:compile", listener):
        if kind == "builtin":
            _builtin(task)
            label = task[0]
        else:
            _input(task)
            label = str(task)
    return label, time.perf_counter() - t0, len(compiled)


def _run_chain(chain):
    return [_run(kind, task) for kind, task in chain]


def compile_kernels(inputs=(), jobs=1, out=None):
    """Compile (or load from numba's cache) every kernel the scenes of the
    TOML ``inputs`` use, or the built-in set if there are none; after the
    first scene, up to ``jobs`` processes at once. Prints one line per scene
    and where the cache is; returns [(label, seconds, kernels compiled)]."""
    out = out or sys.stdout
    if inputs:
        chains = [[("input", str(p))] for p in inputs]
    else:
        chains = [[("builtin", task) for task in chain] for chain in BUILTIN]

    print(f"compiling ase_spin's kernels for {sum(map(len, chains))} scene(s) into "
          f"{_where(compilation.cache_dir(balanced_chunks))} (CPU: {_cpu()})",
          file=out, flush=True)
    t0 = time.perf_counter()
    results = []
    first, rest = chains[0], chains[1:]
    for result in _run_chain(first):
        results.append(result)
        _report(result, out)
    if jobs > 1 and len(rest) > 1:
        # a fresh interpreter per worker (spawn): no numba state or threads forked
        with ProcessPoolExecutor(min(jobs, len(rest)), mp_context=get_context("spawn")) as pool:
            for chain in pool.map(_run_chain, rest):
                for result in chain:
                    results.append(result)
                    _report(result, out)
    else:
        for chain in rest:
            for result in _run_chain(chain):
                results.append(result)
                _report(result, out)
    total = sum(r[2] for r in results)
    print(f"done in {time.perf_counter() - t0:.1f} s: {total} kernel(s) compiled, the rest "
          "loaded from the cache", file=out, flush=True)
    return results


def _report(result, out):
    label, seconds, n = result
    print(f"  {label}: {seconds:.1f} s, {n} kernel(s) compiled", file=out, flush=True)


def _where(path):
    if os.path.basename(path.rstrip(os.sep)) == "__pycache__":
        return f"the __pycache__ folders under {compilation.PACKAGE_ROOT}"
    return path


def _cpu():
    """The CPU numba compiles for: a cached kernel is used only on this one
    (NUMBA_CPU_NAME overrides it, e.g. 'generic' for a mixed cluster)."""
    from numba.core import config

    if config.CPU_NAME:
        return f"{config.CPU_NAME} (NUMBA_CPU_NAME)"
    import llvmlite.binding as ll

    return ll.get_host_cpu_name()
