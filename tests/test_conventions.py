"""Physical conventions by default, LAMMPS's (and the paper's) by one switch on the
calculator: Zeeman energy, precession, ħ, their export and their checks."""

import numpy as np
import pytest
from ase import Atoms, units

import ase_spin
from ase_spin import (HBAR, HBAR_LAMMPS, MU_B, MU_B_LAMMPS, CollectivePRK, Langevin,
                      SpinLatticeCalculator, SuzukiTrotter, Zeeman, get_spins, set_spins)
from ase_spin.constants import G_ELECTRON
from ase_spin.conventions import LAMMPS, PAPER, PHYSICAL, conventions
from ase_spin.scenes import fcc_cobalt, paper_chain

S0 = np.array([np.sin(1.0), 0.0, np.cos(1.0)])  # 57° from the field


def spin_in_field(mu, H=1.0, **calc_kwargs):
    atoms = Atoms("Fe", positions=[[0.0, 0.0, 0.0]])
    set_spins(atoms, [S0], [mu])
    atoms.calc = SpinLatticeCalculator([Zeeman(H, [0, 0, 1])], **calc_kwargs)
    return atoms


def turned_angle(atoms):
    s = get_spins(atoms)[0]
    return np.arctan2(s[1], s[0])


@pytest.mark.parametrize("integrator", [CollectivePRK, SuzukiTrotter])
@pytest.mark.parametrize("mu", [2.2, 0.6])
def test_default_is_larmor_precession_and_the_energy_of_a_moment(integrator, mu):
    """By default a moment μ μB in 1 T has E = −μ μB H and precesses
    right-handedly about H at γ = g_e μB/ħ (0.176 rad/ps), whatever μ (to the
    steps' O((ωh)²) error, 1e-7 here: far below g_e/2 − 1 = 1.2e-3)."""
    atoms = spin_in_field(mu)
    assert atoms.get_potential_energy() == pytest.approx(-mu * MU_B * S0[2], rel=1e-15)
    omega = G_ELECTRON * MU_B * 1.0 / HBAR
    assert omega * 1000 * units.fs == pytest.approx(0.1760859644, rel=1e-9)  # rad/ps, CODATA
    h, n = 5 * units.fs, 20
    dyn = integrator(atoms, h, lattice="frozen")
    assert (dyn.hbar, dyn.gyromagnetic, dyn.precession, dyn.g) == (HBAR, "moment", "moment",
                                                                  G_ELECTRON)
    dyn.run(n)
    assert turned_angle(atoms) == pytest.approx(omega * n * h, rel=1e-6)


@pytest.mark.parametrize("mu", [2.2, 0.6])
def test_lammps_conventions_by_one_switch(mu):
    """conventions="lammps": E = −2 μB' μ H and ω = 2 μB' μ H/ħ' (LAMMPS SPIN's
    fix precession/spin zeeman and nve/spin, its rounded constants), so the
    rate grows with μ; the integrator takes LAMMPS's ħ and rate from the
    calculator."""
    atoms = spin_in_field(mu, conventions="lammps")
    assert atoms.get_potential_energy() == pytest.approx(-2 * MU_B_LAMMPS * mu * S0[2], rel=1e-15)
    h, n = 2 * units.fs, 20
    dyn = CollectivePRK(atoms, h, lattice="frozen")
    assert (dyn.hbar, dyn.gyromagnetic) == (HBAR_LAMMPS, "lammps")
    dyn.run(n)
    omega = 2 * MU_B_LAMMPS * mu / HBAR_LAMMPS
    assert turned_angle(atoms) == pytest.approx(omega * n * h, rel=1e-6)


def test_issue_numbers_physical_against_lammps():
    """The figures of the report: 2.2 μB in 1 T, −1.27e-4 eV and 0.176 rad/ps
    physically; −2.55e-4 eV and 0.387 rad/ps as LAMMPS."""
    ps = 1000 * units.fs
    phys, lmp = spin_in_field(2.2), spin_in_field(2.2, conventions="lammps")
    assert phys.get_potential_energy() / S0[2] == pytest.approx(-1.2734e-4, rel=1e-4)
    assert lmp.get_potential_energy() / S0[2] == pytest.approx(-2.5472e-4, rel=1e-4)
    assert G_ELECTRON * MU_B / HBAR * ps == pytest.approx(0.17609, rel=1e-4)
    assert 2 * MU_B_LAMMPS * 2.2 / HBAR_LAMMPS * ps == pytest.approx(0.38696, rel=1e-4)


