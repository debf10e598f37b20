"""The ``ase-spin`` command line, the progress bar of ``dyn.run`` and the
first-use compilation notice."""

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from ase import units
from ase.io import read

import ase_spin
from ase_spin.app import cli
from ase_spin.app.cli import main
from conftest import PACKAGE_PATH

ROOT = Path(__file__).resolve().parents[1]

SCENE = """
[structure]
build = {{function = "bulk", name = "Co", crystalstructure = "fcc", a = 3.54, cubic = true}}
repeat = [2, 2, 2]
rattle = 0.03
seed = 4

[spins]
magnitude = 1.72
direction = [0, 0, 1]
cone = 30
seed = 5

[velocities]
temperature = 100
seed = 6

[[terms]]
type = "LennardJones"
epsilon = 0.4
sigma = 2.2742
rc = 4.7
cutoff = "shift"

[[terms]]
type = "Exchange"
coupling = {{type = "BetheSlater", J1 = 0.0446928, J2 = 0.003496, J3 = 1.4885}}
rc = 4.0

[[terms]]
type = "Zeeman"
field = [0, 0, 20]

[calculator]
skin = 0.4

[integrator]
type = "{integrator}"
timestep = {timestep}
steps = {steps}
{extra}

[output]
trajectory = "md.traj"
log = "md.log"
xyz = "spins.xyz"
interval = {interval}
"""


def write_input(folder, integrator="CollectivePRK", timestep=0.5, steps=12, interval=4,
                extra="order = 2", text=None):
    path = Path(folder) / "scene.toml"
    path.write_text(text if text is not None else SCENE.format(
        integrator=integrator, timestep=timestep, steps=steps, interval=interval,
        extra=extra))
    return path


def run_cli(*args):
    return main([str(a) for a in args])


@pytest.mark.parametrize("integrator, extra", [("CollectivePRK", "order = 4"),
                                               ("SuzukiTrotter", 'rotation = "exact"')])
def test_run_writes_outputs_and_follows_the_same_scene_in_a_script(tmp_path, integrator,
                                                                    extra, capsys):
    """The command builds the scene the file describes: the same integrator,
    fed the trajectory's first frame in a script, gives its last frame bit for
    bit (timestep in fs, integrator keywords, terms with their parameters)."""
    path = write_input(tmp_path, integrator=integrator, extra=extra)
    assert run_cli("run", path, "--no-progress") == 0
    out = capsys.readouterr().out
    assert "32 atoms" in out and integrator in out and "12 steps" in out
    frames = read(tmp_path / "md.traj", ":")
    assert len(frames) == 12 // 4 + 1
    lines = (tmp_path / "md.log").read_text().splitlines()
    assert lines[0].split()[0] == "Time[ps]" and len(lines) == 1 + len(frames)
    times = [float(line.split()[0]) for line in lines[1:]]
    np.testing.assert_allclose(times, np.arange(len(frames)) * 4 * 0.5e-3, atol=5e-5)
    xyz = read(tmp_path / "spins.xyz", ":")
    assert len(xyz) == len(frames)
    np.testing.assert_allclose(xyz[-1].arrays["dipoles"], ase_spin.get_spins(frames[-1]),
                               atol=1e-7)
    # the magnetic forces of the frames: a column of the xyz file, not its comment line
    assert "magnetic_forces" not in xyz[-1].info
    np.testing.assert_allclose(xyz[-1].arrays["magnetic_forces"],
                               frames[-1].info["magnetic_forces"], rtol=0, atol=1e-8)

    atoms = frames[0].copy()
    atoms.set_momenta(frames[0].get_momenta())
    atoms.calc = ase_spin.SpinLatticeCalculator([
        ase_spin.LennardJones(epsilon=0.4, sigma=2.2742, rc=4.7, cutoff="shift"),
        ase_spin.Exchange(ase_spin.BetheSlater(J1=0.0446928, J2=0.003496, J3=1.4885), rc=4.0),
        ase_spin.Zeeman([0, 0, 20])], skin=0.4)
    cls = getattr(ase_spin, integrator)
    kwargs = {"order": 4} if integrator == "CollectivePRK" else {"rotation": "exact"}
    dyn = cls(atoms, 0.5 * units.fs, **kwargs)
    dyn.run(12)
    np.testing.assert_array_equal(atoms.positions, frames[-1].positions)
    np.testing.assert_array_equal(atoms.arrays["initial_magmoms"],
                                  frames[-1].arrays["initial_magmoms"])


