"""Data never runs code nor writes where it was not asked to (issue 37):
``from_dict`` builds only an allow-list, ``write_lammps`` refuses file names
a deck or a shell would read as commands or paths, input files of
``ase-spin run`` build only their schema, and no output destroys an input or
another run's output. docs/errors.md, "What data may run"."""

import json
import os
import shlex
import socket
import subprocess
import sys

import pytest
from ase import units
from ase.build import bulk
from ase.calculators.emt import EMT

import ase_spin
from ase_spin import (BetheSlater, Exchange, LennardJones, SpinLatticeCalculator, Zeeman,
                      write_lammps)
from ase_spin.app import cli
from ase_spin.app.inputs import check_input, load_input
from test_cli import EAM_SCENE, SCENE, _without_compile_notice, run_cli, write_input
from test_eam import _write_setfl

# -- from_dict: an allow-list ---------------------------------------------------------


def _record(*terms):
    """A calculator's record as a trajectory keeps it (through JSON)."""
    return json.loads(json.dumps(SpinLatticeCalculator(list(terms)).todict()))


def test_from_dict_imports_no_module_the_data_names(tmp_path, monkeypatch):
    """Importing a module runs it: a class of a module named in the data is
    refused by name, and the module is never imported."""
    marker = tmp_path / "ran"
    (tmp_path / "evil_terms_module.py").write_text(
        f"open({str(marker)!r}, 'w').write('imported')\nclass Thing:\n    pass\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    for path in ("evil_terms_module:Thing", "os:system", "subprocess:Popen",
                 "ase_spin.app.cli:main"):
        with pytest.raises(ValueError, match=f"refused to build the term '{path}'"):
            SpinLatticeCalculator.from_dict({"terms": [{"__class__": path, "args": {}}]})
    assert not marker.exists()
    assert "evil_terms_module" not in sys.modules


def test_from_dict_builds_ase_calculators_only_when_the_caller_allows_them(tmp_path):
    """A calculator's parameters can name the program it runs (ASE's LAMMPS
    calculator: a shell command): never built from data alone."""
    crafted = {"terms": [{"__class__": "ase_spin.terms.ase_calculator:CalculatorTerm",
                          "args": {"calculator": {
                              "__calculator__": "ase.calculators.lammpsrun:LAMMPS",
                              "parameters": {"command": f"touch {tmp_path / 'X'}"}}}}]}
    with pytest.raises(ValueError, match="refused to build the ASE calculator "
                                         "'ase.calculators.lammpsrun:LAMMPS'.*allow=\\[LAMMPS\\]"):
        SpinLatticeCalculator.from_dict(crafted)
    assert not (tmp_path / "X").exists()

    data = _record(EMT(), Exchange(BetheSlater(0.0446928, 0.003496, 1.4885), rc=4.0),
                   Zeeman(1.0, [0, 0, 1]))
    with pytest.raises(ValueError, match="'ase.calculators.emt:EMT'"):
        SpinLatticeCalculator.from_dict(data)
    atoms = bulk("Ni", "fcc", a=3.52, cubic=True)
    ase_spin.set_spins(atoms, [0, 0, 1], 0.6)
    atoms.calc = SpinLatticeCalculator([EMT(), Exchange(BetheSlater(0.0446928, 0.003496,
                                                                    1.4885), rc=4.0),
                                        Zeeman(1.0, [0, 0, 1])])
    e = atoms.get_potential_energy()
    seen = []

    def factory(**parameters):
        seen.append(parameters)
        return EMT(**parameters)

    for allow in ([EMT], {"EMT": factory}, {"ase.calculators.emt:EMT": factory}):
        again = atoms.copy()
        again.calc = SpinLatticeCalculator.from_dict(data, allow=allow)
        assert again.get_potential_energy() == e
    assert len(seen) == 2
    # the caller's mapping decides, whatever module the data names
    forged = json.loads(json.dumps(data).replace("ase.calculators.emt:EMT", "os:EMT"))
    assert SpinLatticeCalculator.from_dict(forged, allow={"EMT": factory})
    with pytest.raises(TypeError, match="allow= takes classes"):
        SpinLatticeCalculator.from_dict(data, allow=["EMT"])


