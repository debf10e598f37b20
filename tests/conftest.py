import importlib.machinery
import importlib.util
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from ase import Atoms
from ase.build import bulk


def _source_digest(package):
    """The source digest of the ase_spin package in folder ``package``, by
    that copy's own ase_spin._jit.cache.source_digest (loaded on its own)."""
    spec = importlib.util.spec_from_file_location("_digest_of_copy",
                                                  package / "_jit" / "cache.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.source_digest()


def _import_the_installed_copy():
    """``pip install ".[test]" && python -m pytest`` puts this tree first on
    sys.path, beside the copy pip installed: numba would compile every kernel
    again for the tree's files. When the installed copy is this tree's source
    (same digest), the tests import it instead, and the kernels an earlier
    run compiled for it (examples/demo.py) serve the tests too. A tree edited
    since the install, or an editable install, is imported as it is."""
    tree = Path(__file__).resolve().parents[1]
    on_tree = [p for p in sys.path if Path(p or ".").resolve() == tree]
    if not on_tree or "ase_spin" in sys.modules:
        return
    others = [p for p in sys.path if p not in on_tree]
    spec = importlib.machinery.PathFinder.find_spec("ase_spin", others)
    if spec is None or spec.origin is None:
        return
    installed = Path(spec.origin).resolve().parent
    if installed == tree / "ase_spin":
        return
    if _source_digest(installed) == _source_digest(tree / "ase_spin"):
        sys.path[:] = others


_import_the_installed_copy()

import ase_spin  # noqa: E402

#: The folder holding the ase_spin the tests import (this tree, or the installed
#: copy): what a test puts on PYTHONPATH for a child process, so that the child
#: runs the same copy and loads the kernels compiled for it.
PACKAGE_PATH = str(Path(ase_spin.__file__).resolve().parents[1])

CO_LJ = dict(epsilon=0.4, sigma=2.2742, rc=4.7)
CO_BS = (0.0446928, 0.003496, 1.4885)


def random_spins(n, rng):
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1)[:, None]


def cone_spins(n, rng, angle_deg=30.0):
    """Directions uniform in a cone of half-angle ``angle_deg`` about +z."""
    cmin = np.cos(np.radians(angle_deg))
    cz = rng.uniform(cmin, 1.0, n)
    phi = rng.uniform(0, 2 * np.pi, n)
    sz = np.sqrt(1 - cz**2)
    return np.column_stack([sz * np.cos(phi), sz * np.sin(phi), cz])


def structures():
    """name -> Atoms: rattled bulk cells, a triclinic cell, a cell smaller than
    the cutoff (atoms see their own images), open and mixed boundaries."""
    rng = np.random.default_rng(7)
    out = {}
    out["fcc"] = bulk("Co", "fcc", a=3.54, cubic=True).repeat(2)
    out["bcc"] = bulk("Fe", "bcc", a=2.87, cubic=True).repeat(2)
    out["hcp"] = bulk("Co", "hcp", a=2.507, c=4.07).repeat((2, 2, 2))
    tri = bulk("Co", "fcc", a=3.54, cubic=True).repeat((2, 1, 2))
    shear = np.array([[1.0, 0.08, -0.05], [0.11, 0.97, 0.06], [-0.07, 0.13, 1.02]])
    tri.set_cell(tri.cell.array @ shear, scale_atoms=True)
    tri.rattle(0.08, seed=11)
    out["triclinic"] = tri
    out["tiny"] = bulk("Co", "fcc", a=3.54)  # one atom, cell << cutoff
    out["tiny2"] = Atoms("Co2", cell=[[3.2, 0, 0], [1.1, 3.0, 0], [0.3, 0.9, 3.3]],
                         scaled_positions=[[0, 0, 0], [0.45, 0.55, 0.5]], pbc=True)
    cluster = bulk("Co", "fcc", a=3.54, cubic=True).repeat(2)
    cluster.pbc = False
    cluster.cell[:] = 0.0
    out["open"] = cluster
    slab = bulk("Co", "fcc", a=3.54, cubic=True).repeat((2, 2, 1))
    slab.pbc = [True, True, False]
    out["slab"] = slab
    for name, atoms in out.items():
        if name != "triclinic":
            atoms.rattle(0.08, seed=len(name))
        if len(atoms) > 1:
            assert atoms.get_all_distances(mic=True)[np.triu_indices(len(atoms), 1)].min() > 2.0
        ase_spin.set_spins(atoms, random_spins(len(atoms), rng))
    return out