def test_spins_and_velocities_follow_the_input(tmp_path):
    text = SCENE.format(integrator="CollectivePRK", timestep=0.5, steps=0, interval=1,
                        extra="").replace("direction = [0, 0, 1]", "direction = [1, 1, 0]")
    spec = cli.load_input(write_input(tmp_path, text=text))
    atoms = cli.build_scene(spec)
    spins = ase_spin.get_spins(atoms)
    mu = np.linalg.norm(atoms.arrays["initial_magmoms"], axis=1)
    np.testing.assert_allclose(mu, 1.72, rtol=1e-14)
    angle = np.degrees(np.arccos(np.clip(spins @ (np.array([1, 1, 0]) / 2**0.5), -1, 1)))
    assert angle.max() <= 30.0 + 1e-9 and angle.max() > 15.0   # spread over the cone
    assert np.abs(atoms.get_momenta().sum(axis=0)).max() < 1e-12  # no drift
    assert 20.0 < atoms.get_temperature() < 300.0


def test_per_species_magnitudes_and_random_directions(tmp_path):
    text = textwrap.dedent("""
        [structure]
        build = {function = "bulk", name = "NaCl", crystalstructure = "rocksalt", a = 5.6}
        repeat = [2, 2, 2]
        [spins]
        magnitude = {Na = 1.5, Cl = 0}
        direction = "random"
        [[terms]]
        type = "UniaxialAnisotropy"
        K = 0.01
        axis = [0, 0, 1]
        [integrator]
        timestep = 1
        steps = 0
        """)
    atoms = cli.build_scene(cli.load_input(write_input(tmp_path, text=text)))
    mu = np.linalg.norm(atoms.arrays["initial_magmoms"], axis=1)
    na = np.array(atoms.get_chemical_symbols()) == "Na"
    np.testing.assert_allclose(mu[na], 1.5, rtol=1e-14)
    assert not mu[~na].any()
    spins = ase_spin.get_spins(atoms)[na]
    assert np.linalg.norm(spins.mean(axis=0)) < 0.9  # not all one way


def test_structure_from_a_file_relative_to_the_input(tmp_path, monkeypatch):
    from ase.build import bulk
    from ase.io import write

    data = tmp_path / "data"
    data.mkdir()
    atoms = bulk("Fe", "bcc", a=2.87, cubic=True).repeat(2)
    write(data / "fe.xyz", atoms, format="extxyz")
    text = textwrap.dedent("""
        [structure]
        file = "fe.xyz"
        [spins]
        magnitude = 2.2
        [[terms]]
        type = "Exchange"
        coupling = {type = "Cubic", J0 = 0.02, rc = 3.5}
        [integrator]
        type = "SuzukiTrotter"
        timestep = 0.2
        steps = 3
        [output]
        interval = 1
        """)
    path = write_input(data, text=text)
    monkeypatch.chdir(tmp_path)  # run from elsewhere: paths are the input's folder's
    assert run_cli("run", "data/scene.toml", "--no-progress") == 0
    assert os.getcwd() == str(tmp_path)
    frames = read(data / "scene.traj", ":")  # default names: the input's stem
    assert len(frames) == 4 and (data / "scene.log").is_file()
    np.testing.assert_allclose(frames[0].positions, atoms.positions)
    assert path.is_file()


def test_a_term_exported_by_the_package_is_usable_by_name(tmp_path, monkeypatch):
    """Terms are looked up among ase_spin's exports: a new one needs no CLI change."""
    made = []

    class DoubledZeeman(ase_spin.Zeeman):
        def __init__(self, field, **kwargs):
            made.append(field)
            super().__init__([2 * f for f in field], **kwargs)

    monkeypatch.setattr(ase_spin, "DoubledZeeman", DoubledZeeman, raising=False)
    text = SCENE.format(integrator="CollectivePRK", timestep=0.5, steps=0, interval=1,
                        extra="").replace('type = "Zeeman"', 'type = "DoubledZeeman"')
    atoms = cli.build_scene(cli.load_input(write_input(tmp_path, text=text)))
    terms = atoms.calc.hamiltonian.terms
    assert made == [[0, 0, 20]] and isinstance(terms[-1], DoubledZeeman)
    np.testing.assert_array_equal(terms[-1].H, [0, 0, 40])


def test_a_long_range_dipolar_term_from_the_input_file(tmp_path):
    """Dipolar with its keywords (method, accuracy, mesh order) from a [[terms]] table:
    the same term, and the same energy and field, as built in a script."""
    dipolar = '[[terms]]\ntype = "Dipolar"\nrc = 5.0\nmethod = "pme"\naccuracy = 1e-5\norder = 6\n'
    text = SCENE.format(integrator="CollectivePRK", timestep=0.5, steps=0, interval=1,
                        extra="").replace("[calculator]", dipolar + "\n[calculator]")
    atoms = cli.build_scene(cli.load_input(write_input(tmp_path, text=text)))
    term = atoms.calc.hamiltonian.terms[-1]
    assert isinstance(term, ase_spin.Dipolar)
    assert (term.method, term.accuracy, term.spline_order) == ("pme", 1e-5, 6)
    alone = atoms.copy()
    alone.calc = ase_spin.SpinLatticeCalculator([ase_spin.Dipolar(5.0, "pme", accuracy=1e-5,
                                                                  order=6)])
    alone_energy = alone.get_potential_energy()
    assert alone_energy != 0.0
    atoms.calc = ase_spin.SpinLatticeCalculator([term])
    assert atoms.get_potential_energy() == alone_energy
    np.testing.assert_array_equal(atoms.calc.get_magnetic_forces(atoms),
                                  alone.calc.get_magnetic_forces(alone))