@pytest.mark.parametrize("data, error, message", [
    ({"terms": "x"}, TypeError, "'terms' must be a list"),
    ({"terms": [{"__class__": 3}]}, TypeError, "must be a 'module:Class' string"),
    ({"terms": [{"__class__": "ase_spin.terms.zeeman:Zeeman", "args": [1]}]}, ValueError,
     "'args' must be a mapping"),
    ({"terms": [{"__class__": "ase_spin.terms.lennard_jones:LennardJones",
                 "args": {"epsilon": {"__mapping__": 5}, "sigma": 2.2, "rc": 4.7}}]},
     ValueError, "a list of \\[key, value\\] pairs"),
])
def test_from_dict_refuses_malformed_data_by_name(data, error, message):
    with pytest.raises(error, match=message):
        SpinLatticeCalculator.from_dict(data)


# -- write_lammps: names the deck can hold ------------------------------------------


def _cobalt():
    atoms = bulk("Co", "fcc", a=3.54, cubic=True)
    ase_spin.set_spins(atoms, [0, 0, 1], 1.7)
    atoms.calc = SpinLatticeCalculator(
        [LennardJones(0.4, 2.2742, 4.7, cutoff="shift"),
         Exchange(BetheSlater(0.0446928, 0.003496, 1.4885), rc=4.0)], conventions="lammps")
    return atoms


@pytest.mark.parametrize("field, name, character", [
    ("input_name", "in.spin\nshell touch X", "'\\n'"),
    ("energy_name", "e.spin\rshell rm -rf ~", "'\\r'"),
    ("dump_name", "dump spin", "' '"),
    ("data_name", "../../x.data", "'/'"),
    ("data_name", "..", "not a file name"),
    ("dump_name", "dump.$x", "'$'"),
    ("energy_name", "e.spin&", "'&'"),
    ("input_name", "in#x", "'#'"),
    ("dump_name", "d'x", "\"'\""),
    ("dump_name", 'd"x', "'\"'"),
    ("dump_name", "d`touch X`", "'`'"),
    ("dump_name", "dump.*.spin", "'*'"),
    ("dump_name", "dump.%.spin", "'%'"),
])
def test_deck_file_names_are_refused_before_anything_is_written(tmp_path, field, name,
                                                                character):
    folder = tmp_path / "run"
    with pytest.raises(ValueError) as info:
        write_lammps(folder, _cobalt(), timestep=0.1 * units.fs, **{field: name})
    message = str(info.value)
    assert message.startswith(f"write_lammps: {field} {name!r}") and character in message
    assert "nothing was written" in message
    assert not folder.exists() and list(tmp_path.iterdir()) == []


def test_deck_names_must_differ_and_potential_files_stay_beside_the_deck(tmp_path):
    with pytest.raises(ValueError, match="data_name and input_name are both 'in.spin'"):
        write_lammps(tmp_path / "a", _cobalt(), timestep=units.fs, data_name="in.spin")
    iron = bulk("Fe", "bcc", a=2.8665, cubic=True)
    ase_spin.set_spins(iron, [0, 0, 1], 2.2)
    for bad in ("Fe$Co.eam.alloy", "Fe Co.eam.alloy"):
        (tmp_path / "p").mkdir(exist_ok=True)
        potential = _write_setfl(tmp_path / "p" / bad)
        iron.calc = SpinLatticeCalculator([ase_spin.EAM(potential)])
        with pytest.raises(ValueError, match="the potential file .*: its name"):
            write_lammps(tmp_path / "b", iron, timestep=units.fs)
    potential = _write_setfl(tmp_path / "p" / "atoms.data")
    iron.calc = SpinLatticeCalculator([ase_spin.EAM(potential, format="setfl")])
    with pytest.raises(ValueError, match="would be copied onto the data_name 'atoms.data'"):
        write_lammps(tmp_path / "b", iron, timestep=units.fs)
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()
    # the deck written in the potential's own folder: no copy onto itself
    potential = _write_setfl(tmp_path / "p" / "FeCo.eam.alloy")
    iron.calc = SpinLatticeCalculator([ase_spin.EAM(potential)])
    files = write_lammps(tmp_path / "p", iron, timestep=units.fs)
    assert "pair_coeff * * FeCo.eam.alloy Fe" in files.input.read_text()


def test_command_quotes_the_directory_for_the_shell(tmp_path):
    folder = tmp_path / "run; touch X; echo x"
    files = write_lammps(folder, _cobalt(), timestep=0.1 * units.fs, input_name="in.spin")
    line = files.command(ranks=4)
    assert shlex.split(line) == ["cd", str(folder), "&&", "mpirun", "-n", "4", "lmp", "-in",
                                 "in.spin"]
    # run by a shell (lmp replaced by a harmless command): no X is made anywhere
    subprocess.run(line.replace("mpirun -n 4 lmp -in", "cat"), shell=True, cwd=tmp_path,
                   check=True, capture_output=True)
    assert not (tmp_path / "X").exists() and not (folder / "X").exists()
    for ranks in (0, "4; touch X", 2.5, True):
        with pytest.raises(ValueError, match="ranks must be an integer >= 1"):
            files.command(ranks)


