"""Bad input is refused where it enters, the Atoms stay as they were, and
changes between runs take effect: the issue's reproducers, one by one."""

import copy

import numpy as np
import pytest
from ase import Atoms, units
from ase.build import bulk
from ase.constraints import FixAtoms

import ase_spin
from ase_spin import (BetheSlater, CollectivePRK, Exchange, LennardJones,
                      SpinConvergenceError, SpinLatticeCalculator, SuzukiTrotter,
                      UnstableStepError)

from conftest import CO_BS, CO_LJ, interrupted_at

INTEGRATORS = [CollectivePRK, SuzukiTrotter]


def terms():
    return [LennardJones(**CO_LJ, cutoff="shift"), Exchange(BetheSlater(*CO_BS), rc=4.0)]


def scene(seed=0, calc=True):
    a = bulk("Co", "fcc", a=3.54, cubic=True).repeat((2, 1, 1))
    a.rattle(0.05, seed=seed)
    rng = np.random.default_rng(seed)
    ase_spin.set_spins(a, rng.normal(size=(len(a), 3)) + [0, 0, 2.5], 1.7)
    a.set_momenta(rng.normal(size=(len(a), 3)) * 0.3)
    if calc:
        a.calc = SpinLatticeCalculator(terms())
    return a


def state(a):
    return np.concatenate([a.positions.ravel(), a.get_momenta().ravel(),
                           np.asarray(a.arrays["initial_magmoms"], float).ravel()])


def fingerprint(a):
    """Everything an error must leave untouched, bit for bit, dtypes included."""
    out = []
    for name in sorted(a.arrays):
        x = a.arrays[name]
        out.append((name, x.dtype.str, x.shape, x.tobytes()))
    out.append(("cell", a.cell.array.tobytes()))
    out.append(("pbc", a.pbc.tobytes()))
    out.append(("constraints", repr([c.todict() for c in a.constraints])))
    return out


def raises_unchanged(a, exc, match, fn):
    before = fingerprint(a)
    with pytest.raises(exc, match=match):
        fn()
    assert fingerprint(a) == before


# -- spins ----------------------------------------------------------------------

@pytest.mark.parametrize("direction", [(1e200, 0, 0), (1e308, 1e308, 0), (5e-324, 0, 0),
                                       (1e-160, 1e-160, 0), (3, 4, 0)])
def test_directions_normalised_exactly_at_any_scale(direction):
    a = scene(calc=False)
    ase_spin.set_spins(a, direction, 2.0)
    s = ase_spin.get_spins(a)
    assert np.abs(np.linalg.norm(s, axis=1) - 1.0).max() <= 4e-16
    d = np.array(direction, float)
    np.testing.assert_allclose(s[0], d / np.abs(d).max() / np.linalg.norm(d / np.abs(d).max()),
                               rtol=0, atol=2.3e-16)
    assert np.allclose(np.linalg.norm(ase_spin.get_moments(a), axis=1), 2.0, rtol=1e-15)


@pytest.mark.parametrize("bad, exc", [("1", TypeError), (["1", "0", "0"], TypeError),
                                      ([1j, 0, 0], TypeError), ([True, False, False], TypeError),
                                      (None, TypeError), ([object(), 0, 0], TypeError),
                                      ([np.nan, 0, 1], ValueError), ([0, np.inf, 1], ValueError)])
def test_bad_directions_refused(bad, exc):
    a = scene(calc=False)
    raises_unchanged(a, exc, "spin direction", lambda: ase_spin.set_spins(a, bad))


@pytest.mark.parametrize("mu", [5e-324, 1e-160, 1e154, 1e160, -1.0, np.nan, "2"])
def test_bad_magnitudes_refused(mu):
    a = scene(calc=False)
    exc = TypeError if isinstance(mu, str) else ValueError
    raises_unchanged(a, exc, "magnitude", lambda: ase_spin.set_spins(a, (0, 0, 1), mu))


@pytest.mark.parametrize("moments, exc", [
    (np.array([[1e160, 0, 0]] * 8), ValueError), (np.array([[1e-200, 0, 0]] * 8), ValueError),
    (np.array([[1, 0, 1j]] * 8), TypeError), (np.array([["1", "0", "0"]] * 8), TypeError),
    (np.array([[1, 0, np.nan]] * 8), ValueError)])
def test_bad_moments_on_atoms_refused_everywhere(moments, exc):
    for use in ("energy", "magnetic_forces", "run"):
        a = scene()
        a.arrays["initial_magmoms"] = moments
        fn = {"energy": a.get_potential_energy,
              "magnetic_forces": lambda: a.calc.get_magnetic_forces(a),
              "run": lambda: CollectivePRK(a, 0.1 * units.fs).run(1)}[use]
        raises_unchanged(a, exc, "moment", fn)


