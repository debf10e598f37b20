"""Messages that must not contradict each other or miss the obvious (issue 36,
item 8): the midpoint solver's error against the timestep warning, implausible
parameters and structures, unknown and missing keywords of the integrators."""

import re
import warnings

import numpy as np
import pytest
from ase import Atoms, units

import ase_spin
from ase_spin import (DMI, G_ELECTRON, HBAR, BetheSlater, CollectivePRK, Cubic,
                      CubicAnisotropy, Exchange, ImplausibleParameterWarning, Langevin,
                      LennardJones, SpinConvergenceError, SpinLatticeCalculator,
                      SuzukiTrotter, Tabulated, UniaxialAnisotropy, Zeeman)
from ase_spin.app.inputs import check_keywords
from ase_spin.md.errors import TimestepWarning
from ase_spin.scenes import fcc_cobalt, field_anisotropy_terms, paper_chain

PHASE = re.compile(r"the fastest spin precesses by ([0-9.e+-]+) rad per step")


def _phase(text):
    found = PHASE.findall(text)
    assert found, text
    return float(found[0])


# -- SpinConvergenceError and TimestepWarning: one quantity ----------------------

@pytest.mark.parametrize("solver, dt_fs", [("jacobi", 8.0), ("auto", 30.0)])
def test_convergence_error_reports_the_phase_of_the_timestep_warning(solver, dt_fs):
    """Both give h·max r_i|B_i|/ħ with r_i = g/μ_i (physical conventions) from
    the fields at the step's start; at 30 fs the default solver's refusal
    used to say "h·max|B|/ħ ≈ 0 rad" under a warning of 19 rad per step."""
    atoms = fcc_cobalt(2, temperature_K=0.0)
    B = atoms.calc.get_property("magnetic_forces", atoms)
    mu = np.linalg.norm(atoms.get_initial_magnetic_moments(), axis=1)
    expected = dt_fs * units.fs * np.max(G_ELECTRON / mu * np.linalg.norm(B, axis=1)) / HBAR
    with pytest.warns(TimestepWarning) as caught, \
            pytest.raises(SpinConvergenceError, match="Reduce the timestep") as error:
        CollectivePRK(atoms, dt_fs * units.fs, lattice="frozen", solver=solver).run(1)
    warned = _phase(str(next(w.message for w in caught
                             if isinstance(w.message, TimestepWarning))))
    raised = _phase(str(error.value))
    assert warned == raised == pytest.approx(expected, rel=0.03)  # (two digits)
    assert raised > 1.0  # not the "≈ 0 rad" of the midpoint fields
    if solver == "auto":
        assert "above 8 rad" in str(error.value)


def test_convergence_error_phase_includes_the_gilbert_factor_in_langevin():
    """With a bath both figures carry the Gilbert factor 1/(1+λ²) (half the
    NVE figure at λ = 1); the error's is taken after the opening bath half
    step has damped the spins a little."""
    atoms = fcc_cobalt(2, temperature_K=0.0)
    B = atoms.calc.get_property("magnetic_forces", atoms)
    mu = np.linalg.norm(atoms.get_initial_magnetic_moments(), axis=1)
    nve = 8 * units.fs * np.max(G_ELECTRON / mu * np.linalg.norm(B, axis=1)) / HBAR
    with pytest.warns(TimestepWarning) as caught, \
            pytest.raises(SpinConvergenceError) as error:
        Langevin(atoms, 8 * units.fs, 0.0, spin_damping=1.0, friction=0.0, lattice="frozen",
                 solver="jacobi").run(1)
    warned = _phase(str(next(w.message for w in caught
                             if isinstance(w.message, TimestepWarning))))
    assert warned == pytest.approx(nve / 2, rel=0.03)  # (two digits)
    assert _phase(str(error.value)) == pytest.approx(warned, rel=0.1)


# -- implausible parameters ---------------------------------------------------------

@pytest.mark.parametrize("make, match", [
    (lambda: Zeeman([0.0, 0.0, 1e4]), r"Zeeman field \|H\| = 1e\+04 T.*Oe or G given as tesla"),
    (lambda: Zeeman(2e4, [1.0, 0.0, 0.0]), r"2e\+04 T.*1 T = 10⁴ Oe"),
    (lambda: UniaxialAnisotropy(50.0, [0, 0, 1]), r"UniaxialAnisotropy K = 50 eV per atom"),
    (lambda: UniaxialAnisotropy({"Fe": -3.0, "Co": 1e-4}, [0, 0, 1]), r"K = 3 eV per atom"),
    (lambda: CubicAnisotropy(0.001, -40.0), r"CubicAnisotropy K2 = 40 eV"),
    (lambda: BetheSlater(44.7, 0.003, 1.49), r"BetheSlater J1 = 44.7 eV.*meV given as eV"),
    (lambda: Cubic(-10.0, 1.5), r"Cubic J\(rc/2\) = J0/8 \(J0 = -10 eV\) = 1.25 eV"),
    (lambda: Tabulated([2.0, 2.5, 3.0], [5.0, 1.0, 0.0]), r"Tabulated J = 5 eV"),
    (lambda: DMI(3.0, [0, 0, 1], rc=3.0), r"DMI \|D\| = 3 eV"),
])
def test_implausible_parameters_warn_where_they_enter(make, match):
    with pytest.warns(ImplausibleParameterWarning, match=match) as caught:
        make()
    # attributed to the line that gave the value (here: this file), not to
    # the package's internals, however deep the check sits
    assert all(w.filename == __file__ for w in caught), [w.filename for w in caught]


