"""Trajectories: never truncated by accident, restartable, recoverable after a
crash mid-write."""

import numpy as np
import pytest
from ase import units
from ase.build import bulk
from ase.constraints import FixAtoms
from ase.io import Trajectory, read

import ase_spin
from ase_spin import CollectivePRK, SuzukiTrotter
from ase_spin.io.trajectories import complete_frames, recover_trajectory

from conftest import CO_BS, CO_LJ


def scene():
    a = bulk("Co", "fcc", a=3.54, cubic=True)
    a.rattle(0.05, seed=2)
    ase_spin.set_spins(a, np.random.default_rng(2).normal(size=(4, 3)) + [0, 0, 2], 1.7)
    a.set_momenta(np.random.default_rng(3).normal(size=(4, 3)) * 0.2)
    a.set_constraint(FixAtoms([3]))
    a.calc = ase_spin.SpinLatticeCalculator([
        ase_spin.LennardJones(**CO_LJ, cutoff="shift"),
        ase_spin.Exchange(ase_spin.BetheSlater(*CO_BS), rc=4.0)])
    return a


def same_frames(a, b):
    assert len(a) == len(b)
    for x, y in zip(a, b):
        for name in ("positions", "momenta", "initial_magmoms"):
            np.testing.assert_array_equal(x.arrays[name], y.arrays[name])
        np.testing.assert_array_equal(x.cell.array, y.cell.array)
        assert [c.todict() for c in x.constraints] == [c.todict() for c in y.constraints]


@pytest.mark.parametrize("cls", [CollectivePRK, SuzukiTrotter])
def test_existing_trajectory_is_never_overwritten(cls, tmp_path):
    path = tmp_path / "md.traj"
    a = scene()
    cls(a, 0.2 * units.fs, trajectory=str(path)).run(3)
    before = path.read_bytes()
    atoms_before = a.copy()
    with pytest.raises(FileExistsError, match="append_trajectory=True"):
        cls(a, 0.2 * units.fs, trajectory=str(path))
    with pytest.raises(FileExistsError):
        cls(a, 0.2 * units.fs, trajectory=path)  # a Path too
    assert path.read_bytes() == before
    assert a == atoms_before
    # an empty file holds nothing to lose
    empty = tmp_path / "empty.traj"
    empty.touch()
    cls(a, 0.2 * units.fs, trajectory=str(empty)).run(1)
    assert len(read(empty, ":")) == 2


def test_restart_appends(tmp_path):
    path = tmp_path / "md.traj"
    a = scene()
    CollectivePRK(a, 0.2 * units.fs, trajectory=str(path)).run(4)
    b = read(path, -1)
    b.calc = scene().calc
    CollectivePRK(b, 0.2 * units.fs, trajectory=str(path), append_trajectory=True).run(4)
    frames = read(path, ":")
    assert len(frames) == 10  # 0..4, then the restart's first frame (= frame 4) .. 8
    ref = scene()
    CollectivePRK(ref, 0.2 * units.fs).run(8)
    np.testing.assert_allclose(frames[-1].positions, ref.positions, atol=1e-12)
    np.testing.assert_allclose(frames[-1].arrays["initial_magmoms"],
                               ref.arrays["initial_magmoms"], atol=1e-12)


def _trajectory(path, n=4):
    a = scene()
    CollectivePRK(a, 0.2 * units.fs, trajectory=str(path)).run(n - 1)
    return read(path, ":")


def test_append_to_a_truncated_file_is_a_clear_error(tmp_path):
    path = tmp_path / "md.traj"
    _trajectory(path)
    data = path.read_bytes()
    path.write_bytes(data[:-37])
    with pytest.raises(ValueError, match="recover_trajectory"):
        CollectivePRK(scene(), 0.2 * units.fs, trajectory=str(path), append_trajectory=True)
    assert path.read_bytes() == data[:-37]