@pytest.mark.parametrize("cls", INTEGRATORS)
@pytest.mark.parametrize("dtype", [np.int64, np.int32, np.float32, np.float16])
def test_moment_dtypes_computed_and_written_in_float64(cls, dtype):
    a = scene()
    m = np.array([[2, 0, 2], [0, 2, 2], [1, 1, 1], [0, 0, 3]] * 2, dtype=dtype)
    a.arrays["initial_magmoms"] = m
    b = scene()
    b.arrays["initial_magmoms"] = m.astype(float)
    e_int, e_float = a.get_potential_energy(), b.get_potential_energy()
    assert e_int == e_float
    cls(a, 0.2 * units.fs).run(5)
    cls(b, 0.2 * units.fs).run(5)
    assert a.arrays["initial_magmoms"].dtype == np.float64
    np.testing.assert_array_equal(state(a), state(b))
    mu0 = np.linalg.norm(m.astype(float), axis=1)
    np.testing.assert_allclose(np.linalg.norm(a.arrays["initial_magmoms"], axis=1), mu0,
                               rtol=1e-14)


# -- terms and calculator --------------------------------------------------------

@pytest.mark.parametrize("make, match", [
    (lambda: LennardJones("0.4", 2.27, 4.7), "epsilon"),
    (lambda: LennardJones(0.4, 2.27j, 4.7), "sigma"),
    (lambda: LennardJones(0.4, None, 4.7), "sigma"),
    (lambda: LennardJones(0.4, 2.27, np.nan), "rc"),
    (lambda: LennardJones(0.4, 2.27, "4.7"), "rc"),
    (lambda: LennardJones({("Co", "Co"): "x"}, 2.27, 4.7), "epsilon"),
    (lambda: BetheSlater(0.04, None, 1.5), "J2"),
    (lambda: BetheSlater(0.04, 0.0, -1.5), "J3"),
    (lambda: Exchange(BetheSlater(*CO_BS), rc=4.0, offset="False"), "offset"),
    (lambda: Exchange(BetheSlater(*CO_BS), rc=4.0, offset=1), "offset"),
    (lambda: Exchange(BetheSlater(*CO_BS), rc="4"), "rc"),
    (lambda: Exchange("not a coupling", rc=4.0), "coupling"),
    (lambda: SpinLatticeCalculator(terms(), skn=0.5), "skn"),
    (lambda: SpinLatticeCalculator(terms(), skin="0.3"), "skin"),
])
def test_bad_term_parameters_refused(make, match):
    with pytest.raises((TypeError, ValueError), match=match):
        make()


def test_parameter_assignment_is_checked_and_takes_effect():
    a = scene()
    lj, ex = a.calc.hamiltonian.terms
    e0 = a.get_potential_energy()
    with pytest.raises(TypeError, match="epsilon"):
        lj.epsilon = "0.5"
    assert lj.epsilon == CO_LJ["epsilon"] and a.get_potential_energy() == e0
    for change in (lambda: setattr(lj, "epsilon", 0.5), lambda: setattr(ex.coupling, "J1", 0.06),
                   lambda: setattr(ex, "rc", 3.0), lambda: setattr(lj, "mode", "smooth")):
        before = a.get_potential_energy()
        change()
        fresh = a.copy()
        fresh.calc = SpinLatticeCalculator(copy.deepcopy(list(a.calc.hamiltonian.terms)))
        assert a.get_potential_energy() == pytest.approx(fresh.get_potential_energy(),
                                                         rel=1e-13)
        assert a.get_potential_energy() != before
    mapped = LennardJones({("Co", "Co"): 0.4}, 2.27, 4.7)
    with pytest.raises(TypeError, match="read-only"):
        mapped.epsilon["Co", "Co"] = 0.5


def test_offset_string_no_longer_switches_offset_on():
    a = scene()
    e_off = a.get_potential_energy()
    a.calc = SpinLatticeCalculator([terms()[0], Exchange(BetheSlater(*CO_BS), rc=4.0,
                                                         offset=False)])
    assert a.get_potential_energy() == e_off


def test_overlap_is_an_error_for_every_property_it_makes_infinite():
    for prop in ("energy", "energies", "forces", "stress"):
        a = scene()
        a.positions[1] = a.positions[0]
        raises_unchanged(a, ase_spin.AtomsTooCloseError, "closest pair",
                         lambda: a.calc.get_property(prop, a))
    # B = −∂E/∂s is finite there (J(0) = 0 for Bethe–Slater) and is returned
    a = scene()
    a.positions[1] = a.positions[0]
    assert np.isfinite(a.calc.get_magnetic_forces(a)).all()