def test_explicit_settings_win_over_the_conventions():
    atoms = spin_in_field(1.5, conventions="lammps")
    dyn = CollectivePRK(atoms, units.fs, hbar=HBAR, gyromagnetic="moment", g=2.0)
    assert (dyn.hbar, dyn.gyromagnetic, dyn.g) == (HBAR, "moment", 2.0)
    z = spin_in_field(1.5)
    z.calc = SpinLatticeCalculator([Zeeman(1.0, [0, 0, 1], g=2.0, mu_B=MU_B_LAMMPS)])
    assert z.get_potential_energy() == pytest.approx(-2 * MU_B_LAMMPS * 1.5 * S0[2], rel=1e-15)


def test_paper_scene_runs_in_its_own_units():
    atoms = paper_chain(6)
    dyn = CollectivePRK(atoms, 0.01)
    assert (dyn.hbar, dyn.precession, dyn.gyromagnetic) == (1.0, "spin", "lammps")
    assert fcc_cobalt(1, conventions="lammps").calc.hamiltonian.conventions is LAMMPS


def test_names_and_errors():
    assert conventions("physical") is PHYSICAL and conventions(PAPER) is PAPER
    with pytest.raises(ValueError, match='"physical", "lammps" or "paper"'):
        SpinLatticeCalculator([Zeeman(1.0, [0, 0, 1])], conventions="LAMMPS SPIN")
    h = ase_spin.Hamiltonian([Zeeman(1.0, [0, 0, 1])], conventions="lammps")
    with pytest.raises(ValueError, match="differ from the given Hamiltonian"):
        SpinLatticeCalculator(h, conventions="physical")
    assert SpinLatticeCalculator(h).hamiltonian.conventions is LAMMPS


@pytest.mark.parametrize("unit, value", [("eV·ps", HBAR / (1000 * units.fs)),
                                         ("eV·ps", HBAR_LAMMPS / (1000 * units.fs)),
                                         ("eV·fs", HBAR / units.fs),
                                         ("J·s", units._hbar)])
def test_hbar_in_another_unit_is_refused(unit, value):
    atoms = spin_in_field(2.0)
    before = atoms.get_initial_magnetic_moments().copy()
    with pytest.raises(ValueError, match=f"is ħ in {unit}"):
        CollectivePRK(atoms, units.fs, hbar=value)
    with pytest.raises(ValueError, match="is ħ in"):
        Langevin(atoms, units.fs, 100.0, spin_damping=0.1, friction=0.0, hbar=value)
    assert np.array_equal(atoms.get_initial_magnetic_moments(), before)
    CollectivePRK(atoms, units.fs, hbar=1.0)  # reduced units stay allowed


def test_calculator_replaced_under_other_conventions_is_refused():
    atoms = spin_in_field(2.0)
    dyn = CollectivePRK(atoms, units.fs)
    atoms.calc = SpinLatticeCalculator([Zeeman(1.0, [0, 0, 1])], conventions="lammps")
    with pytest.raises(ValueError, match="'lammps' conventions but CollectivePRK was made "
                                         "under 'physical'"):
        dyn.run(1)


def test_conventions_survive_todict_and_trajectories(tmp_path):
    atoms = spin_in_field(2.0, conventions="lammps")
    data = atoms.calc.todict()
    assert data["conventions"] == "lammps"
    again = SpinLatticeCalculator.from_dict(data)
    assert again.hamiltonian.conventions is LAMMPS
    a = atoms.copy()
    a.calc = again
    assert a.get_potential_energy() == atoms.get_potential_energy()


def test_export_translates_the_zeeman_field(tmp_path):
    """write_lammps writes H scaled so LAMMPS's −2 μB' μ s·H equals the
    scene's energy; LAMMPS cannot run the physical precession (1/μ_i), and the
    refusal says how to export."""
    from ase_spin import write_lammps

    for name, H in [("physical", MU_B / (2 * MU_B_LAMMPS)), ("lammps", 1.0)]:
        atoms = spin_in_field(2.0, conventions=name)
        files = write_lammps(tmp_path / name, atoms, timestep=units.fs, steps=1)
        deck = files.input.read_text()
        written = float(deck.split("precession/spin zeeman ")[1].split()[0])
        assert written == pytest.approx(H, rel=1e-15)
    atoms = spin_in_field(2.0)
    with pytest.raises(ValueError, match='conventions="lammps"'):
        write_lammps(tmp_path / "refused", atoms, CollectivePRK(atoms, units.fs), steps=1)
