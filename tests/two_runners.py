"""The test run on two cores: a second pytest process runs test files beside
this one.

A cold run spends most of its time in numba compiling kernels, one core at a
time; the machine the tests must fit (2 cores) would idle one core. So a run
of more than one test file starts a second runner as it starts, a child
pytest process that collects the tests beside this one and then keeps this
one's selection, and both take whole test files from one list, each
file run by whichever process claims it first (an exclusive file create in a
shared folder): this process from the front of the list, the child from the
back, each starting with files of its own (:data:`MAIN_FIRST`,
:data:`CHILD_FIRST`), until they meet. Each process runs its files as pytest always does;
the child sends every report of its tests (serialised by pytest's own hooks,
as pytest-xdist does) through a file, and this process, once its own files
are done, waits for the child and reports them as if it had run them: the
summary, the failures and the exit status are those of one run. Tests that
must have the machine to themselves (:data:`ALONE`) run after the child has
ended, in this process.

A child that dies leaves its unreported tests failed, with its exit status
and its output. ``ASE_SPIN_TESTS_ONE_RUNNER=1`` runs everything in one
process (as does a run of one file).
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import pytest

#: Set in the child's environment: the shared folder.
SHARED = "ASE_SPIN_TESTS_SHARED_FOLDER"
#: Set to 1 to run every test in this process.
ONE_RUNNER = "ASE_SPIN_TESTS_ONE_RUNNER"
#: The file (in the shared folder) listing the selected tests' node ids.
ITEMS = "items.txt"

#: Test files run after the child has ended, in this process: those that fix
#: two threads (each parallel region waits for both, so a second process
#: holding one of the two cores stalls them at every region); single tests
#: that do are marked ``alone`` and join them.
ALONE = ("test_reproducibility.py",)
#: Test files the child starts with, in this order, before taking files from
#: the back of the list: files whose kernels are mostly their own (Monte
#: Carlo, the dipolar sums, the Gaussian stream, EAM, spectra, ...), so that
#: the child compiles those while this process compiles the common path of
#: the integrators (pair lists, exchange geometry, midpoint solves), instead
#: of both compiling the same kernels at the same time early in a cold run
#: (test_dipolar after test_landscapes and test_dipolar_mesh last: their
#: reference runs take the small-system step, which this process compiles
#: first; taken earlier, test_dipolar compiled it again beside this process),
#: then test_lammps_plugin, a long file that would otherwise be among the last
#: (see :data:`MAIN_FIRST`).
CHILD_FIRST = ("test_import_graph.py", "test_gaussian.py", "test_montecarlo.py",
               "test_landscapes.py", "test_dipolar.py", "test_eam.py", "test_spectra.py",
               "test_io.py", "test_dipolar_mesh.py", "test_lammps_plugin.py")
#: Test files this process starts with, in this order, before taking the rest
#: from the front of the list: the one that compiles the integrators' common
#: path, then the longest files, so that the two runners meet among short
#: files (one runner waits for the other's last file at the end; test_fuzz:
#: long, and alphabetically where they would meet).
MAIN_FIRST = ("test_ase_integration.py", "test_langevin.py", "test_examples.py", "test_fuzz.py")
#: The test that runs test_compilation's scan of every kernel's signatures (a
#: process of its own): taken by whichever runner runs out of files first
#: (the kernels are in numba's cache by then, so the scan loads them rather
#: than compiling them a third time), while the other finishes its last file.
SCAN = "test_each_kernel_is_compiled_for_one_set_of_argument_types"

_state = {"child": None, "folder": None, "made": None, "role": "main"}


def _file(item):
    return item.nodeid.split("::")[0]


def _alone(item):
    return _file(item).split("/")[-1] in ALONE or item.get_closest_marker("alone") is not None


def is_child():
    return _state["role"] == "child"


def pytest_configure(config):
    if os.environ.get(SHARED):
        _state["role"] = "child"
        _state["folder"] = Path(os.environ[SHARED])
        _end_with_the_parent()
    else:
        _start_child(config)


def _end_with_the_parent(every=1.0):
    """In the child: end the process when the main one has gone (killed, so
    that it could not stop the child itself), rather than run on alone,
    holding a core, after the run it belonged to."""
    parent = os.getppid()

    def watch():
        while os.getppid() == parent:
            time.sleep(every)
        os._exit(3)

    threading.Thread(target=watch, daemon=True, name="end-with-the-parent").start()


def pytest_collection_modifyitems(session, config, items):
    """The child keeps the items the main process selected (its list, which
    it waits for: both processes collect at the same time)."""
    if not is_child():
        return
    path = _state["folder"] / ITEMS
    while not path.exists():
        time.sleep(0.05)
    wanted = set(path.read_text().splitlines())
    keep = [item for item in items if item.nodeid in wanted]
    dropped = [item for item in items if item.nodeid not in wanted]
    if dropped:
        config.hook.pytest_deselected(items=dropped)
    items[:] = keep


def _groups(items):
    """(the items by file, in order of first appearance; the scan test as a
    group of its own; the :data:`ALONE` files)."""
    groups, scan, alone = {}, [], []
    for item in items:
        if item.name == SCAN:
            scan.append(item)
        elif _alone(item):
            alone.append(item)
        else:
            groups.setdefault(_file(item), []).append(item)
    return list(groups.items()), [(f"{_file(i)}::scan", [i]) for i in scan], alone


def _first(groups, names):
    """``groups`` (file, items) with the files ``names`` first, in that
    order, the others after them in their order."""
    first = {name: k for k, name in enumerate(names)}
    return sorted(groups, key=lambda g: first.get(g[0].split("/")[-1], len(first)))


def _claim(name):
    """True if this process is the first to claim test file ``name``."""
    path = _state["folder"] / "claims" / name.replace("/", "__")
    try:
        os.close(os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
    except FileExistsError:
        return False
    with open(path, "w") as fd:
        fd.write(_state["role"])
    return True


def _one_file(config):
    """Whether the command line names test files or tests of one file only."""
    paths = {str(arg).split("::")[0] for arg in config.args}
    return len(paths) == 1 and Path(next(iter(paths))).is_file()


def _start_child(config):
    """Start the second runner as this process starts, so that it collects the
    tests while this one does (a cold collection rewrites every test file's
    asserts: seconds), unless the run is of one process (:data:`ONE_RUNNER`,
    one file, --collect-only, --pdb); :func:`start_child` hands it the
    selection once collected, or stops it."""
    if (os.environ.get(ONE_RUNNER) or config.option.collectonly
            or config.getoption("usepdb", False) or _one_file(config)):
        return
    folder = Path(tempfile.mkdtemp(prefix="ase_spin_tests_"))
    (folder / "claims").mkdir()
    _state["folder"] = _state["made"] = folder
    root = Path(config.rootpath)
    env = {**os.environ, SHARED: str(folder), "ASE_SPIN_QUIET_COMPILE": "1"}
    log = open(folder / "child.out", "w")
    _state["child"] = subprocess.Popen(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-m", "",
         "--rootdir", str(root), *map(str, config.args)],
        stdout=log, stderr=subprocess.STDOUT, env=env, cwd=config.invocation_params.dir,
        start_new_session=True)
    log.close()


def start_child(session):
    """Hand the second runner the selected tests if the run has more than one
    test file to share, else stop it (this process runs them all)."""
    if _state["child"] is None:
        return
    groups, _, _ = _groups(session.items)
    folder = _state["folder"]
    if len(groups) < 2 or session.testsfailed:
        _stop_child()
        _state["folder"] = None
        return
    partial = folder / (ITEMS + ".part")
    partial.write_text("\n".join(item.nodeid for item in session.items))
    partial.rename(folder / ITEMS)


@pytest.hookimpl(tryfirst=True)
def pytest_runtestloop(session):
    """Run the claimed files; in the main process, then the child's reports,
    then the :data:`ALONE` files."""
    if session.testsfailed and not session.config.option.continue_on_collection_errors:
        return None  # pytest's own loop reports the collection errors
    if _state["folder"] is None or session.config.option.collectonly:
        return None  # one runner: pytest's own loop
    import numba as nb

    groups, scan, tail = _groups(session.items)
    if is_child():
        groups, tail = _first(groups[::-1], CHILD_FIRST), []
    else:
        groups = _first(groups, MAIN_FIRST)
    groups = groups + scan
    # One active thread each while both run: two processes of two threads on
    # two cores would wait at every parallel region for a descheduled worker
    # (milliseconds each). The threaded kernels split their work into
    # NUMBA_NUM_THREADS chunks whatever the active count: the same bits.
    nb.set_num_threads(1)

    start = time.perf_counter()
    for name, items in groups:
        if not _claim(name):
            continue
        _run(session, items)
    _state["busy"] = time.perf_counter() - start
    if is_child():
        (_state["folder"] / "child_busy").write_text(f"{_state['busy']:.1f}")
    else:
        waited = time.perf_counter()
        _report_the_child(session, groups)
        _state["waited"] = time.perf_counter() - waited
        nb.set_num_threads(nb.config.NUMBA_NUM_THREADS)
        _run(session, tail)
    return True


def pytest_terminal_summary(terminalreporter):
    """One line on how the two runners shared the files (for the test time)."""
    if is_child() or _state.get("busy") is None:
        return
    claims = _state["folder"] / "claims"
    mine = sum(1 for f in claims.iterdir() if f.read_text() == "main")
    busy = _state["folder"] / "child_busy"
    theirs = f" in {float(busy.read_text()):.0f} s" if busy.exists() else ""
    terminalreporter.write_line(
        f"two runners: this process ran {mine} test files in {_state['busy']:.0f} s, the "
        f"second {sum(1 for _ in claims.iterdir()) - mine}{theirs} and was waited for "
        f"{_state['waited']:.0f} s more")


def _run(session, items):
    for k, item in enumerate(items):
        nextitem = items[k + 1] if k + 1 < len(items) else None
        item.config.hook.pytest_runtest_protocol(item=item, nextitem=nextitem)
        if session.shouldfail:
            raise session.Failed(session.shouldfail)
        if session.shouldstop:
            raise session.Interrupted(session.shouldstop)


def pytest_runtest_logreport(report):
    """In the child: every report, serialised, to the shared folder."""
    if not is_child():
        return
    config = _state["config"]
    data = config.hook.pytest_report_to_serializable(config=config, report=report)
    with open(_state["folder"] / "reports.jsonl", "a") as fd:
        fd.write(json.dumps(data) + "\n")


@pytest.hookimpl(trylast=True)
def pytest_sessionstart(session):
    _state["config"] = session.config


def _report_the_child(session, groups):
    """Wait for the child; report the tests of the groups ((claim name,
    items)) it claimed."""
    child = _state["child"]
    if child is None:
        return
    try:
        child.wait(timeout=3600)
    except subprocess.TimeoutExpired:
        child.kill()
        child.wait()
    folder = _state["folder"]
    config = session.config
    reports = {}
    path = folder / "reports.jsonl"
    if path.exists():
        for line in path.read_text().splitlines():
            if line.strip():
                report = config.hook.pytest_report_from_serializable(config=config,
                                                                     data=json.loads(line))
                reports.setdefault(report.nodeid, []).append(report)
    output = (folder / "child.out").read_text(errors="replace")
    for name, items in groups:
        claim = folder / "claims" / name.replace("/", "__")
        if not claim.exists() or claim.read_text() != "child":
            continue
        for item in items:
            hook = item.ihook
            hook.pytest_runtest_logstart(nodeid=item.nodeid, location=item.location)
            got = reports.get(item.nodeid)
            if got is None:
                got = [_lost(item, child.returncode, output)]
            for report in got:
                hook.pytest_runtest_logreport(report=report)
            hook.pytest_runtest_logfinish(nodeid=item.nodeid, location=item.location)


def _lost(item, returncode, output):
    """A failed report for a test of the child's that it never reported."""
    from _pytest.reports import TestReport

    text = (f"the second test runner (a child pytest process, tests/two_runners.py) "
            f"ended with exit status {returncode} before reporting this test; the end "
            f"of its output:\n{output[-4000:]}")
    return TestReport(item.nodeid, item.location, {}, "failed", text, "call", [], 0.0)


def pytest_sessionfinish(session):
    """A child the run did not wait for (stopped early, -x) is stopped with it."""
    _stop_child()


@pytest.hookimpl(trylast=True)
def pytest_unconfigure(config):
    """The shared folder goes, once the summary has read it (the one this
    process made, also when it stopped the child early)."""
    folder = _state["made"]
    if folder is not None and not is_child():
        shutil.rmtree(folder, ignore_errors=True)


def _stop_child():
    """Stop the second runner if it is still running."""
    child = _state["child"]
    if child is not None and child.poll() is None:
        try:
            os.killpg(child.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        child.wait()