class NaNCoupling:
    rc = 4.0

    def values(self, r):
        return np.where(r > 3.0, np.nan, 0.01), np.zeros_like(r)


@pytest.mark.parametrize("cls", INTEGRATORS)
def test_coupling_returning_nan_never_reaches_the_spins(cls):
    a = scene()
    a.calc = SpinLatticeCalculator([terms()[0], Exchange(NaNCoupling())])
    raises_unchanged(a, ValueError, "coupling", lambda: cls(a, 0.1 * units.fs).run(1))
    raises_unchanged(a, ValueError, "coupling", a.get_potential_energy)


# -- integrator settings and states ----------------------------------------------

@pytest.mark.parametrize("cls", INTEGRATORS)
@pytest.mark.parametrize("kw, exc, match", [
    (dict(timestep=1j), TypeError, "timestep"), (dict(timestep="1"), TypeError, "timestep"),
    (dict(timestep=None), TypeError, "timestep"), (dict(timestep=np.nan), ValueError, "timestep"),
    (dict(timestep=0.0), ValueError, "timestep"), (dict(hbar=np.inf), ValueError, "hbar"),
    (dict(hbar=0.0), ValueError, "hbar"), (dict(hbar="1"), TypeError, "hbar"),
    (dict(precession="Moment"), ValueError, "precession"),
    (dict(lattice=["frozen"]), ValueError, "lattice"), (dict(tmestep=1), TypeError, "tmestep"),
])
def test_bad_integrator_settings(cls, kw, exc, match):
    a = scene()
    args = dict(timestep=0.1 * units.fs)
    args.update(kw)
    raises_unchanged(a, exc, match, lambda: cls(a, **args))


@pytest.mark.parametrize("kw, exc", [(dict(tol=np.inf), ValueError), (dict(tol=0), ValueError),
                                     (dict(tol=1e-2), ValueError), (dict(tol="1e-15"), TypeError),
                                     (dict(max_iter=0), ValueError),
                                     (dict(max_iter=2.5), TypeError)])
def test_bad_solver_settings(kw, exc):
    a = scene()
    name = next(iter(kw))
    raises_unchanged(a, exc, name, lambda: CollectivePRK(a, 0.1 * units.fs, **kw))


@pytest.mark.parametrize("cls", INTEGRATORS)
@pytest.mark.parametrize("lattice", ["moving", "frozen"])
@pytest.mark.parametrize("edit, match", [("negative mass", "mass"), ("zero mass", "mass"),
                                         ("nan mass", "mass"), ("nan momenta", "momenta")])
def test_bad_masses_and_momenta(cls, lattice, edit, match):
    a = scene()
    if "mass" in edit:
        m = a.get_masses()
        m[1] = {"negative mass": -1.0, "zero mass": 0.0, "nan mass": np.nan}[edit]
        a.set_masses(m)
    else:
        p = a.get_momenta()
        p[2, 1] = np.nan
        a.set_momenta(p)
    with pytest.warns() if edit == "zero mass" else _nothing():
        dyn = cls(a, 0.1 * units.fs, lattice=lattice)
    raises_unchanged(a, ValueError, match, lambda: dyn.run(1))


class _nothing:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


@pytest.mark.parametrize("cls, exc", [(SuzukiTrotter, UnstableStepError),
                                      (CollectivePRK, SpinConvergenceError)])
def test_absurd_hbar_refused_on_the_first_step(cls, exc):
    a = scene()
    raises_unchanged(a, exc, "timestep", lambda: cls(a, 0.1 * units.fs, hbar=1e-30).run(1))


@pytest.mark.parametrize("cls", INTEGRATORS)
@pytest.mark.parametrize("lattice", ["moving", "frozen"])
def test_empty_and_one_atom(cls, lattice):
    empty = Atoms()
    empty.calc = SpinLatticeCalculator(terms())
    cls(empty, 0.1 * units.fs, lattice=lattice).run(2)
    one = scene()[:1]
    one.calc = SpinLatticeCalculator(terms())
    cls(one, 0.1 * units.fs, lattice=lattice).run(2)
    assert np.isfinite(state(one)).all()


# -- changes between runs ------------------------------------------------------------

