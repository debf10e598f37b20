"""Pinned spins (ase_spin.FixSpins, LAMMPS ``fix setforce/spin 0 0 0``): an
ASE constraint kept by copies, slices and trajectories; its spins left to the
bit by every integrator while they act on the others; the equations of motion
with those spins fixed (the ODE reference, energy); a domain wall between
pinned ends. The LAMMPS comparison is in tests/test_lammps_bridge.py."""

import pickle
import subprocess
import sys

import numpy as np
import pytest
from ase import Atoms, units
from ase.constraints import FixAtoms
from ase.io import Trajectory, read, write

import ase_spin
from ase_spin import (CollectivePRK, FixSpins, Langevin, ShellExchange, SpinLatticeCalculator,
                      SuzukiTrotter, UniaxialAnisotropy, get_spins, relax_spins)
from ase_spin.constraints import MARK, lattice_constraints, pinned_spins
from ase_spin.interop.lammps import LammpsIntegratorWarning, write_lammps
from ase_spin.md.ode import reference_solution
from ase_spin.scenes import fcc_cobalt, field_anisotropy_terms, paper_chain

from conftest import general_path_only, spy_fused

PINNED = [0, 5, 7, 20]

#: steps up to 1 fs on purpose (the convergence and energy checks, as in
#: tests/test_md.py), and relax_spins' probe of the fields
pytestmark = pytest.mark.filterwarnings("ignore::ase_spin.md.errors.TimestepWarning")


def _atoms(field=False, pinned=PINNED, **kw):
    """fcc Co, 32 atoms (a tiny system: CollectivePRK's fused step and blocks),
    exchange (and LJ), with a field and an easy axis if ``field`` (several spin
    operators), a 60° spin cone; ``pinned`` spins pinned."""
    atoms = fcc_cobalt(2, cone_deg=60.0, extra=field_anisotropy_terms() if field else (), **kw)
    atoms.set_constraint(FixSpins(pinned))
    return atoms


# -- the constraint ------------------------------------------------------------------


def test_fix_spins_is_an_ase_constraint():
    """Like FixAtoms: indices or a mask, repr, copy, deepcopy by atoms.copy(),
    slicing (index_shuffle; dropped when no pinned atom is in the slice),
    repeat, pickle. It moves no position, force or momentum and removes no
    degree of freedom."""
    atoms = fcc_cobalt(2)
    c = FixSpins(mask=np.arange(len(atoms)) % 5 == 0)
    assert c.index.tolist() == [0, 5, 10, 15, 20, 25, 30]
    assert repr(FixSpins([3, 1])) == "FixSpins(indices=[3, 1])"
    with pytest.raises(ValueError):
        FixSpins([1, 1])
    atoms.set_constraint([FixAtoms([1]), c])
    assert atoms.get_number_of_degrees_of_freedom() == 3 * len(atoms) - 3
    copy = c.copy()
    assert type(copy) is FixSpins and copy.index.tolist() == c.index.tolist()
    assert copy.index is not c.index
    assert atoms.copy().constraints[1].index.tolist() == c.index.tolist()
    assert pickle.loads(pickle.dumps(atoms)).constraints[1].index.tolist() == c.index.tolist()
    assert atoms[4:12].constraints[-1].index.tolist() == [1, 6]  # atoms 5, 10
    assert [type(x) for x in atoms[[1, 2, 3]].constraints] == [FixAtoms]
    assert atoms.repeat((2, 1, 1)).constraints[1].index.tolist() == (
        c.index.tolist() + (c.index + len(atoms)).tolist())
    new = atoms.positions + 0.1
    atoms.set_positions(new)  # (FixAtoms holds atom 1)
    assert np.array_equal(atoms.positions[c.index], new[c.index])
    forces = np.ones((len(atoms), 3))
    c.adjust_forces(atoms, forces)
    c.adjust_momenta(atoms, forces)
    assert np.all(forces == 1.0)
    assert pinned_spins(atoms).nonzero()[0].tolist() == c.index.tolist()
    assert lattice_constraints(atoms) == (atoms.constraints[0],)
    atoms.set_constraint(FixSpins([len(atoms)]))
    with pytest.raises(IndexError, match="FixSpins pins atom 32"):
        pinned_spins(atoms)


