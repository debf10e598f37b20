"""The example scripts' command lines: --help, where they write (the current folder
or the --out they are given, never docs/figures unless asked), and files they report
as written exist. Each runs in an empty folder, as ``python script.py ...`` would
run it (runpy, ``__name__ == "__main__"``): the runs that only parse their command
line (--help, a refused --out) one after another in one process, the short runs
in another, the slow ones each in a process of its own."""

import importlib.util
import json
import math
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import PACKAGE_PATH

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = sorted((ROOT / "examples").glob("*.py"))


def run(script, *args, cwd):
    env = {**os.environ, "PYTHONPATH": PACKAGE_PATH, "MPLBACKEND": "Agg"}
    return subprocess.run([sys.executable, str(ROOT / "examples" / script), *args], cwd=cwd,
                          capture_output=True, text=True, env=env, timeout=900,
                          check=False)


#: Runs scripts one after another in one Python process: for each (script,
#: arguments, folder) its exit code, standard output and standard error, as JSON.
_IN_TURN = r"""
import contextlib, io, json, os, runpy, sys, traceback
results = []
for script, args, cwd in json.loads(sys.argv[1]):
    out, err = io.StringIO(), io.StringIO()
    os.chdir(cwd)
    sys.argv = [script, *args]
    sys.path[0] = os.path.dirname(script)
    code = 0
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            runpy.run_path(script, run_name="__main__")
        except SystemExit as stop:
            code = stop.code if isinstance(stop.code, int) else int(stop.code is not None)
        except BaseException:
            traceback.print_exc()
            code = 1
    results.append((code, out.getvalue(), err.getvalue()))
sys.stdout.write(json.dumps(results))
"""


def run_in_turn(calls):
    """subprocess.CompletedProcess-like (returncode, stdout, stderr) of each
    (script, arguments, folder) of ``calls``, run in turn in one process."""
    env = {**os.environ, "PYTHONPATH": PACKAGE_PATH, "MPLBACKEND": "Agg"}
    spec = [(str(ROOT / "examples" / script), list(args), str(cwd)) for script, args, cwd in calls]
    done = subprocess.run([sys.executable, "-c", _IN_TURN, json.dumps(spec)], capture_output=True,
                          text=True, env=env, timeout=900, check=True)
    return [subprocess.CompletedProcess(call, *result)
            for call, result in zip(calls, json.loads(done.stdout))]


def files_in(folder):
    return sorted(str(p.relative_to(folder)) for p in Path(folder).rglob("*"))


def reported(stdout, cwd):
    """The paths of the script's "wrote PATH" lines (the first word after it)."""
    paths = [m.group(1) for m in re.finditer(r"^wrote (\S+)", stdout, re.MULTILINE)]
    return [Path(cwd) / p for p in paths]


def test_every_example_is_found():
    assert {p.name for p in EXAMPLES} >= {"demo.py", "magnetisation_curve.py", "metals.py",
                                          "paper_chain.py", "skyrmion.py", "view_spins.py"}


REFUSE_PNG = ["view_spins.py", "paper_chain.py"]


@pytest.fixture(scope="module")
def command_lines(tmp_path_factory):
    """Every example with --help, and those writing several files with a
    .png --out, each in an empty folder of its own: (the run, its folder) by
    (script, first argument)."""
    calls = [(p.name, ["--help"]) for p in EXAMPLES]
    calls += [(script, ["--out", "x.png"]) for script in REFUSE_PNG]
    folders = [tmp_path_factory.mktemp(script.replace(".", "_")) for script, _ in calls]
    runs = run_in_turn([(script, args, folder) for (script, args), folder in zip(calls, folders)])
    return {(script, args[0]): (done, folder)
            for (script, args), done, folder in zip(calls, runs, folders)}