def test_timestep_warning_points_at_the_users_line():
    """The warning of a run() or step() names the user's line, whichever
    depth of the package (a run, a step, a re-synchronised state) checks it."""
    atoms = fcc_cobalt(2)
    dyn = CollectivePRK(atoms, 3 * units.fs)
    with pytest.warns(TimestepWarning) as caught:
        dyn.run(1)
    atoms = fcc_cobalt(2)
    dyn = Langevin(atoms, 3 * units.fs, 300.0, spin_damping=0.1, friction=0.0)
    with pytest.warns(TimestepWarning) as more:
        dyn.step()
    assert [w.filename for w in [*caught, *more]
            if isinstance(w.message, TimestepWarning)] == [__file__] * 2


def test_reassigned_parameters_are_checked_too():
    coupling = BetheSlater(0.0446928, 0.003496, 1.4885)
    with pytest.warns(ImplausibleParameterWarning, match="J1 = 44.69"):
        coupling.J1 = 44.6928


def test_plausible_scenes_say_nothing():
    """The package's own scenes (fcc Co with field and anisotropy; the paper's
    chain in its reduced units) and plausible parameters: no warning."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        atoms = fcc_cobalt(2, extra=field_anisotropy_terms())
        atoms.get_potential_energy()
        paper_chain(10).get_potential_energy()
        Zeeman(999.0, [0, 0, 1])
        UniaxialAnisotropy(-0.5, [0, 0, 1])
        DMI(0.003, [0, 0, 1], rc=3.0)
        Cubic(0.010 / (1.0 - 2.5 / 3.0) ** 3, 3.0)  # examples/skyrmion.py: J0 = 2.16 eV, J_nn 10 meV


def _dimer(r, cell=10.0):
    atoms = Atoms("Co3", positions=[[0, 0, 0], [r, 0, 0], [0, 2.5, 0]],
                  cell=[cell, cell, cell], pbc=True)
    ase_spin.set_spins(atoms, [[0, 0, 1]] * 3, magnitudes=1.7)
    atoms.calc = SpinLatticeCalculator([LennardJones(epsilon=0.4, sigma=2.2742, rc=4.7),
                                        Exchange(BetheSlater(0.0446928, 0.003496, 1.4885),
                                                 rc=4.0)])
    return atoms


def test_atoms_too_close_warn_once_naming_the_pair():
    """Two atoms 0.01 Å apart (E ≈ 3e28 eV) used to pass without a word: the
    first neighbour list of the structure names them and the distance; the
    rebuilds of a run do not warn again."""
    atoms = _dimer(0.01)
    with pytest.warns(ImplausibleParameterWarning,
                      match=r"atoms 0 and 1 are 0.01 Å apart: closer than 0.5 Å"):
        energy = atoms.get_potential_energy()
    assert energy > 1e20
    with warnings.catch_warnings():
        warnings.simplefilter("error", ImplausibleParameterWarning)
        atoms.positions[1, 0] = 0.02  # moved more than half the skin: a rebuild
        atoms.get_potential_energy()
        _dimer(0.6).get_potential_energy()


def test_atoms_too_close_seen_by_an_integrator():
    atoms = _dimer(0.3)
    with pytest.warns(ImplausibleParameterWarning, match=r"atoms 0 and 1 are 0.3 Å apart"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", TimestepWarning)
            CollectivePRK(atoms, 0.01 * units.fs, lattice="frozen").run(1)


# -- keywords of the integrators ----------------------------------------------------

def test_unknown_keyword_is_named_before_the_missing_ones():
    atoms = fcc_cobalt(1)
    with pytest.raises(TypeError, match=r"^Langevin: unknown keyword 'temperature'; did you "
                       r"mean temperature_K\? \(in kelvin"):
        Langevin(atoms, 0.5 * units.fs, temperature=300)
    with pytest.raises(TypeError, match=r"unknown keyword 'damping'; did you mean spin_damping"):
        Langevin(atoms, 0.5 * units.fs, 300, damping=0.1, friction=0.0)
    with pytest.raises(TypeError, match=r"unknown keyword 'tl'; did you mean tol\?"):
        CollectivePRK(atoms, 0.5 * units.fs, tl=1e-10)
    with pytest.raises(TypeError, match=r"unknown keyword 'dt'; did you mean timestep\?"):
        SuzukiTrotter(atoms, 0.5 * units.fs, dt=1.0)
    with pytest.raises(TypeError, match=r"CollectivePRK: unknown keyword 'temperature' \(no "
                       r"heat bath here: ase_spin.Langevin takes temperature_K\)"):
        CollectivePRK(atoms, 0.5 * units.fs, temperature=300)
    # ASE's own keywords pass through
    CollectivePRK(atoms, 0.5 * units.fs, append_trajectory=False)


def test_missing_bath_parameters_say_what_they_are():
    atoms = fcc_cobalt(1)
    with pytest.raises(TypeError, match=r"Langevin needs spin_damping \(λ.*typically 0.01 to "
                       r"0.1.*\); friction \(γ.*0.01 / units.fs.*For example"):
        Langevin(atoms, 0.5 * units.fs, 300)
    with pytest.raises(TypeError, match=r"Langevin needs temperature_K \(the bath temperature "
                       r"in K\); spin_damping"):
        Langevin(atoms, 0.5 * units.fs)
    with pytest.raises(TypeError, match=r"needs friction"):
        Langevin(atoms, 0.5 * units.fs, temperature_K=300, spin_damping=0.1)
    Langevin(atoms, 0.5 * units.fs, 300, spin_damping=0.1, friction=0.01 / units.fs)


def test_input_files_still_require_the_bath_parameters():
    """The command line reads the required keywords from the signature: the
    REQUIRED default counts as required."""
    from ase_spin.app.inputs import InputError

    with pytest.raises(InputError, match="needs 'spin_damping' and 'friction'"):
        check_keywords(["temperature_K"], Langevin, "[integrator] (Langevin)",
                       given=("atoms", "timestep"))