def test_files_keep_fix_spins_and_plain_ase_still_reads_them(tmp_path):
    """ASE reads a constraint from a file with its own classes only (a foreign
    name makes the file unreadable): FixSpins is written as an inert
    FixCartesian (no direction fixed) carrying its atoms under "ase_spin",
    which ase_spin reads back as FixSpins. A .traj and a .json file: read
    here, FixSpins and FixAtoms are back; read by Python without ase_spin,
    the file opens, with the inert FixCartesian, which moves nothing."""
    atoms = _atoms()
    atoms.set_constraint([FixAtoms([3]), FixSpins([1, 4])])
    assert atoms.constraints[1].todict()[MARK] == {"name": "FixSpins",
                                                   "kwargs": {"indices": [1, 4]}}
    for name in ("pins.traj", "pins.json"):
        write(tmp_path / name, atoms)
        back = read(tmp_path / name)
        assert [repr(c) for c in back.constraints] == ["FixAtoms(indices=[3])",
                                                       "FixSpins(indices=[1, 4])"]
    script = ("import sys, numpy as np\nfrom ase.io import read\n"
              "atoms = read(sys.argv[1])\n"
              "assert 'ase_spin' not in sys.modules\n"
              "cart = atoms.constraints[1]\n"
              "new = atoms.positions + 0.25\n"
              "atoms.set_positions(new)\n"
              "assert np.array_equal(atoms.positions[cart.index], new[cart.index])\n"
              "print(type(cart).__name__, cart.index.tolist(), cart.get_removed_dof(atoms))\n")
    for name in ("pins.traj", "pins.json"):
        done = subprocess.run([sys.executable, "-c", script, str(tmp_path / name)],
                              capture_output=True, text=True, cwd=tmp_path, timeout=120,
                              check=False)
        assert done.returncode == 0, done.stderr[-2000:]
        assert done.stdout.split("\n")[0] == "FixCartesian [1, 4] 0"


def test_a_run_continued_from_its_trajectory_keeps_the_pins(tmp_path):
    """The integrator's frames carry FixSpins; the last one, given a calculator,
    continues with the same spins pinned (and the same state as a run that was
    never interrupted)."""
    atoms = _atoms()
    dyn = CollectivePRK(atoms, 0.5 * units.fs, trajectory=str(tmp_path / "md.traj"),
                        loginterval=5)
    dyn.run(10)
    with Trajectory(str(tmp_path / "md.traj")) as traj:
        last = traj[-1]
    assert [repr(c) for c in last.constraints] == [f"FixSpins(indices={PINNED})"]
    last.calc = _atoms().calc  # (a calculator of its own: sharing one resyncs both runs)
    held = last.get_initial_magnetic_moments()[PINNED].copy()
    CollectivePRK(last, 0.5 * units.fs).run(10)
    dyn.run(10)
    assert np.array_equal(last.get_initial_magnetic_moments()[PINNED], held)
    assert np.abs(get_spins(last) - get_spins(atoms)).max() < 1e-12


# -- the integrators ------------------------------------------------------------------


INTEGRATORS = {
    "prk": lambda a: CollectivePRK(a, 0.5 * units.fs),
    "prk-order4": lambda a: CollectivePRK(a, 0.5 * units.fs, order=4),
    "prk-order6": lambda a: CollectivePRK(a, 0.5 * units.fs, order=6),
    "prk-jacobi": lambda a: CollectivePRK(a, 0.5 * units.fs, solver="jacobi"),
    "prk-anderson": lambda a: CollectivePRK(a, 0.5 * units.fs, solver="anderson"),
    "prk-frozen": lambda a: CollectivePRK(a, 0.5 * units.fs, lattice="frozen"),
    "splitting": lambda a: SuzukiTrotter(a, 0.5 * units.fs),
    "splitting-exact-order4": lambda a: SuzukiTrotter(a, 0.5 * units.fs, rotation="exact",
                                                      order=4),
    "splitting-frozen": lambda a: SuzukiTrotter(a, 0.5 * units.fs, lattice="frozen"),
    "langevin": lambda a: Langevin(a, 0.5 * units.fs, 600.0, spin_damping=0.2,
                                   friction=0.02 / units.fs, rng=3),
    "langevin-order4-frozen": lambda a: Langevin(a, 0.5 * units.fs, 0.0, spin_damping=0.5,
                                                 friction=0.0, spin_temperature_K=900.0,
                                                 order=4, lattice="frozen", rng=4),
}