#: The short runs checked below: (script, arguments), each in an empty folder.
SHORT_RUNS = {
    "skyrmion-png": ("skyrmion.py", ["--size", "8", "--steps", "5", "--out", "sky.png"]),
    "skyrmion-folder": ("skyrmion.py", ["--size", "8", "--steps", "5", "--out", "pictures"]),
    "metals": ("metals.py", ["--steps", "50"]),
    "metals-png": ("metals.py", ["--steps", "50", "--out", "fe.png"]),
    "magnons": ("magnons.py", ["--size", "4", "--steps", "400"]),
    "skyrmion_barrier": ("skyrmion_barrier.py", ["--size", "12", "--images", "7", "--out",
                                                 "b.png"]),
    "dipolar_film": ("dipolar_film.py", ["--ku", "0", "--tilt", "45", "--time", "25",
                                         "--timestep", "5", "--out", "film.png"]),
}


@pytest.fixture(scope="module")
def short_runs(tmp_path_factory):
    """The :data:`SHORT_RUNS`, one after another in one process (a Python
    start, the imports and the kernels' loads once for them all): (the run,
    its folder) by name."""
    names = list(SHORT_RUNS)
    folders = [tmp_path_factory.mktemp(name.replace("-", "_")) for name in names]
    runs = run_in_turn([(*SHORT_RUNS[name], folder) for name, folder in zip(names, folders)])
    return dict(zip(names, zip(runs, folders)))


@pytest.mark.parametrize("script", [p.name for p in EXAMPLES])
def test_help_prints_usage_and_writes_nothing(command_lines, script):
    """`--help` is argparse's: usage on stdout, exit 0, and no file or folder
    (a folder named --help, say) left behind."""
    done, folder = command_lines[script, "--help"]
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("usage:") and "--out" in done.stdout
    assert files_in(folder) == []


@pytest.mark.parametrize("script", REFUSE_PNG)
def test_examples_writing_several_files_refuse_a_png_out(command_lines, script):
    done, folder = command_lines[script, "--out"]
    assert done.returncode == 2 and "--out is a folder" in done.stderr
    assert files_in(folder) == []


def test_skyrmion_writes_the_png_it_is_given_or_into_a_folder(short_runs):
    done, folder = short_runs["skyrmion-png"]
    assert done.returncode == 0, done.stderr
    assert files_in(folder) == ["sky.png"]
    assert reported(done.stdout, folder) == [folder / "sky.png"]
    done, folder = short_runs["skyrmion-folder"]
    assert done.returncode == 0, done.stderr
    assert files_in(folder) == ["pictures", "pictures/skyrmion.png"]


def test_metals_plots_into_the_current_folder(short_runs):
    """The default is iron.png here (it was docs/figures/iron.png); the top panel
    is the conservation check, E_tot − E_tot(0)."""
    from ase_spin.terms.eam_files import lammps_potential_path

    try:
        lammps_potential_path("Fe_mm.eam.fs")
    except FileNotFoundError:
        pytest.skip("Fe_mm.eam.fs not found")
    pytest.importorskip("matplotlib")
    done, folder = short_runs["metals"]
    assert done.returncode == 0, done.stderr
    assert files_in(folder) == ["iron.png"]
    assert reported(done.stdout, folder) == [folder / "iron.png"]
    done, folder = short_runs["metals-png"]
    assert done.returncode == 0, done.stderr
    assert files_in(folder) == ["fe.png"]


