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


def finish(child, timeout=1800):
    """Wait for a child process to end and return its (stdout, stderr), kept on
    it (``output``): a child writing to a pipe is read while it runs (a full
    pipe would stop it), and its output is there for whoever asks next."""
    if not hasattr(child, "output"):
        child.output = child.communicate(timeout=timeout)
    return child.output


# The run on two cores: a second pytest process takes test files beside this
# one (tests/two_runners.py); its hooks are this conftest's.
from two_runners import (pytest_collection_modifyitems, pytest_configure,  # noqa: E402,F401
                         pytest_runtest_logreport, pytest_runtestloop, pytest_sessionfinish,
                         pytest_sessionstart, pytest_terminal_summary, pytest_unconfigure,
                         start_child)


def pytest_collection_finish(session):
    start_child(session)