@pytest.fixture(autouse=True)
def _threads_as_they_were():
    """Each test starts with the threads' mode and numba's thread count as the
    process had them: a KeyboardInterrupt that lands between a ``with``
    context's entry and the start of its body (tests/test_validation.py raises
    one at every line of a step) skips its exit, which CPython's with
    statement cannot prevent, and would carry a serial mode into later tests."""
    import numba as nb

    from ase_spin._jit import threads

    mode = (threads._mode.serial, threads._mode.tiny)
    count = nb.get_num_threads()
    yield
    threads._mode.serial, threads._mode.tiny = mode
    nb.set_num_threads(count)


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


def general_path_only(monkeypatch):
    """Send every CollectivePRK step of a small system down the general path:
    neither the fused step nor blocks of them (ase_spin.md.fused)."""
    from ase_spin.md import fused

    monkeypatch.setattr(fused, "collective_step", lambda *args: None)
    monkeypatch.setattr(fused, "collective_block", lambda *args: (0, 0, 0, 0))


def spy_fused(monkeypatch):
    """Count the fused steps taken (one per stage; a block's steps counted as
    such) and given up."""
    from ase_spin.md import fused

    used = {"done": 0, "general": 0, "blocks": 0}
    step, block = fused.collective_step, fused.collective_block

    def spy_step(*args):
        result = step(*args)
        used["done" if result is not None else "general"] += 1
        return result

    def spy_block(*args):
        result = block(*args)
        used["done"] += result[0]
        used["blocks"] += result[0] > 0
        return result

    monkeypatch.setattr(fused, "collective_step", spy_step)
    monkeypatch.setattr(fused, "collective_block", spy_block)
    return used


def interrupted_at(k, action):
    """Run ``action()`` with a KeyboardInterrupt raised at the k-th line
    executed in ase_spin (Python lines only: compiled code is not traced).
    Returns True if it completed before the k-th line, False if interrupted."""
    import sys

    count = [0]

    def tracer(frame, event, arg):
        if event == "line" and "ase_spin" in frame.f_code.co_filename:
            count[0] += 1
            if count[0] == k:
                raise KeyboardInterrupt
        return tracer

    sys.settrace(tracer)
    try:
        action()
        return True
    except KeyboardInterrupt:
        return False
    finally:
        sys.settrace(None)


#: Tests that are the first (often the only) to call a kernel no earlier test
#: compiles, each taking seconds of numba compilation from a cold cache
#: (measured with a numba:compile listener per test): colour-ordered and
#: frozen-lattice solvers, fused steps of several combinations, the storage
#: variants, the examples' scenes.
COMPILE_AHEAD = (
    "test_midpoint_solver.py",
    "test_small_systems.py",
    "test_exchange_storage.py",
    "test_golden.py",
    "test_examples.py",
    "test_cli.py::test_dyn_run_progress_changes_nothing_but_the_display",
    "test_cell_list.py::test_atoms_outside_the_cell_get_shifted_images",
    "test_gaussian.py",
    "test_langevin.py::test_bath_kernels_equal_the_spin_by_spin_formulas",
    "test_langevin.py::test_pairs_sampled_with_the_end_field_from_the_midpoint",
    "test_dipolar.py",
    "test_ase_integration.py::test_emt_plus_exchange_derivatives_by_finite_differences",
    "test_ase_integration.py::test_frames_with_a_frozen_lattice_and_an_open_system",
    "test_ase_integration.py::test_timestep_warnings_name_the_value_in_fs",
)

#: The test that reads the scan of test_compilation (started with the run).
SCAN = "test_each_kernel_is_compiled_for_one_set_of_argument_types"