def _mutations():
    def masses(a):
        a.set_masses(a.get_masses() * np.linspace(0.5, 2.0, len(a)))

    def epsilon(a):
        a.calc.hamiltonian.terms[0].epsilon = 0.5

    def j1(a):
        a.calc.hamiltonian.terms[1].coupling.J1 = 0.06

    def rc(a):
        a.calc.hamiltonian.terms[1].rc = 3.0

    def fix(a):
        a.set_constraint(FixAtoms([0]))

    def fix_index_in_place(a):
        a.constraints[0].index[:] = [2]

    def spins(a):
        ase_spin.set_spins(a, [1, 0, 0])

    def cell(a):
        a.set_cell(a.cell * 1.01, scale_atoms=True)

    def new_calc(a):
        a.calc = SpinLatticeCalculator(terms())

    return dict(masses=masses, epsilon=epsilon, J1=j1, rc=rc, fix=fix,
                fix_index_in_place=fix_index_in_place, spins=spins, cell=cell,
                new_calc=new_calc)


MUTATIONS = _mutations()


@pytest.mark.parametrize("cls", INTEGRATORS)
@pytest.mark.parametrize("name", list(MUTATIONS))
def test_change_between_runs_takes_effect(cls, name):
    """Run, change something, run on: equal to a fresh integrator started from
    the changed state (the caches of the first run are not reused)."""
    mutate = MUTATIONS[name]

    def prepared():
        a = scene()
        if name == "fix_index_in_place":
            a.set_constraint(FixAtoms([1]))
        return a

    a = prepared()
    dyn = cls(a, 0.2 * units.fs)
    dyn.run(4)
    mutate(a)
    dyn.run(4)

    b = prepared()
    cls(b, 0.2 * units.fs).run(4)
    mutate(b)
    fresh = b.copy()
    fresh.calc = SpinLatticeCalculator(copy.deepcopy(list(b.calc.hamiltonian.terms)))
    fresh.set_constraint(copy.deepcopy(b.constraints))
    cls(fresh, 0.2 * units.fs).run(4)
    np.testing.assert_allclose(state(a), state(fresh), rtol=0, atol=1e-10)
    assert dyn.get_potential_energy() == pytest.approx(fresh.get_potential_energy(),
                                                       rel=1e-10)


@pytest.mark.parametrize("cls", INTEGRATORS)
def test_one_calculator_shared_by_two_atoms(cls):
    a, b = scene(0), scene(1)
    b.calc = a.calc
    ref = scene(0)
    d1, d2 = cls(a, 0.2 * units.fs), cls(b, 0.2 * units.fs)
    d1.run(3)
    d2.run(3)
    b.get_forces()
    d1.run(3)
    cls(ref, 0.2 * units.fs).run(6)
    np.testing.assert_allclose(state(a), state(ref), rtol=0, atol=1e-12)
    # the same calculator on a copy with other magnetic atoms
    c = a.copy()
    ase_spin.set_spins(c, np.where(np.arange(len(c))[:, None] % 2 == 0, [0, 0, 1], [0, 0, 0]))
    c.calc = a.calc
    cls(c, 0.2 * units.fs).run(2)
    d1.run(2)
    assert np.isfinite(state(a)).all() and np.isfinite(state(c)).all()


# -- interrupts --------------------------------------------------------------------

@pytest.mark.parametrize("cls, order, constrained", [(CollectivePRK, 2, False),
                                                     (SuzukiTrotter, 2, True)])
def test_interrupt_anywhere_in_a_step_leaves_a_whole_state(cls, order, constrained):
    """A KeyboardInterrupt raised at the k-th line executed inside ase_spin
    during a step, for every k until the step completes: the Atoms and nsteps
    are both before or both after the step, and running on reaches the
    uninterrupted run's state."""

    def make():
        a = scene()
        if constrained:
            a.set_constraint(FixAtoms([0]))
        return cls(a, 0.2 * units.fs, order=order)

    ref = make()
    ref.run(2)
    before = state(ref.atoms)
    ref.run(1)
    after = state(ref.atoms)
    ref.run(2)
    final = state(ref.atoms)

    dyn = make()
    k = 0
    outcomes = {"before": 0, "after": 0}
    while True:
        k += 1
        dyn = make()
        dyn.run(2)
        if interrupted_at(k, lambda: dyn.run(1)):
            break
        s = state(dyn.atoms)
        if np.array_equal(s, before):
            assert dyn.nsteps == 2
            outcomes["before"] += 1
            dyn.run(3)
        else:
            np.testing.assert_array_equal(s, after)
            assert dyn.nsteps == 3
            outcomes["after"] += 1
            dyn.run(2)
        np.testing.assert_allclose(state(dyn.atoms), final, rtol=0, atol=1e-12)
    assert k > 100 and outcomes["before"] > 50
