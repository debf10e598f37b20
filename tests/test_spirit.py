"""Side by side with Spirit (spirit-code) on a pure-spin Heisenberg ferromagnet: the
conventions of spirit_peer (energy, precession sign and rate, ħ, γ, each
pair once) are those of Spirit's own core. Skipped when ``spirit`` is not installed
(the test extra installs it on Linux x86-64)."""

import numpy as np
import pytest

from ase_spin.md.ode import reference_solution
from spirit_peer import SpiritHeisenberg, run_collective, spirit_available
from conftest import cone_spins

pytestmark = pytest.mark.skipif(not spirit_available(), reason="spirit is not installed")

T_END = 2.0**-4  # ps: the fastest spin of the cone turns by about 5 rad


def rms(a, b):
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    import os

    cwd = os.getcwd()
    os.chdir(tmp_path_factory.mktemp("spirit"))  # no file named STOP here
    try:
        with SpiritHeisenberg(4) as sc:
            yield sc
    finally:
        os.chdir(cwd)


@pytest.fixture(scope="module")
def start():
    return cone_spins(64, np.random.default_rng(3), 40.0)


def test_energy_and_field_conventions(scene, start):
    """E = −Σ_<ij> J s_i·s_j (each pair once, J in meV) in both codes."""
    atoms = scene.atoms(start)
    ours = atoms.calc.get_potential_energy(atoms) * 1e3
    scene.set_spins(start)
    theirs = scene.energy_meV()  # float32
    assert abs(ours - theirs) <= 2e-7 * abs(ours)
    # and by hand: the three bonds of each site along +x, +y, +z (periodic)
    s = start.reshape(4, 4, 4, 3)  # Spirit's order: x fastest, so the array is [z, y, x]
    by_hand = -scene.J_meV * sum(np.sum(s * np.roll(s, -1, axis=ax)) for ax in range(3))
    assert ours == pytest.approx(by_hand, rel=1e-12)


def test_same_trajectory_as_dt_to_zero(scene, start):
    """Spirit's RK4 and CollectivePRK order 4 both converge at fourth order to one
    DOP853 solution of ds/dt = −(γ/μB)(1/μ) s × B: the equations are the same."""
    atoms = scene.atoms(start)
    o = scene.integrator_options()
    _, _, ref = reference_solution(atoms, T_END * 1000.0 * __import__("ase").units.fs,
                                   hbar=o["hbar"], precession="moment",
                                   gyromagnetic="moment", g=o["g"], frozen_lattice=True)
    moved = rms(start, ref)
    assert moved > 0.2  # the dynamics is not trivial
    errors = []
    for k in (9, 10):
        dt = 2.0**-k
        steps = int(round(T_END / dt))
        theirs, _ = scene.run("RK4", dt, steps, start)
        ours, _, _ = run_collective(scene, start, 4, dt, steps, threads=1)
        errors.append((rms(theirs, ref), rms(ours, ref)))
    (sp0, pr0), (sp1, pr1) = errors
    assert 10 < sp0 / sp1 < 24 and 10 < pr0 / pr1 < 24  # 16: fourth order, both
    assert sp1 < 1e-5 * moved and pr1 < 1e-5 * moved
    # the wrong precession sense is an O(1) difference: the check above can fail
    flipped = scene.atoms(start)
    _, _, wrong = reference_solution(flipped, T_END * 1000.0 * __import__("ase").units.fs,
                                     hbar=o["hbar"], precession="spin",
                                     gyromagnetic="moment", g=o["g"], frozen_lattice=True)
    assert rms(wrong, ref) > 0.1 * moved


def test_second_order_solvers_converge_to_the_same_trajectory(scene, start):
    """Spirit's Heun, Depondt and SIB solvers (second order) on the same equation."""
    steps = {k: int(round(T_END / 2.0**-k)) for k in (11, 12)}
    ours, _, _ = run_collective(scene, start, 6, 2.0**-10, 64, threads=1)  # ≈ 1e-9 accurate
    for solver in ("Heun", "Depondt", "SIB"):
        e = [rms(scene.run(solver, 2.0**-k, steps[k], start)[0], ours) for k in (11, 12)]
        assert 3 < e[0] / e[1] < 5.5, (solver, e)  # 4: second order
        assert e[1] < 1e-3, (solver, e)


def test_bad_input(scene, start):
    with pytest.raises(ValueError, match="single precision"):
        scene.start("RK4", 1e-3)
    with pytest.raises(ValueError, match="solver must be one of"):
        scene.start("VP", 2.0**-10)
    with pytest.raises(ValueError, match="shape"):
        scene.set_spins(start[:10])
    with pytest.raises(ValueError, match="n must be"):
        SpiritHeisenberg(2)