def test_magnetisation_curve_out_is_a_picture_or_a_folder():
    spec = importlib.util.spec_from_file_location("magnetisation_curve",
                                                  ROOT / "examples" / "magnetisation_curve.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)  # main() only runs as a script
    assert module.output_paths(Path("mt.png")) == (Path("mt.png"), Path("mt.txt"))
    assert module.output_paths(Path("out/M.PNG")) == (Path("out/M.PNG"), Path("out/M.txt"))
    assert module.output_paths(Path(".")) == (Path("magnetisation_curve.png"),
                                              Path("magnetisation_curve.txt"))
    assert module.output_paths(Path("figs")) == (Path("figs/magnetisation_curve.png"),
                                                 Path("figs/magnetisation_curve.txt"))


def test_magnons_writes_its_figure_and_the_peaks_lie_on_the_bands(short_runs):
    pytest.importorskip("matplotlib")
    done, folder = short_runs["magnons"]
    assert done.returncode == 0, done.stderr
    assert files_in(folder) == ["magnons.png"]
    assert reported(done.stdout, folder) == [folder / "magnons.png"]
    resolution = float(re.search(r"resolution ([0-9.]+) meV", done.stdout).group(1))
    worst = float(re.search(r"where resolved: ([0-9.]+) meV", done.stdout).group(1))
    assert worst < resolution


def test_skyrmion_barrier_runs_short_and_writes_its_figure(short_runs):
    """The short run: the skyrmion relaxes (Q = −1), the band converges, the
    collapse barrier is positive and its figure is written where asked."""
    pytest.importorskip("matplotlib")
    done, folder = short_runs["skyrmion_barrier"]
    assert done.returncode == 0, done.stderr
    assert "Q = -1.0000" in done.stdout and "GNEB converged" in done.stdout
    barrier = float(re.search(r"collapse barrier (\S+) meV", done.stdout).group(1))
    assert barrier > 1.0
    assert files_in(folder) == ["b.png"]
    assert reported(done.stdout, folder) == [folder / "b.png"]


@pytest.mark.slow
def test_skyrmion_barrier_with_the_lattice_free(tmp_path):
    """The lattice free (a triangular film; the band relaxed frozen and free:
    the barrier moves by less than a tenth). Slow: the default run has the
    frozen example above and the spin–lattice band in test_landscapes."""
    pytest.importorskip("matplotlib")
    done = run("skyrmion_barrier.py", "--lattice", "--size", "12", "--images", "9", "--out",
               "lattice", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert done.stdout.count("converged in") == 2 and "NOT" not in done.stdout
    found = re.search(r"lattice frozen (\S+) meV, lattice free (\S+) meV", done.stdout)
    frozen, free = (float(x) for x in found.groups())
    assert frozen > 1.0 and abs(free - frozen) < 0.1 * frozen
    assert files_in(tmp_path) == ["lattice", "lattice/skyrmion_barrier.png"]


def test_dipolar_film_without_anisotropy_turns_into_the_plane(short_runs):
    """K_u = 0: the three-plane Fe film falls from 45° off the normal into the plane
    (within 2°, m_z < sin 2°), releasing the energy its statics predict,
    (E⊥ − E∥) cos²45° per atom, to 1% (what is left at 2° from the plane is
    (E⊥ − E∥) cos²88° ~ 2e-3 of it; without the slab's shape term nothing would
    turn); the monolayer's E⊥ − E∥ is the exact square-lattice sum. The 5 fs step
    (the uniform mode turns in tens of ps; the TimestepWarning is about the
    exchange field's rate, which a uniform state does not feel) keeps it short."""
    pytest.importorskip("matplotlib")
    done, folder = short_runs["dipolar_film"]
    assert done.returncode == 0, done.stderr
    m_z = float(re.search(r"m_z = (\S+),", done.stdout).group(1))
    assert abs(m_z) < math.sin(math.radians(2.0)) and "in-plane, as expected" in done.stdout
    found = re.search(r"energy released (\S+) meV per atom, the statics' (\S+)", done.stdout)
    released, statics = (float(x) for x in found.groups())
    assert statics > 0.0 and abs(released / statics - 1.0) < 0.01
    assert float(re.search(r"monolayer.*relative difference (\S+)\)", done.stdout)
                 .group(1)) < 1e-9
    assert files_in(folder) == ["film.png"]
    assert reported(done.stdout, folder) == [folder / "film.png"]


@pytest.mark.slow
def test_dipolar_film_default_run_turns_one_film_and_keeps_the_other(tmp_path):
    """The default run: K_u = 0 ends in-plane, K_u = 0.2 meV (above the film's
    shape anisotropy, 0.12 meV per atom) back along the normal, each with the
    energy the statics predict to 1%; its figure goes into the folder given."""
    pytest.importorskip("matplotlib")
    done = run("dipolar_film.py", "--out", "figures", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert "in-plane, as expected" in done.stdout
    assert "perpendicular, as expected" in done.stdout and "NOT" not in done.stdout
    for found in re.finditer(r"energy released (\S+) meV per atom, the statics' (\S+)",
                             done.stdout):
        released, statics = (float(x) for x in found.groups())
        assert abs(released / statics - 1.0) < 0.01
    assert files_in(tmp_path) == ["figures", "figures/dipolar_film.png"]
