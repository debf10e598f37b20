"""Reproducibility: what observes a run and how it is cut into runs never
change its trajectory (docs/dynamics.md, "Reproducibility").

For each integrator (CollectivePRK on a moving and on a frozen lattice, and on
the paper's chain, whose small size takes the compiled step and blocks of
steps; SuzukiTrotter; Langevin with a fixed seed, with exchange alone and
with a field and an anisotropy), with the thread count fixed and as the
default leaves it, the positions, momenta and moments after 200 steps are the
same to the bit:

- with and without a trajectory frame, a log line and an observer every 7
  steps, the observer reading every observable and calling the calculator
  (per-atom energies: a calculation the step did not publish);
- as run(200), run(100) + run(100), run(60) + a calculation + run(140), and
  step() 200 times.
"""

from __future__ import annotations

import io

import numba
import numpy as np
import pytest
from ase import units

import ase_spin
from ase_spin import scenes

STEPS = 200
#: a fixed thread count (two where numba has them), and the default ("auto")
FIXED = min(2, numba.config.NUMBA_NUM_THREADS)


def _langevin(**kw):
    return ase_spin.Langevin, dict(timestep=0.2 * units.fs, temperature_K=300.0,
                                   spin_damping=0.05, friction=0.01 / units.fs, rng=42, **kw)


#: name -> () -> (Atoms, integrator class, its keywords)
SCENES = {
    "collective": lambda: (scenes.fcc_cobalt(3), ase_spin.CollectivePRK,
                           dict(timestep=0.1 * units.fs)),
    "collective_frozen": lambda: (scenes.fcc_cobalt(3), ase_spin.CollectivePRK,
                                  dict(timestep=0.5 * units.fs, lattice="frozen")),
    "collective_chain": lambda: (scenes.paper_chain(30), ase_spin.CollectivePRK,
                                 dict(timestep=0.01)),
    "suzuki_trotter": lambda: (scenes.fcc_cobalt(3), ase_spin.SuzukiTrotter,
                               dict(timestep=0.1 * units.fs)),
    "langevin": lambda: (scenes.fcc_cobalt(3), *_langevin()),
    "langevin_terms": lambda: (scenes.fcc_cobalt(3, extra=scenes.field_anisotropy_terms()),
                               *_langevin()),
}


def _final(atoms):
    return (atoms.positions.copy(), atoms.get_momenta(),
            atoms.arrays["initial_magmoms"].copy())


def _plain(dyn, atoms, tmp_path):
    dyn.run(STEPS)


def _chunks(*sizes, calculate=False):
    def run(dyn, atoms, tmp_path):
        for k, n in enumerate(sizes):
            if k and calculate:  # the calculator and the observables between runs
                atoms.get_potential_energy()
                dyn.get_potential_energy()
            dyn.run(n)
    return run


def _steps(dyn, atoms, tmp_path):
    for _ in range(STEPS):  # (as in ASE, step() alone does not count steps)
        dyn.step()


def _observed(dyn, atoms, tmp_path):
    def look():
        dyn.get_energy_terms()
        dyn.get_magnetic_forces()
        dyn.get_spin_temperature()
        dyn.get_temperature()
        if hasattr(dyn, "get_bath_energy"):
            dyn.get_conserved_energy()
        atoms.get_forces()
        atoms.get_potential_energies()  # not published: the calculator computes it

    dyn.attach(look, interval=7)
    dyn.run(STEPS)


#: variant -> (extra integrator keywords(tmp_path), how it runs)
VARIANTS = {
    "trajectory_log_and_observer": (lambda tmp: dict(trajectory=str(tmp / "run.traj"),
                                                     logfile=io.StringIO(), loginterval=7),
                                    _observed),
    "100+100": (lambda tmp: {}, _chunks(100, 100)),
    "60+calculation+140": (lambda tmp: {}, _chunks(60, 140, calculate=True)),
    "step_by_step": (lambda tmp: {}, _steps),
}


def _run(scene, threads, tmp_path, variant=None):
    atoms, cls, kwargs = SCENES[scene]()
    extra, how = VARIANTS[variant] if variant else ((lambda tmp: {}), _plain)
    dyn = cls(atoms, threads=threads, **kwargs, **extra(tmp_path))
    how(dyn, atoms, tmp_path)
    return _final(atoms)


@pytest.mark.filterwarnings("ignore::ase_spin.md.errors.TimestepWarning")
@pytest.mark.parametrize("threads", [FIXED, None], ids=["fixed_threads", "default_threads"])
@pytest.mark.parametrize("scene", list(SCENES))
def test_observers_and_chunks_change_no_bit(scene, threads, tmp_path):
    want = _run(scene, threads, tmp_path)
    for variant in VARIANTS:
        path = tmp_path / variant
        path.mkdir()
        got = _run(scene, threads, path, variant)
        for name, a, b in zip(("positions", "momenta", "moments"), got, want):
            assert np.array_equal(a, b), (
                f"{scene}, {variant}: {name} differ by {np.abs(a - b).max():.3g}")


def test_a_seed_fixes_a_langevin_run_and_another_seed_changes_it(tmp_path):
    """The same seed gives the same run (above, however it is observed); the
    bath energy too, whether or not it was read in between; another seed
    gives another run."""
    def run(seed, read_between):
        atoms, cls, kwargs = SCENES["langevin"]()
        kwargs["rng"] = seed
        dyn = cls(atoms, threads=FIXED, **kwargs)
        if read_between:
            dyn.attach(dyn.get_bath_energy, interval=3)
        dyn.run(60)
        return _final(atoms), dyn.get_bath_energy()

    (a, ea), (b, eb), (c, _) = run(42, False), run(42, True), run(43, False)
    for x, y in zip(a, b):
        assert np.array_equal(x, y)
    assert ea == eb
    assert np.abs(a[2] - c[2]).max() > 1e-3


def test_moments_written_back_keep_the_calculators_evaluator():
    """The moments an integrator writes back, μ_i s_i, have magnitudes off μ_i
    in their last bits: the calculator keeps its evaluator's moments for them
    (a calculation between runs or in an observer then changes nothing the
    integrator holds), and takes a real change of a magnitude."""
    atoms = scenes.fcc_cobalt(2)
    dyn = ase_spin.CollectivePRK(atoms, 0.1 * units.fs)
    dyn.run(5)
    ev = atoms.calc.evaluator
    mu = ev.moments.copy()
    written = np.linalg.norm(atoms.get_initial_magnetic_moments(), axis=1)
    assert not np.array_equal(written, mu) and np.allclose(written, mu, rtol=1e-15, atol=0)
    token = ev.state_token
    atoms.get_potential_energies()
    assert atoms.calc.evaluator is ev and ev.state_token == token
    assert np.array_equal(ev.moments, mu)
    moments = atoms.get_initial_magnetic_moments()
    moments[3] *= 1.0 + 1e-12
    atoms.set_initial_magnetic_moments(moments)
    atoms.get_potential_energy()
    assert ev.state_token != token
    assert ev.moments[3] == pytest.approx(np.linalg.norm(moments[3]), rel=1e-15)
    assert abs(ev.moments[3] - mu[3]) > 1e-13