@pytest.mark.parametrize("field", [False, True], ids=["exchange", "field-anisotropy"])
@pytest.mark.parametrize("name", INTEGRATORS)
def test_pinned_spins_keep_every_bit_in_every_integrator(name, field):
    """After a run, the pinned spins — the integrator's state and the moments
    on the Atoms — are bit for bit as they were; every other spin moved,
    and the pinned atoms themselves moved on a moving lattice. Exchange alone
    (CollectivePRK: the fused step and blocks of a tiny system; the
    splitting's compiled sweep) and with a field and an easy axis (several
    spin operators: the operators' solver, the splitting's per-site sweeps);
    Langevin with noise and damping on the spins, friction on the lattice."""
    atoms = _atoms(field)
    q0 = atoms.positions.copy()
    m0 = atoms.get_initial_magnetic_moments().copy()
    dyn = INTEGRATORS[name](atoms)
    s0 = dyn._sync().s.copy()
    dyn.run(20)
    m = atoms.get_initial_magnetic_moments()
    assert m[PINNED].tobytes() == m0[PINNED].tobytes()
    assert dyn._state.s[PINNED].tobytes() == s0[PINNED].tobytes()
    free = np.setdiff1d(np.arange(len(atoms)), PINNED)
    assert np.abs(m - m0)[free].max(axis=1).min() > 0.0
    frozen = name.endswith("frozen")
    assert (np.abs(atoms.positions - q0)[PINNED].max(axis=1).min() > 0.0) != frozen
    # the calculator's magnetic forces are −∂E/∂s, pinned spins or not
    B = atoms.calc.get_magnetic_forces(atoms)
    assert np.abs(dyn.get_magnetic_forces() - B).max() < 1e-12
    assert np.abs(B[PINNED]).min() > 0.0


def test_pins_changed_between_runs_are_noticed():
    """A new FixSpins, or its indices edited in place, between two runs: the
    next step pins the new spins and lets the old ones go."""
    atoms = _atoms(pinned=[0])
    dyn = SuzukiTrotter(atoms, 0.5 * units.fs)
    for pinned in ([1], [2]):
        dyn.run(3)
        if pinned == [1]:
            atoms.set_constraint(FixSpins(pinned))
        else:
            atoms.constraints[0].index[:] = pinned
        m0 = atoms.get_initial_magnetic_moments().copy()
        dyn.run(3)
        m = atoms.get_initial_magnetic_moments()
        assert np.array_equal(m[pinned], m0[pinned])
        assert not np.array_equal(m[0], m0[0])


def test_relax_spins_leaves_pinned_spins_and_ignores_their_torques():
    atoms = _atoms(field=True)
    m0 = atoms.get_initial_magnetic_moments().copy()
    relax_spins(atoms, fmax=1e-7)
    assert atoms.get_initial_magnetic_moments()[PINNED].tobytes() == m0[PINNED].tobytes()
    s = get_spins(atoms)
    torque = np.linalg.norm(np.cross(s, atoms.calc.get_magnetic_forces(atoms)), axis=1)
    free = np.setdiff1d(np.arange(len(atoms)), PINNED)
    assert torque[free].max() <= 1e-7 < torque[PINNED].max()


@pytest.mark.parametrize("scene", ["chain", "fcc"])
def test_fused_step_and_blocks_with_pinned_spins_equal_the_general_path(scene, monkeypatch):
    """FixSpins is not a lattice constraint: a small system keeps its compiled
    step and blocks of steps (the compensated sums too), with the same bits as
    the general path."""
    used = spy_fused(monkeypatch)
    runs = []
    for general in (False, True):
        if general:
            general_path_only(monkeypatch)
        if scene == "chain":
            atoms = paper_chain()
            atoms.set_constraint(FixSpins([0, 1, 15]))
            dyn = CollectivePRK(atoms, 2.0**-6, hbar=1.0, precession="spin")
        else:
            atoms = _atoms()
            dyn = CollectivePRK(atoms, 0.5 * units.fs)
        dyn.run(40)
        runs.append((atoms.positions.copy(), atoms.get_momenta(),
                     atoms.get_initial_magnetic_moments().copy()))
    assert used["done"] > 0 and used["blocks"] > 0
    for a, b in zip(*runs):
        assert np.array_equal(a, b)