@pytest.mark.parametrize("change, message", [
    (('type = "Zeeman"', 'type = "Zeman"'),
     "unknown type 'Zeman' (did you mean 'Zeeman'?); choose one of"),
    (("field = [0, 0, 20]", "field = [0, 0, 20]\nstrength = 3"),
     "unknown key 'strength' in [[terms]] #3 (Zeeman)"),
    (("cutoff = \"shift\"", "cutoff = \"sharp\""), "#1 (LennardJones)"),
    (("[calculator]", "[calculater]"),
     "unknown table [calculater] in "),
    (("[calculator]", "[calculater]"), "(did you mean [calculator]?)"),
    (("steps = 12", "steps = 12.5"), "steps must be an integer"),
    (("timestep = 0.5", "timestep = -0.5"), "[integrator] timestep = -0.5 (fs) must be > 0"),
    (("timestep = 0.5\n", ""), "[integrator] needs 'timestep' (fs)"),
    (("timestep = 0.5", "time_step = 0.5"),
     "unknown key 'time_step' in [integrator] (CollectivePRK) (did you mean 'timestep'?)"),
    (("type = \"CollectivePRK\"", "type = \"LennardJones\""), "unknown type 'LennardJones'"),
    (("[spins]\nmagnitude = 1.72", "[spins]\nmagnitude = {Fe = 2.2}"),
     "no value for Co"),
    (("repeat = [2, 2, 2]", "repeat = [2, 2, 2]\nrattel = 1"),
     "unknown key 'rattel' in [structure] (did you mean 'rattle'?)"),
    (("repeat = [2, 2, 2]", "repeat = [2, 2, 2]\ncolour = 1"),
     "unknown key 'colour' in [structure] (its keys: file, index,"),
    (("a = 3.54, cubic", "a = 3.54, cubix"),
     "unknown key 'cubix' in [structure] build = bulk(...) (did you mean 'cubic'?)"),
    (("J3 = 1.4885}", "J4 = 1.4885}"),
     "unknown key 'J4' in [[terms]] #2.coupling (BetheSlater) (its keys: J1, J2, J3)"),
    ((", J3 = 1.4885}", "}"), "[[terms]] #2.coupling (BetheSlater) needs 'J3'"),
    (("epsilon = 0.4\n", ""), "[[terms]] #1 (LennardJones) needs 'epsilon'"),
    (("temperature = 100", "temperatur = 100"),
     "unknown key 'temperatur' in [velocities] (did you mean 'temperature'?)"),
    (("temperature = 100\n", ""), "[velocities] needs 'temperature' (K)"),
    (("steps = 12", "steps = 12\ncomm = 1"), "unknown key 'comm' in [integrator]"),
    (("steps = 12", "steps = 12\nspin_damping = 0.1"),
     "unknown key 'spin_damping' in [integrator] (CollectivePRK)"),
    (("interval = 4", "intervall = 4"),
     "unknown key 'intervall' in [output] (did you mean 'interval'?)"),
    (("repeat = [2, 2, 2]", "repeat = [2, -1, 2]"),
     "[structure] repeat must be a positive integer or three of them"),
    (("rattle = 0.03", "rattle = -0.1"),
     "[structure] rattle must be a finite number >= 0"),
    (("cone = 30", "cone = 200"), "[spins] cone must be a half-angle from 0 to 180"),
])
def test_bad_input_is_refused_with_a_message_naming_it(tmp_path, capsys, change, message):
    text = SCENE.format(integrator="CollectivePRK", timestep=0.5, steps=12, interval=4,
                        extra="")
    assert change[0] in text
    path = write_input(tmp_path, text=text.replace(change[0], change[1], 1))
    assert run_cli("run", path, "--no-progress") == 2
    err = _without_compile_notice(capsys.readouterr().err)
    assert err.startswith("ase-spin: error:") and message in err, err
    assert len(err.splitlines()) == 1, err  # one line, no traceback
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.toml"]


def _without_compile_notice(err):
    return "".join(line for line in err.splitlines(keepends=True)
                   if not line.startswith("ase_spin: compiling"))


def test_spin_terms_without_moments_are_refused(tmp_path, capsys):
    text = SCENE.format(integrator="CollectivePRK", timestep=0.5, steps=1, interval=1,
                        extra="")
    start = text.index("[spins]")
    text = text[:start] + text[text.index("[velocities]"):]
    assert run_cli("run", write_input(tmp_path, text=text), "--no-progress") == 2
    assert "no magnetic moments" in capsys.readouterr().err