# -- ase-spin run: the schema, and outputs that destroy nothing ----------------------


def _scene(**changes):
    text = SCENE.format(integrator="CollectivePRK", timestep=0.5, steps=2, interval=1,
                        extra="")
    for old, new in changes.items():
        assert old in text, old
        text = text.replace(old, new, 1)
    return text


def _refused(tmp_path, capsys, text, message, *options, files=("scene.toml",)):
    path = write_input(tmp_path, text=text)
    assert run_cli("run", path, "--no-progress", *options) == 2
    err = _without_compile_notice(capsys.readouterr().err)
    assert err.startswith("ase-spin: error:") and message in err, err
    assert len(err.splitlines()) == 1, err
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(files)


LOGGER = ('g = {type = "SpinMDLogger", dyn = {type = "LennardJones", epsilon = 0.4, '
          'sigma = 2.2, rc = 4.7}, logfile = "pwned.txt"}')


@pytest.mark.parametrize("old, new, message", [
    # a logger as a field value opened (created, truncated) the file it names
    ("field = [0, 0, 20]", f"field = [0, 0, 20]\n{LOGGER}",
     ("[[terms]] #3.g: type 'SpinMDLogger' is not built here: a table inside a [[terms]] "
      "table builds a coupling")),
    ('coupling = {type = "BetheSlater", J1 = 0.0446928, J2 = 0.003496, J3 = 1.4885}',
     'coupling = {"Co-Co" = {type = "SpinLatticeCalculator", terms = []}}',
     "[[terms]] #2.coupling.Co-Co: type 'SpinLatticeCalculator' is not built here"),
    ("steps = 2", 'steps = 2\ncomposition = {type = "BetheSlater", J1 = 1, J2 = 1, J3 = 1}',
     ("[integrator].composition: a table with a type builds a coupling inside a [[terms]] "
      "table only")),
    ("steps = 2", "steps = 2\norder = true",
     "[integrator] (CollectivePRK) order = true: true/false where a value is expected"),
    ("rc = 4.0", "rc = true", "[[terms]] #2 (Exchange) rc = true: true/false"),
    ("J1 = 0.0446928", "J1 = true", "[[terms]] #2.coupling (BetheSlater) J1 = true"),
    ("field = [0, 0, 20]", "field = [0, 0, true]",
     "[[terms]] #3 (Zeeman) field = [0, 0, true]: true/false"),
    ("direction = [0, 0, 1]", "direction = [0, 0, true]",
     '[spins] direction must be three numbers or "random", got [0, 0, true]'),
    ("direction = [0, 0, 1]", "direction = [0, 1]", "[spins] direction must be three numbers"),
    ("repeat = [2, 2, 2]", "repeat = [2, true, 2]",
     "[structure] repeat must be a positive integer or three of them, got [2, true, 2]"),
    ("a = 3.54", "a = true", "[structure] build = bulk(...) a = true: true/false"),
    ("magnitude = 1.72", "magnitude = {Co = 1.72, Fe = 2.2}",
     "[spins] magnitude has a value for Fe, which the structure does not have"),
    ("magnitude = 1.72", "magnitude = {Co = true}", "[spins] magnitude Co must be a number"),
])
def test_input_files_build_only_their_schema(tmp_path, capsys, old, new, message):
    _refused(tmp_path, capsys, _scene(**{old: new}), message)


def test_flags_still_take_true_and_false(tmp_path):
    text = _scene(**{"rc = 4.0": "rc = 4.0\noffset = true"})
    spec = load_input(write_input(tmp_path, text=text))
    check_input(spec)
    assert spec["terms"][1]["offset"] is True