@pytest.mark.parametrize("order", [2, 4])
def test_pinned_spins_converge_to_the_equations_with_those_spins_fixed(order):
    """ds_i/dt = 0 for the pinned spins, the usual equations for the rest (the
    ODE reference, DOP853): CollectivePRK converges at its order, so the
    pinned spins act on the others through exchange and the lattice forces
    as any spin does."""
    t_end = 10 * units.fs
    ref = reference_solution(_atoms(temperature_K=300), t_end)
    assert np.array_equal(ref[2][PINNED], get_spins(_atoms())[PINNED])
    hs, errors = [], []
    for n in (10, 20, 40):
        atoms = _atoms(temperature_K=300)
        CollectivePRK(atoms, t_end / n, order=order).run(n)
        hs.append(t_end / n)
        errors.append(max(np.abs(atoms.positions - ref[0]).max(),
                          np.abs(atoms.get_momenta() - ref[1]).max(),
                          np.abs(get_spins(atoms) - ref[2]).max()))
    assert errors[-1] > 1e-12
    slope = np.polyfit(np.log(hs), np.log(errors), 1)[0]
    assert abs(slope - order) < 0.2, errors


def test_energy_conserved_with_pinned_spins():
    """NVE with a quarter of the spins pinned (fixed fields for the others):
    CollectivePRK's energy error stays small and falls as h² (the method's
    error, no drift), as without pins (tests/test_md.py); on a frozen lattice
    with exchange alone each of the splitting's rotations keeps the energy, to
    round-off."""
    worst = {}
    for dt in (0.5, 1.0):
        atoms = fcc_cobalt(3, temperature_K=300)
        atoms.set_constraint(FixSpins(np.arange(0, len(atoms), 4)))
        dyn = CollectivePRK(atoms, dt * units.fs)
        e0, ekin = dyn.get_total_energy(), dyn.get_kinetic_energy()
        errors = []
        dyn.attach(lambda dyn=dyn, e0=e0, errors=errors:
                   errors.append(dyn.get_total_energy() - e0), interval=5)
        dyn.run(int(100 / dt))
        worst[dt] = np.abs(errors).max()
    assert worst[0.5] < 5e-4 * ekin
    assert 3.0 < worst[1.0] / worst[0.5] < 5.5
    atoms = _atoms()
    dyn = SuzukiTrotter(atoms, 1.0 * units.fs, lattice="frozen")
    e0 = dyn.get_total_energy()
    dyn.run(200)
    assert abs(dyn.get_total_energy() - e0) < 1e-12 * abs(e0)


def test_spin_temperature_leaves_pinned_spins_out():
    """Pinned spins are no degrees of freedom: LAMMPS's estimator Σ|s×B|² /
    (2 k_B Σ s·B) is taken over the others (the pinned ones here lie against
    their fields: with them it would be another number)."""
    atoms = fcc_cobalt(2, cone_deg=20.0)
    s = get_spins(atoms)
    s[PINNED] = -s[PINNED]
    ase_spin.set_spins(atoms, s, 1.72)
    atoms.set_constraint(FixSpins(PINNED))
    dyn = CollectivePRK(atoms, 0.5 * units.fs)
    B = dyn.get_magnetic_forces()
    free = np.setdiff1d(np.arange(len(atoms)), PINNED)
    sf, Bf = s[free] / np.linalg.norm(s[free], axis=1)[:, None], B[free]
    expected = (np.cross(sf, Bf) ** 2).sum() / (2 * units.kB * np.einsum("ij,ij->", sf, Bf))
    assert dyn.get_spin_temperature() == pytest.approx(expected, rel=1e-12)
    s = s / np.linalg.norm(s, axis=1)[:, None]
    everyone = (np.cross(s, B) ** 2).sum() / (2 * units.kB * np.einsum("ij,ij->", s, B))
    assert abs(everyone / expected - 1.0) > 0.1


# -- a domain wall between pinned ends -------------------------------------------------


def _wall(delta, n=81, J=0.01, a=2.5):
    r"""A chain of n spins along x, nearest-neighbour exchange J and an easy
    axis z with K = J/(2δ²), its end spins pinned up and down, relaxed from a
    wall spread over the whole chain (a tilted rotation plane). Returns
    (k, relaxed spins), k the site minus the chain's centre."""
    x = a * np.arange(n)
    atoms = Atoms(f"Fe{n}", positions=np.column_stack([x, np.zeros(n), np.zeros(n)]),
                  cell=[a * n + 20.0, 20.0, 20.0], pbc=False)
    theta = np.linspace(0.0, np.pi, n)
    ase_spin.set_spins(atoms, np.column_stack([np.sin(theta), 0.3 * np.sin(theta),
                                               np.cos(theta)]), 2.0)
    atoms.set_constraint(FixSpins([0, n - 1]))
    atoms.calc = SpinLatticeCalculator([ShellExchange([(a, J)]),
                                        UniaxialAnisotropy(J / (2 * delta**2), [0, 0, 1])])
    ends = atoms.get_initial_magnetic_moments()[[0, -1]].copy()
    relax_spins(atoms, fmax=1e-9 * J, steps=50_000)
    assert np.array_equal(atoms.get_initial_magnetic_moments()[[0, -1]], ends)
    return np.arange(n) - (n - 1) / 2, get_spins(atoms)