def test_existing_outputs_are_kept_unless_overwrite(tmp_path, capsys):
    path = write_input(tmp_path, steps=2, interval=1)
    (tmp_path / "md.log").write_text("precious\n")
    assert run_cli("run", path, "--no-progress") == 2
    assert "md.log exist" in capsys.readouterr().err
    assert (tmp_path / "md.log").read_text() == "precious\n"
    assert run_cli("run", path, "--no-progress", "--overwrite") == 0
    assert len(read(tmp_path / "md.traj", ":")) == 3
    assert (tmp_path / "md.log").read_text().startswith("Time[ps]")
    assert run_cli("run", path, "--no-progress", "--steps", "4", "--overwrite") == 0
    assert len(read(tmp_path / "md.traj", ":")) == 5


def test_progress_bar_on_stderr(tmp_path, capsys):
    path = write_input(tmp_path, steps=6, interval=3)
    assert run_cli("run", path) == 0
    err = capsys.readouterr().err
    assert "CollectivePRK" in err and "6/6" in err and "step/s" in err


def test_dyn_run_progress_changes_nothing_but_the_display(capsys):
    """dyn.run(progress=True) takes the same steps to the same state, adds no
    observer (no energies on unlogged steps) and leaves a finished bar."""
    from ase.build import bulk

    def scene():
        atoms = bulk("Co", "fcc", a=3.54, cubic=True).repeat(2)
        atoms.rattle(0.02, seed=1)
        ase_spin.set_spins(atoms, np.random.default_rng(2).normal(size=(32, 3)), 1.72)
        atoms.calc = ase_spin.SpinLatticeCalculator([
            ase_spin.LennardJones(0.4, 2.2742, 4.7, cutoff="shift"),
            ase_spin.Exchange(ase_spin.BetheSlater(0.0446928, 0.003496, 1.4885), rc=4.0)])
        return atoms

    a, b = scene(), scene()
    da = ase_spin.CollectivePRK(a, 0.5 * units.fs)
    db = ase_spin.CollectivePRK(b, 0.5 * units.fs)
    assert da.run(7) is True
    observers = list(db.observers)
    assert db.run(7, progress={"desc": "spins"}) is True
    assert db.observers == observers and db.nsteps == da.nsteps == 7
    np.testing.assert_array_equal(a.positions, b.positions)
    np.testing.assert_array_equal(a.arrays["initial_magmoms"], b.arrays["initial_magmoms"])
    err = capsys.readouterr().err
    assert "spins" in err and "7/7" in err
    with pytest.raises(TypeError, match="progress must be"):
        db.run(1, progress="yes")


def test_plot_makes_a_png_of_the_log(tmp_path, capsys):
    pytest.importorskip("matplotlib")
    from matplotlib.image import imread

    path = write_input(tmp_path, steps=8, interval=2)
    assert run_cli("run", path, "--no-progress") == 0
    # a second run appended to the same log: its header is skipped
    log = tmp_path / "md.log"
    text = log.read_text()
    log.write_text(text + text)
    columns = cli.read_log(log)
    assert len(columns["Time[ps]"]) == 10 and "|M|" in columns and "Ts[K]" in columns
    assert run_cli("plot", log, "-o", tmp_path / "out.png") == 0
    assert "out.png" in capsys.readouterr().out
    image = imread(tmp_path / "out.png")
    assert image.shape[0] > 400 and image.shape[1] > 400
    assert image[..., :3].std() > 0.05  # drawn, not blank
    assert run_cli("plot", log) == 0 and (tmp_path / "md.png").is_file()


def _small_co(seed=1):
    atoms = ase_spin.scenes.fcc_cobalt(2, temperature_K=300.0, seed=seed)
    return atoms