def test_recovery_at_every_byte_of_the_last_frame(tmp_path):
    path = tmp_path / "md.traj"
    frames = _trajectory(path, n=4)
    data = path.read_bytes()
    # where the last frame starts: the end of the previous frame's JSON block
    cut_file = tmp_path / "cut.traj"
    ends = []
    for k in range(1, len(frames) + 1):
        with Trajectory(path) as t:
            x = int(t.backend._offsets[k - 1])
        ends.append(x + 8 + int.from_bytes(data[x:x + 8], "little"))
    start = ends[-2]
    out = tmp_path / "rec.traj"
    checked = 0
    for cut in list(range(start, len(data) + 1)) + [ends[0] + 5, ends[1] - 3]:
        cut_file.write_bytes(data[:cut])
        expected = sum(end <= cut for end in ends)
        n = recover_trajectory(cut_file, out, overwrite=True)
        assert n == expected
        if cut % 53 == 0 or cut in (start, len(data)) or expected < len(frames) - 1:
            same_frames(read(out, ":"), frames[:expected])
            checked += 1
    assert checked > 10


def test_recovered_file_can_be_continued(tmp_path):
    path = tmp_path / "md.traj"
    frames = _trajectory(path, n=5)
    data = path.read_bytes()
    path.write_bytes(data[:-100])
    assert complete_frames(path) == 4
    out = tmp_path / "md.recovered.traj"
    assert recover_trajectory(path) == 4 and out.exists()
    with pytest.raises(FileExistsError):
        recover_trajectory(path)
    b = read(out, -1)
    b.calc = scene().calc
    CollectivePRK(b, 0.2 * units.fs, trajectory=str(out), append_trajectory=True).run(2)
    again = read(out, ":")
    assert len(again) == 7
    same_frames(again[:4], frames[:4])


def test_nothing_to_recover(tmp_path):
    path = tmp_path / "bad.traj"
    path.write_bytes(b"- of Ulm" + b" " * 30)
    with pytest.raises(ValueError, match="header|no complete frame"):
        recover_trajectory(path)
    path.write_bytes(b"not a trajectory at all" * 10)
    with pytest.raises(ValueError, match="not an ASE trajectory"):
        recover_trajectory(path)


@pytest.mark.parametrize("cls", [CollectivePRK, ase_spin.Langevin])
def test_attached_trajectory_frames_carry_what_trajectory_frames_carry(cls, tmp_path):
    """Frames of an attached ``Trajectory(...).write`` (and of ``ase.io.write``
    of extxyz in an observer) hold the same calculator results and the same
    magnetic forces, magnetic energy and energy terms in ``info`` as the
    integrator's own ``trajectory=`` frames, values equal; a user's own info
    key survives, and the Atoms keep their own info."""
    from ase.io import write

    a = scene()
    a.info["mine"] = 1
    kwargs = (dict(temperature_K=300.0, spin_damping=0.1, friction=0.01 / units.fs, rng=4)
              if cls is ase_spin.Langevin else {})
    xyz = tmp_path / "md.xyz"
    with Trajectory(str(tmp_path / "attached.traj"), "w", a) as traj:
        dyn = cls(a, 0.2 * units.fs, trajectory=str(tmp_path / "own.traj"), loginterval=2,
                  **kwargs)
        dyn.attach(traj.write, interval=2)
        dyn.attach(lambda: write(xyz, a, append=True), interval=2)
        dyn.run(4)
    own = read(tmp_path / "own.traj", ":")
    attached = read(tmp_path / "attached.traj", ":")
    texts = read(xyz, ":")
    assert len(own) == len(attached) == len(texts) == 3
    for x, y, z in zip(own, attached, texts):
        assert set(x.calc.results) == set(y.calc.results) >= {"energy", "forces", "stress",
                                                              "magmoms", "magmom"}
        for key, value in x.calc.results.items():
            np.testing.assert_array_equal(y.calc.results[key], value)
        for key in ("magnetic_forces", "magnetic_energy", "energy_terms"):
            assert key in x.info and key in y.info and key in z.info
        np.testing.assert_array_equal(y.info["magnetic_forces"], x.info["magnetic_forces"])
        np.testing.assert_allclose(z.info["magnetic_forces"], x.info["magnetic_forces"],
                                   rtol=1e-12, atol=1e-15)
        assert y.info["magnetic_energy"] == x.info["magnetic_energy"]
        assert y.info["energy_terms"] == x.info["energy_terms"]
        assert x.info["mine"] == y.info["mine"] == 1
        # B of the frame's own state
        b = x.copy()
        b.calc = ase_spin.SpinLatticeCalculator(a.calc.hamiltonian.terms)
        np.testing.assert_allclose(x.info["magnetic_forces"], b.calc.get_magnetic_forces(b),
                                   rtol=0, atol=1e-12)
    assert a.info == {"mine": 1}