def test_domain_wall_between_pinned_ends_relaxes_to_the_tanh_profile():
    r"""Chain, E = −J Σ s_i·s_{i+1} − K Σ (s_i·z)², ends pinned at ±z. In the
    continuum limit (s_i·s_{i+1} = cos(θ_{i+1} − θ_i) ≈ 1 − a²θ'²/2) the energy
    per length is (Ja/2) θ'² + (K/a) sin²θ, whose wall is
    cos θ = −tanh(x/δ), sin θ = sech(x/δ), δ = a √(J/2K), in one plane (any:
    the wall's azimuth costs nothing here). The lattice equation,
    J[sin(θ_{i+1} − θ_i) − sin(θ_i − θ_{i−1})] = K sin 2θ_i, is the continuum
    one plus J(θ''''/12 − θ'²θ''/2) + O(a⁴): for the tanh wall
    sin 2θ (1/24 − sin²θ/2)/δ⁴ against sin 2θ/(2δ²), a change of relative size
    (a/δ)² that varies across the wall. So the relaxed profile differs from
    tanh by c (a/δ)² with c the same for every δ: at δ = 3 and 6 sites
    the largest difference of s_z times δ² agrees within 10 % (c ≈ 0.08; that
    of |s_⊥| against sech, largest in the tails, stays below 0.12/δ² too),
    and the width of the best tanh is δ(1 − c'/δ²) with c' ≈ 0.155 at both."""
    scaled = {}
    for delta in (3.0, 6.0):
        k, s = _wall(delta)
        err = np.abs(s[:, 2] + np.tanh(k / delta)).max()
        assert err < 0.1 / delta**2
        assert np.abs(np.hypot(s[:, 0], s[:, 1]) - 1.0 / np.cosh(k / delta)).max() < (
            0.12 / delta**2)
        scaled[delta] = err * delta**2
        # one rotation plane: the azimuth of the inner spins is one angle
        phi = np.arctan2(s[1:-1, 1], s[1:-1, 0])
        assert np.ptp(phi) < 1e-3
        # the width of the best tanh: a least-squares fit of δ (the centre fixed by symmetry)
        widths = np.linspace(0.9 * delta, 1.1 * delta, 2001)
        misfit = [np.sum((s[:, 2] + np.tanh(k / w)) ** 2) for w in widths]
        fitted = widths[int(np.argmin(misfit))]
        assert 0.13 < (1.0 - fitted / delta) * delta**2 < 0.18
        assert np.abs(s[:, 2] + s[::-1, 2]).max() < 1e-8  # antisymmetric about the centre
    assert abs(scaled[3.0] / scaled[6.0] - 1.0) < 0.1


# -- LAMMPS export (the deck; the run: tests/test_lammps_bridge.py) -------------------


def test_write_lammps_pins_with_setforce_spin_and_refuses_other_constraints(tmp_path):
    atoms = fcc_cobalt(2, extra=field_anisotropy_terms())
    atoms.calc = SpinLatticeCalculator(atoms.calc.hamiltonian.terms, conventions="lammps")
    atoms.set_constraint(FixSpins([0, 1, 2, 5, 9, 10]))
    dyn = Langevin(atoms, 0.1 * units.fs, 300.0, spin_damping=0.1, friction=0.0)
    with pytest.warns(LammpsIntegratorWarning, match="no collective"):
        files = write_lammps(tmp_path, atoms, dyn, steps=10)
    deck = files.input.read_text().splitlines()
    assert "group pinned_spins id 1:3 6 10:11" in deck
    fix = deck.index("fix pin_spins pinned_spins setforce/spin 0.0 0.0 0.0")
    last_field = max(k for k, line in enumerate(deck)
                     if "precession/spin" in line or "langevin/spin" in line)
    assert last_field < fix < deck.index("fix integrate all nve/spin lattice moving")
    atoms.set_constraint([FixSpins([0]), FixAtoms([1])])
    with pytest.raises(ValueError, match="FixAtoms"):
        write_lammps(tmp_path, atoms, timestep=1.0)