def test_plot_draws_the_langevin_balance_and_ase_logs(tmp_path, capsys):
    """A Langevin log gets the bath's panels (Etot with Ebath; Econs = Etot − Ebath);
    ASE's own MDLogger logs, per atom and with stress, are read and their
    energies drawn (per atom: eV/atom), stress too; every log makes a PNG."""
    pytest.importorskip("matplotlib")
    from ase.md import MDLogger

    atoms = _small_co()
    langevin = tmp_path / "langevin.log"
    with ase_spin.Langevin(atoms, 0.4 * units.fs, 800.0, spin_damping=0.2,
                           friction=0.02 / units.fs, rng=3, logfile=str(langevin),
                           loginterval=2) as dyn:
        dyn.run(6)
    columns = cli.read_log(langevin)
    assert len(columns["Time[ps]"]) == 4
    np.testing.assert_allclose(columns["Econs[eV]"],
                               columns["Etot[eV]"] - columns["Ebath[eV]"], rtol=0, atol=2e-9)
    panels = [(names, unit) for _, names, unit in cli.log_panels(columns)]
    assert panels == [(["Etot[eV]", "Epot[eV]", "Ekin[eV]", "Emag[eV]"], "eV"),
                      (["Etot[eV]", "Ebath[eV]"], "eV"), (["Econs[eV]"], "eV"),
                      (["T[K]", "Ts[K]"], None), (["|M|"], None)]

    atoms = _small_co(2)
    per_atom, stress = tmp_path / "peratom.log", tmp_path / "stress.log"
    with ase_spin.CollectivePRK(atoms, 0.4 * units.fs) as dyn:
        for path, kwargs in ((per_atom, dict(peratom=True)), (stress, dict(stress=True))):
            dyn.attach(dyn.closelater(MDLogger(dyn, atoms, str(path), **kwargs)), interval=2)
        dyn.run(6)
    columns = cli.read_log(per_atom)
    assert len(columns["Time[ps]"]) == 4
    panels = cli.log_panels(columns)
    assert panels[0][1:] == (["Etot/N[eV]", "Epot/N[eV]", "Ekin/N[eV]"], "eV/atom")
    assert [p[1] for p in panels[1:]] == [["T[K]"]]
    np.testing.assert_allclose(columns["Epot/N[eV]"][-1],
                               atoms.get_potential_energy() / len(atoms), atol=1e-4)
    columns = cli.read_log(stress)
    assert len(columns["Time[ps]"]) == 4 and set(cli.STRESS_COLUMNS) <= set(columns)
    assert [p[1] for p in cli.log_panels(columns)][-1] == list(cli.STRESS_COLUMNS)
    np.testing.assert_allclose([columns[c][-1] for c in cli.STRESS_COLUMNS],
                               atoms.get_stress(include_ideal_gas=True) / units.GPa, atol=2e-3)
    for log in (langevin, per_atom, stress):
        assert run_cli("plot", log) == 0 and log.with_suffix(".png").is_file()
    assert "langevin.png" in capsys.readouterr().out


def test_plot_errors(tmp_path, capsys, monkeypatch):
    assert run_cli("plot", tmp_path / "missing.log") == 2
    assert "not found" in capsys.readouterr().err
    (tmp_path / "empty.log").write_text("Time[ps] Etot[eV]\n")
    assert run_cli("plot", tmp_path / "empty.log") == 2
    assert "no log lines" in capsys.readouterr().err
    monkeypatch.setitem(sys.modules, "matplotlib.figure", None)
    (tmp_path / "a.log").write_text("Time[ps] Etot[eV]\n0.0 1.0\n")
    assert run_cli("plot", tmp_path / "a.log") == 2
    assert "needs matplotlib" in capsys.readouterr().err


