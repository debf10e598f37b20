"""SuzukiTrotter, the LAMMPS-style splitting baseline: convergence, invariants."""

import numpy as np
import pytest
from ase import units

import ase_spin
from ase_spin import SuzukiTrotter
from ase_spin.md.ode import reference_solution
from ase_spin.scenes import fcc_cobalt, paper_chain

from test_md import fitted_order, state, state_error


@pytest.fixture(scope="module")
def chain_reference():
    return reference_solution(paper_chain(), 1.0, hbar=1.0, precession="spin")


@pytest.mark.parametrize("rotation", ["cayley", "exact"])
@pytest.mark.parametrize("order, exponents", [(2, (4, 5, 6, 7)), (4, (4, 5, 6))])
def test_chain_converges_to_ode_solution(chain_reference, rotation, order, exponents):
    """On the paper's chain (cubic J, which LAMMPS has no pair style for)."""
    hs, errors = [], []
    for e in exponents:
        atoms = paper_chain()
        SuzukiTrotter(atoms, 2.0**-e, hbar=1.0, precession="spin", rotation=rotation,
                      order=order).run(2**e)
        hs.append(2.0**-e)
        errors.append(state_error(state(atoms), chain_reference))
    assert errors[-1] > 1e-12
    assert abs(fitted_order(hs, errors) - order) < 0.15, errors


@pytest.mark.parametrize("precession", ["moment", "spin"])
def test_fcc_converges_to_ode_solution(precession):
    t_end = 20 * units.fs
    ref = reference_solution(fcc_cobalt(2, temperature_K=300), t_end, hbar=ase_spin.HBAR,
                             precession=precession)
    hs, errors = [], []
    for n in (20, 40, 80):
        atoms = fcc_cobalt(2, temperature_K=300)
        SuzukiTrotter(atoms, t_end / n, precession=precession).run(n)
        hs.append(t_end / n)
        errors.append(state_error(state(atoms), ref))
    assert abs(fitted_order(hs, errors) - 2) < 0.2, errors


def test_more_accurate_per_step_than_one_midpoint_rotation():
    """peers.md: four rotations by h/4 per step make the splitting's spin error
    at equal h well below the collective method's (about 10x on this scene)."""
    t_end = 20 * units.fs
    ref = reference_solution(fcc_cobalt(2), t_end, hbar=ase_spin.HBAR)
    a, b = fcc_cobalt(2), fcc_cobalt(2)
    SuzukiTrotter(a, 0.5 * units.fs).run(40)
    ase_spin.CollectivePRK(b, 0.5 * units.fs).run(40)
    err_split = np.abs(ase_spin.get_spins(a) - ref[2]).max()
    err_collective = np.abs(ase_spin.get_spins(b) - ref[2]).max()
    assert 3 < err_collective / err_split < 30


def test_time_reversible_and_lengths():
    atoms = fcc_cobalt(2, temperature_K=500)
    start = state(atoms)
    dyn = SuzukiTrotter(atoms, 1.0 * units.fs, rotation="exact")
    dyn.run(30)
    assert state_error(state(atoms), start) > 1e-3
    s = ase_spin.get_spins(atoms)
    dyn.dt = -dyn.dt
    dyn.run(30)
    assert state_error(state(atoms), start) < 1e-11
    assert np.abs(np.linalg.norm(dyn._state.s, axis=1) - 1).max() < 1e-14


def test_frozen_lattice_and_bad_rotation():
    atoms = fcc_cobalt(2)
    x0 = atoms.positions.copy()
    SuzukiTrotter(atoms, 1.0 * units.fs, lattice="frozen").run(5)
    assert np.array_equal(atoms.positions, x0)
    with pytest.raises(ValueError, match="rotation"):
        SuzukiTrotter(atoms, 1.0, rotation="euler")


def test_site_sweeps_are_cached_on_disk_per_combination_of_terms():
    """The sequential sweeps over any spin terms are compiled once per
    combination of terms and kept in numba's disk cache (a kernel taking the
    field functions as arguments could not be, and compiled in every
    process); the order of the terms makes another kernel."""
    from pathlib import Path

    from ase_spin import UniaxialAnisotropy, Zeeman
    from ase_spin._jit import cache as compilation
    from ase_spin.md import splitting

    pad = (splitting._no_site,) * (splitting.MAX_SITE_TERMS - 2)
    one = (Zeeman.site_field, UniaxialAnisotropy.site_field, *pad)
    other = (UniaxialAnisotropy.site_field, Zeeman.site_field, *pad)
    sweeps = splitting.rotate_sweeps_sites(one)
    assert splitting.rotate_sweeps_sites(one) is sweeps
    assert splitting.rotate_sweeps_sites(other).py_func.__qualname__ != sweeps.py_func.__qualname__
    s = np.tile([0.6, 0.0, 0.8], (4, 1))
    data = (Zeeman(1.0, [0, 0, 1]).bind(_system(4)), UniaxialAnisotropy(0.01, [1, 0, 0]).bind(
        _system(4)), *(splitting._NO_DATA,) * len(pad))
    sweeps(s, np.full(4, 0.1), False, *data)
    name = sweeps.py_func.__qualname__
    assert list(Path(compilation.cache_dir(sweeps)).glob(f"splitting.{name}-*.nbi")), name


def _system(n):
    from ase_spin.terms.base import Species, System

    return System(Species.from_symbols(["Co"] * n), np.full(n, 1.72), np.eye(3) * 10.0,
                  np.array([True] * 3))


@pytest.mark.parametrize("extra", ["exchange", "zeeman", "zeeman+dmi", "easy axis across"])
def test_frozen_lattice_energy_to_round_off_when_fields_do_not_depend_on_the_spin(extra):
    """Each rotation turns s_i about its own field B_i; where B_i does not depend
    on s_i (exchange, a Zeeman field, DMI) it leaves s_i·B_i and so E unchanged:
    at fixed positions the energy stays at round-off (docs/benchmarks.md,
    "Long runs: energy"). A uniaxial axis across the field makes B_i depend on s_i:
    the energy then moves (dynamics.md: the splitting loses its order there)."""
    from ase_spin.terms.anisotropy import UniaxialAnisotropy
    from ase_spin.terms.dmi import DMI
    from ase_spin.terms.zeeman import Zeeman

    terms = {"exchange": [], "zeeman": [Zeeman(10.0, [0.0, 0.0, 1.0])],
             "zeeman+dmi": [Zeeman(10.0, [0.0, 0.0, 1.0]), DMI(0.005, [0, 0, 1], rc=2.6)],
             "easy axis across": [Zeeman(10.0, [0.0, 0.0, 1.0]),
                                  UniaxialAnisotropy(0.01, [1.0, 0.0, 0.0])]}[extra]
    atoms = fcc_cobalt(2, cone_deg=60, extra=terms)
    s0 = ase_spin.get_spins(atoms).copy()
    e0 = atoms.get_potential_energy()
    SuzukiTrotter(atoms, 0.5 * units.fs, lattice="frozen", order=4).run(200)
    assert np.abs(ase_spin.get_spins(atoms) - s0).max() > 0.1  # the spins did move
    change = abs(atoms.get_potential_energy() - e0) / len(atoms)
    if extra == "easy axis across":
        assert change > 1e-6
    else:
        assert change < 1e-13