#: Set in the environment of the child that compiles ahead (it starts none).
AHEAD_CHILD = "ASE_SPIN_TESTS_COMPILING_AHEAD"

#: Child processes started for the run, stopped with it.
children = []


def _ahead_rank(item):
    """The place in :data:`COMPILE_AHEAD` of the entry naming ``item``, or None."""
    name = item.nodeid.split("/")[-1]
    for rank, prefix in enumerate(COMPILE_AHEAD):
        if name.startswith(prefix):
            return rank
    return None


#: Tests that fix two threads: each parallel region waits for both, so a child
#: process holding one of the two cores stalls them at every region. They run
#: after the children have ended (:func:`_quiet`).
QUIET = ("test_reproducibility.py",)


def _is_quiet(item):
    return item.nodeid.split("/")[-1].startswith(QUIET)


def pytest_collection_modifyitems(session, config, items):
    """The tests of :data:`COMPILE_AHEAD` run last, in its order, so that the
    child compiling ahead (:func:`pytest_collection_finish`) has the run until
    then to compile their kernels; then the :data:`QUIET` tests, once the
    children have ended; then the test that reads the scan (started with the
    run)."""
    ahead = sorted((item for item in items if _ahead_rank(item) is not None),
                   key=_ahead_rank)
    scan = [item for item in items if item.name == SCAN]
    quiet = [item for item in items if _is_quiet(item) and _ahead_rank(item) is None]
    rest = [item for item in items if _ahead_rank(item) is None and item.name != SCAN
            and not _is_quiet(item)]
    items[:] = rest + ahead + quiet + scan


def finish(child, timeout=1800):
    """Wait for a child process to end and return its (stdout, stderr), kept on
    it (``output``): a child writing to a pipe is read while it runs (a full
    pipe would stop it), and its output is there for whoever asks next."""
    if not hasattr(child, "output"):
        child.output = child.communicate(timeout=timeout)
    return child.output


@pytest.fixture(autouse=True)
def _quiet(request):
    """Before a :data:`QUIET` test: wait for the child processes to end."""
    if _is_quiet(request.node):
        for child in children:
            try:
                finish(child)
            except subprocess.TimeoutExpired:  # a stuck child: run the test beside it
                pass
    yield


#: Runs the command in its arguments at the lowest priority (nice 19): a test's
#: threaded kernels wait at every parallel region for each of their threads, so
#: a child that took time slices from one of them would slow the run it is
#: meant to speed up.
IDLE = """
import os, sys
os.nice(19)
os.execv(sys.argv[1], sys.argv[1:])
"""


def pytest_collection_finish(session):
    """A cold run compiles for minutes on one core while the other waits. Two
    child processes take the second core: test_compilation's scan of every
    kernel (for small and large systems; its test reads the output), which
    also compiles the kernels most tests share, and, on what is left idle
    (:data:`IDLE`), the tests of :data:`COMPILE_AHEAD` this session
    holds (their results unread), which compiles their kernels into numba's
    disk cache before this run reaches them."""
    import os
    import subprocess

    if os.environ.get(AHEAD_CHILD):
        return
    if any(item.name == SCAN for item in session.items):
        import test_compilation

        test_compilation.started.append(test_compilation.start_scan())
        children.append(test_compilation.started[-1])  # (its test may pop it)
    ids = [item.nodeid for item in session.items if _ahead_rank(item) is not None]
    if ids:
        env = {**os.environ, AHEAD_CHILD: "1", "ASE_SPIN_QUIET_COMPILE": "1"}
        children.append(subprocess.Popen(
            [sys.executable, "-c", IDLE, sys.executable, "-m", "pytest", "-q", "-p",
             "no:cacheprovider", *ids],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env,
            cwd=Path(__file__).resolve().parents[1], start_new_session=True))


def pytest_sessionfinish(session):
    """The child the run did not wait for (stopped early, -x) is stopped with
    it, its own children too."""
    import os
    import signal

    for child in children:
        if child.poll() is None:
            try:
                os.killpg(child.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        finish(child)