def test_console_script_is_declared_and_the_module_runs(tmp_path):
    try:
        import tomllib
    except ModuleNotFoundError:  # Python < 3.11
        import tomli as tomllib
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    module, function = project["scripts"]["ase-spin"].split(":")
    assert getattr(__import__(module, fromlist=[function]), function) is main
    assert any(d.startswith("tqdm") for d in project["dependencies"])
    path = write_input(tmp_path, steps=2, interval=1)
    env = {**os.environ, "PYTHONPATH": PACKAGE_PATH}
    # "-m" puts the working folder first on sys.path: run from the input's folder,
    # not the tree (whose copy's kernels this run has not compiled)
    done = subprocess.run([sys.executable, "-m", "ase_spin.app.cli", "run", str(path)],
                          capture_output=True, text=True, env=env, timeout=600, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert "2/2" in done.stderr and "done: 2 steps" in done.stdout
    bad = subprocess.run([sys.executable, "-m", "ase_spin.app.cli", "run", str(path)],
                         capture_output=True, text=True, env=env, timeout=600, cwd=tmp_path)
    assert bad.returncode == 2 and "exist" in bad.stderr


NOTICE_SCRIPT = """
import numba, numpy as np

@numba.njit(cache=True)
def not_ours(x):
    return x + 1.0

import ase_spin
not_ours(1.0)             # a cached kernel of someone else: no notice
import sys
print("-- ours from here --", file=sys.stderr, flush=True)
from ase_spin.md import kernels
a = np.zeros((3, 3))
kernels.same(a, a.copy())  # one of ours, compiled on first use
kernels.same(a, a.copy())
print("ok")
"""


def test_first_use_compilation_is_announced_once_then_cached(tmp_path):
    """With an empty numba cache the first compilation of one of this package's
    kernels prints one line on stderr; the next process finds it cached and
    prints nothing."""
    script = tmp_path / "notice.py"
    script.write_text(NOTICE_SCRIPT)
    env = {**os.environ, "PYTHONPATH": PACKAGE_PATH, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    env.pop("ASE_SPIN_QUIET_COMPILE", None)
    runs = [subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                           env=env, timeout=600) for _ in range(2)]
    for r in runs:
        assert r.returncode == 0 and r.stdout.strip() == "ok", r.stderr
    assert runs[0].stderr.count("compiling numba kernels on first use") == 1, runs[0].stderr
    assert "compiling" in runs[0].stderr.split("-- ours from here --")[1]
    assert str(tmp_path / "cache") in runs[0].stderr
    assert "compiling" not in runs[1].stderr, runs[1].stderr
    assert any(p.suffix == ".nbi" for p in (tmp_path / "cache").rglob("*"))


def test_a_bad_integrator_keyword_leaves_existing_outputs(tmp_path, capsys):
    path = write_input(tmp_path, steps=2, interval=1, extra="ordr = 2")
    (tmp_path / "md.log").write_text("precious\n")
    assert run_cli("run", path, "--no-progress", "--overwrite") == 2
    assert "[integrator] (CollectivePRK)" in capsys.readouterr().err
    assert (tmp_path / "md.log").read_text() == "precious\n"


def test_collinear_moments_from_a_file_need_a_direction(tmp_path, capsys, monkeypatch):
    from ase.build import bulk
    from ase.io import write

    atoms = bulk("Fe", "bcc", a=2.87, cubic=True).repeat(2)  # initial_magmoms (N,) = 2.3
    write(tmp_path / "fe.xyz", atoms, format="extxyz")
    text = textwrap.dedent("""
        [structure]
        file = "fe.xyz"
        [[terms]]
        type = "Exchange"
        coupling = {type = "Cubic", J0 = 0.02, rc = 3.5}
        [integrator]
        timestep = 0.2
        steps = 1
        """)
    assert run_cli("run", write_input(tmp_path, text=text), "--no-progress") == 2
    assert "collinear moments" in capsys.readouterr().err
    monkeypatch.chdir(tmp_path)  # build_scene reads paths from the current folder
    atoms = cli.build_scene(cli.load_input(write_input(
        tmp_path, text=text.replace("[[terms]]", "[spins]\ndirection = [1, 0, 0]\n[[terms]]"))))
    np.testing.assert_allclose(atoms.arrays["initial_magmoms"],
                               np.tile([2.3, 0, 0], (len(atoms), 1)), rtol=1e-14)


def test_an_unstable_run_stops_with_a_message(tmp_path, capsys):
    """A run that stops at its first step leaves no file (they hold nothing but
    the input's state), so the corrected input runs without --overwrite; the
    timestep warning speaks of the input file's key, in fs."""
    path = write_input(tmp_path, timestep=40.0, steps=50, interval=10)
    assert run_cli("run", path, "--no-progress") == 1
    err = _without_compile_notice(capsys.readouterr().err)
    warning, stopped = err.splitlines()
    assert warning.startswith("ase-spin: warning: timestep = 40 (fs) in [integrator]: ")
    assert "keep h·ω below 0.3 rad" in warning and "ase.units" not in warning
    assert stopped.startswith("ase-spin: the run stopped:") and "fs" in stopped
    assert "no step was completed: removed md.traj, md.log, spins.xyz" in stopped
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.toml"]
    write_input(tmp_path, timestep=0.25, steps=2, interval=1)
    assert run_cli("run", path, "--no-progress") == 0
    assert "warning" not in capsys.readouterr().err
    assert len(read(tmp_path / "md.traj", ":")) == 3


LANGEVIN = 'temperature_K = 300\nspin_damping = 0.1\nfriction = {friction}\nrng = 7'


def test_friction_is_in_inverse_fs_like_the_timestep(tmp_path, capsys):
    """[integrator] friction is in 1/fs, as the timestep is in fs: the file's
    friction = 0.05 is the Python API's friction=0.05 / units.fs (the same run,
    bit for bit); a relaxation time 1/friction longer than the run is warned
    about, naming the key and its unit."""
    path = write_input(tmp_path, integrator="Langevin", steps=8, interval=4,
                       extra=LANGEVIN.format(friction=0.05))
    assert run_cli("run", path, "--no-progress") == 0
    err = capsys.readouterr().err
    assert ("ase-spin: warning: friction = 0.05 (1/fs) in [integrator]: the lattice relaxes "
            "towards the bath temperature over 1/friction = 20 fs, longer than the whole run "
            "(8 steps x 0.5 fs = 4 fs)") in err
    frames = read(tmp_path / "md.traj", ":")
    atoms = frames[0].copy()
    atoms.set_momenta(frames[0].get_momenta())
    atoms.calc = ase_spin.SpinLatticeCalculator([
        ase_spin.LennardJones(epsilon=0.4, sigma=2.2742, rc=4.7, cutoff="shift"),
        ase_spin.Exchange(ase_spin.BetheSlater(J1=0.0446928, J2=0.003496, J3=1.4885), rc=4.0),
        ase_spin.Zeeman([0, 0, 20])], skin=0.4)
    # the same outputs at the same steps (the baths' halves merge between outputs)
    dyn = ase_spin.Langevin(atoms, 0.5 * units.fs, 300, spin_damping=0.1,
                            friction=0.05 / units.fs, rng=7, trajectory=tmp_path / "py.traj",
                            logfile=tmp_path / "py.log", loginterval=4)
    dyn.attach(lambda: None, interval=4)  # the xyz frames
    dyn.run(8)
    assert dyn.fr == pytest.approx(0.05 / units.fs, rel=1e-15)
    np.testing.assert_array_equal(atoms.positions, frames[-1].positions)
    np.testing.assert_array_equal(atoms.arrays["initial_magmoms"],
                                  frames[-1].arrays["initial_magmoms"])
    assert (tmp_path / "py.log").read_text() == (tmp_path / "md.log").read_text()


def test_implausible_friction_is_warned_about_in_the_files_units():
    from ase_spin.app.inputs import InputWarning, warn_implausible

    spec = {"integrator": {"type": "Langevin", "timestep": 0.5, "friction": 0.002}}
    with pytest.warns(InputWarning, match=r"friction = 0.002 \(1/fs\) in \[integrator\]: "
                      r"the lattice relaxes .* over 1/friction = 500 fs, longer than the whole "
                      r"run \(400 steps x 0.5 fs = 200 fs\)"):
        warn_implausible(spec, 400)
    spec["integrator"]["friction"] = 5
    with pytest.warns(InputWarning, match=r"friction = 5 \(1/fs\) in \[integrator\]: "
                      r"1/friction = 0.2 fs is shorter than a step \(0.5 fs\)"):
        warn_implausible(spec, 400)
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        spec["integrator"]["friction"] = 0.01  # 100 fs, in a 200 fs run
        warn_implausible(spec, 400)
        spec["integrator"]["friction"] = 0  # no lattice bath
        warn_implausible(spec, 400)


@pytest.mark.parametrize("old, new, message", [
    ("spin_damping = 0.1", "spin_dampng = 0.1",
     "unknown key 'spin_dampng' in [integrator] (Langevin) (did you mean 'spin_damping'?)"),
    ("spin_damping = 0.1\n", "", "[integrator] (Langevin) needs 'spin_damping'"),
    ("friction = 0.01\n", "", "[integrator] (Langevin) needs 'friction' (1/fs)"),
    ("friction = 0.01", "friction = -0.01", "[integrator] friction = -0.01 (1/fs) must be >= 0"),
    ("temperature_K = 300\n", "", "[integrator] (Langevin) needs 'temperature_K'"),
])
def test_integrator_keys_are_checked_before_it_is_built(tmp_path, capsys, old, new, message):
    """A typo or a missing key of [integrator] is reported as the table's key
    (with the nearest known one), not as a Python signature error."""
    text = SCENE.format(integrator="Langevin", timestep=0.5, steps=4, interval=2,
                        extra=LANGEVIN.format(friction=0.01))
    assert old in text
    path = write_input(tmp_path, text=text.replace(old, new, 1))
    assert run_cli("run", path, "--no-progress") == 2
    err = _without_compile_notice(capsys.readouterr().err)
    assert err == f"ase-spin: error: {message}\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.toml"]