@pytest.mark.parametrize("old, new, message", [
    ('trajectory = "md.traj"', 'trajectory = "scene.toml"',
     ("[output] trajectory 'scene.toml' is the input file, which the run reads: writing it "
      "would destroy it")),
    ('log = "md.log"', 'log = "./sub/../scene.toml"',
     "[output] log './sub/../scene.toml' is the input file"),
    ('xyz = "spins.xyz"', 'xyz = "start.xyz"',
     "[output] xyz 'start.xyz' is the structure file ([structure] file)"),
    ('log = "md.log"', 'log = "md.traj"',
     "[output] trajectory and log are both 'md.traj': their contents would be interleaved"),
    ('log = "md.log"', 'log = "sub"', "[output] log 'sub' is a folder"),
    ('log = "md.log"', 'log = "nowhere/md.log"', "the folder 'nowhere' does not exist"),
])
def test_outputs_never_destroy_an_input_even_with_overwrite(tmp_path, capsys, old, new,
                                                            message):
    from ase.io import write

    write(tmp_path / "start.xyz", bulk("Co", "fcc", a=3.54, cubic=True).repeat(2))
    structure = bytes((tmp_path / "start.xyz").read_bytes())
    (tmp_path / "sub").mkdir()
    build = ('build = {function = "bulk", name = "Co", crystalstructure = "fcc", a = 3.54, '
             'cubic = true}\nrepeat = [2, 2, 2]')
    text = _scene(**{build: 'file = "start.xyz"', old: new,
                     "interval = 1": "interval = 1\noverwrite = true"})
    _refused(tmp_path, capsys, text, message, "--overwrite",
             files=["scene.toml", "start.xyz", "sub"])
    assert (tmp_path / "scene.toml").read_text() == text
    assert (tmp_path / "start.xyz").read_bytes() == structure


def test_an_output_is_never_a_potential_the_terms_read(tmp_path, capsys):
    _write_setfl(tmp_path / "FeCo.eam.alloy")
    data = (tmp_path / "FeCo.eam.alloy").read_bytes()
    path = tmp_path / "eam.toml"
    path.write_text(EAM_SCENE.replace('Cu = "Mn"', 'Cu = "Co"').replace(
        "[output]", '[output]\ntrajectory = "FeCo.eam.alloy"'))
    assert run_cli("run", path, "--no-progress", "--overwrite") == 2
    err = _without_compile_notice(capsys.readouterr().err)
    assert ("[output] trajectory 'FeCo.eam.alloy' is a file the terms read ([[terms]] "
            "#1.potential)") in err
    assert (tmp_path / "FeCo.eam.alloy").read_bytes() == data
    assert sorted(p.name for p in tmp_path.iterdir()) == ["FeCo.eam.alloy", "eam.toml"]


def _dead_pid():
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def test_a_second_run_on_the_same_outputs_is_refused(tmp_path, capsys):
    """A run holds <output>.lock while it writes: another run naming the same
    files (with --overwrite too) is refused before it touches them; a lock
    of a process that is gone from this machine is taken over."""
    path = write_input(tmp_path, steps=2, interval=1)
    lock = tmp_path / "md.traj.lock"
    host = socket.gethostname()
    for holder in (f"{os.getppid()} {host}", "4242 another-node", ""):
        lock.write_text(holder)
        for options in ((), ("--overwrite",)):
            assert run_cli("run", path, "--no-progress", *options) == 2
            err = _without_compile_notice(capsys.readouterr().err)
            assert err.startswith("ase-spin: error: [output] trajectory 'md.traj' is being "
                                  "written by ")
            assert str(lock) in err and len(err.splitlines()) == 1
            assert sorted(p.name for p in tmp_path.iterdir()) == ["md.traj.lock", "scene.toml"]
            assert lock.read_text() == holder
    # a run in progress: its outputs and lock are kept from a second run with --overwrite
    (tmp_path / "md.traj").write_bytes(b"frames of a run in progress")
    lock.write_text(f"{os.getppid()} {host}")
    assert run_cli("run", path, "--no-progress", "--overwrite") == 2
    assert (tmp_path / "md.traj").read_bytes() == b"frames of a run in progress"
    (tmp_path / "md.traj").unlink()
    # a killed run's lock on this machine
    lock.write_text(f"{_dead_pid()} {host}")
    assert run_cli("run", path, "--no-progress") == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["md.log", "md.traj", "scene.toml",
                                                          "spins.xyz"]


def test_locks_are_released_however_the_run_ends(tmp_path, capsys, monkeypatch):
    path = write_input(tmp_path, steps=2, interval=1)
    seen = []

    def interrupted(*args, **kwargs):
        seen.append(sorted(p.name for p in tmp_path.glob("*.lock")))
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "write_ovito_xyz", interrupted)
    assert run_cli("run", path, "--no-progress") == 130
    assert seen == [["md.log.lock", "md.traj.lock", "spins.xyz.lock"]]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.toml"]


def test_overwrite_in_the_file_replaces_outputs_once_they_are_locked(tmp_path):
    text = _scene(**{"interval = 1": "interval = 1\noverwrite = true"})
    path = write_input(tmp_path, text=text)
    (tmp_path / "md.log").write_text("an earlier run\n")
    assert run_cli("run", path, "--no-progress") == 0
    assert (tmp_path / "md.log").read_text().startswith("Time[ps]")
    assert not list(tmp_path.glob("*.lock"))