EAM_SCENE = """
[structure]
build = {function = "bulk", name = "Cu", crystalstructure = "fcc", a = 3.61, cubic = true}
repeat = [2, 2, 2]
rattle = 0.02

[velocities]
temperature = 100

[[terms]]
type = "EAM"
potential = "FeCo.eam.alloy"
elements = {Cu = "Mn"}

[integrator]
timestep = 1
steps = 2

[output]
interval = 1
"""


def test_a_wrong_eam_element_map_is_refused_before_any_file(tmp_path, capsys):
    """An EAM element map to an element the file lacks: one line naming the
    [[terms]] table, exit status 2, no file written; the corrected input then
    runs without --overwrite."""
    from test_eam import _write_setfl

    _write_setfl(tmp_path / "FeCo.eam.alloy")
    path = tmp_path / "eam.toml"
    path.write_text(EAM_SCENE)
    assert run_cli("run", path, "--no-progress") == 2
    err = _without_compile_notice(capsys.readouterr().err)
    assert err == ("ase-spin: error: [[terms]] #1 (EAM): EAM: the potential FeCo.eam.alloy "
                   "has no element Mn (for the atoms' Cu): it has Fe, Co\n")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["FeCo.eam.alloy", "eam.toml"]
    path.write_text(EAM_SCENE.replace('Cu = "Mn"', 'Cu = "Co"'))
    assert run_cli("run", path, "--no-progress") == 0
    assert len(read(tmp_path / "eam.traj", ":")) == 3
    # an OVITO file of spins, for atoms without any: refused before any file too
    path.write_text(EAM_SCENE.replace('Cu = "Mn"', 'Cu = "Co"').replace(
        "[output]", '[output]\ntrajectory = "b.traj"\nlog = "b.log"\nxyz = "b.xyz"'))
    capsys.readouterr()
    assert run_cli("run", path, "--no-progress") == 2
    err = _without_compile_notice(capsys.readouterr().err)
    assert err.startswith("ase-spin: error: [output] xyz: the atoms carry no (N, 3) "
                          "initial_magmoms")
    assert not list(tmp_path.glob("b.*"))


def test_a_failure_at_step_zero_leaves_no_file(tmp_path, capsys, monkeypatch):
    """Step 0 is evaluated before any file is created: a problem there (here a
    skin of 0, which one pair list for q and q̃ cannot have) is an input error
    with nothing written. And a failure after the files were created, before
    the first step is done (here writing the first xyz frame), removes them."""
    text = SCENE.format(integrator="CollectivePRK", timestep=0.5, steps=4, interval=2,
                        extra="").replace("skin = 0.4", "skin = 0")
    path = write_input(tmp_path, text=text)
    assert run_cli("run", path, "--no-progress") == 2
    err = _without_compile_notice(capsys.readouterr().err)
    assert err.startswith("ase-spin: error: step 0 (CollectivePRK): ") and "skin" in err
    assert len(err.splitlines()) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.toml"]

    def broken(*args, **kwargs):
        raise RuntimeError("disk full")

    write_input(tmp_path, steps=4, interval=2)
    monkeypatch.setattr(cli, "write_ovito_xyz", broken)
    with pytest.raises(RuntimeError, match="disk full"):  # not the input's: a traceback
        run_cli("run", path, "--no-progress")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.toml"]
    monkeypatch.undo()
    assert run_cli("run", path, "--no-progress") == 0
    assert len(read(tmp_path / "md.traj", ":")) == 3


def test_debug_shows_the_traceback(tmp_path, capsys):
    path = write_input(tmp_path, extra="ordr = 2")
    assert run_cli("run", path, "--no-progress", "--debug") == 2
    err = capsys.readouterr().err
    assert "Traceback" in err and err.rstrip().endswith("(did you mean 'order'?)")


def test_compile_command_runs_each_scene_and_writes_nothing(tmp_path, capsys):
    """``ase-spin compile INPUT`` evaluates the scene and takes two steps (the
    kernels it needs end up in numba's cache), says where the cache is, and
    leaves no output file behind."""
    path = write_input(tmp_path, steps=50, interval=1)
    assert run_cli("compile", path, "--jobs", "1") == 0
    out = capsys.readouterr().out
    assert str(path) in out and "CPU:" in out and "done in" in out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.toml"]
    assert run_cli("compile", path, "--jobs", "0") == 2
    assert "--jobs" in capsys.readouterr().err


@pytest.mark.slow
def test_compile_command_fills_an_empty_cache_for_later_runs(tmp_path):
    """After ``ase-spin compile INPUT`` with an empty cache (two processes), a
    run of that scene compiles nothing (no first-use notice)."""
    path = write_input(tmp_path, steps=2, interval=1)
    env = {**os.environ, "PYTHONPATH": PACKAGE_PATH, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    env.pop("ASE_SPIN_QUIET_COMPILE", None)
    first = subprocess.run([sys.executable, "-m", "ase_spin.app.cli", "compile", str(path), str(path),
                            "--jobs", "2"], capture_output=True, text=True, env=env,
                           timeout=1200, cwd=tmp_path)  # (not the tree's copy: "-m")
    assert first.returncode == 0, first.stderr
    assert "kernel(s) compiled" in first.stdout and "compiling numba" not in first.stderr
    run = subprocess.run([sys.executable, "-m", "ase_spin.app.cli", "run", str(path), "--steps", "2",
                          "--no-progress"], capture_output=True, text=True, env=env,
                         timeout=1200, cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    assert "compiling numba kernels" not in run.stderr, run.stderr


def test_conventions_in_the_calculator_table(tmp_path, capsys):
    """[calculator] conventions = "lammps" runs the scene under LAMMPS's
    conventions, as the script's SpinLatticeCalculator(..., conventions=...);
    an unknown name is refused naming the table."""
    text = SCENE.format(integrator="CollectivePRK", timestep=0.5, steps=8, interval=4,
                        extra="").replace("skin = 0.4", 'skin = 0.4\nconventions = "lammps"')
    assert 'conventions = "lammps"' in text
    path = write_input(tmp_path, text=text)
    assert run_cli("run", path, "--no-progress") == 0
    frames = read(tmp_path / "md.traj", ":")
    assert frames[-1].calc.parameters["conventions"] == "lammps"
    atoms = frames[0].copy()
    atoms.set_momenta(frames[0].get_momenta())
    atoms.calc = ase_spin.SpinLatticeCalculator.from_dict(frames[0].calc.parameters)
    assert atoms.calc.hamiltonian.conventions.name == "lammps"
    ase_spin.CollectivePRK(atoms, 0.5 * units.fs).run(8)
    np.testing.assert_array_equal(atoms.arrays["initial_magmoms"],
                                  frames[-1].arrays["initial_magmoms"])
    (tmp_path / "bad").mkdir()
    path = write_input(tmp_path / "bad", text=text.replace('"lammps"', '"LAMMPS"'))
    assert run_cli("run", path, "--no-progress") == 2
    err = capsys.readouterr().err
    assert "[calculator]" in err and "conventions" in err
