"""Spectra and spin waves (ase_spin.analysis): q paths held by a supercell, linear
spin-wave theory against analytic dispersions, S(q, ω) normalisation and sign
conventions, and the dynamics' spectrum on the spin-wave bands."""

import numpy as np
import pytest
from ase import Atoms, units
from ase.build import bulk

import ase_spin
from ase_spin import (DMI, G_ELECTRON, MU_B, BetheSlater, CollectivePRK, CubicAnisotropy,
                      Dipolar, Exchange, LennardJones, ShellExchange, SpinLatticeCalculator,
                      UniaxialAnisotropy, Zeeman)
from ase_spin.analysis import (QPath, SpinSeries, StructureFactorRecorder,
                               dynamical_structure_factor, magnon_bands, q_path,
                               read_spin_series)
from ase_spin.scenes import cone

FE_EXCHANGE = BetheSlater(J1=0.02726, J2=0.2171, J3=1.841)  # LAMMPS examples/SPIN/iron


def neighbour_vectors(cell, rc):
    """Every lattice vector 0 < |δ| < rc of a Bravais lattice (an independent sum)."""
    n = np.arange(-6, 7)
    R = np.stack(np.meshgrid(n, n, n, indexing="ij"), -1).reshape(-1, 3) @ np.asarray(cell)
    d = np.linalg.norm(R, axis=1)
    keep = (d > 0) & (d < rc)
    return R[keep], d[keep]


def ferromagnet_dispersion(q, cell, coupling, rc, rate, gap):
    """ħω(q) = r [Σ_δ J(|δ|)(1 − cos q·δ) + gap] (eV)."""
    R, d = neighbour_vectors(cell, rc)
    J = coupling.values(d)[0]
    return rate * ((J[None, :] * (1.0 - np.cos(q @ R.T))).sum(axis=1) + gap)


# -- q paths -------------------------------------------------------------------

def test_q_path_in_a_supercell_holds_only_its_wave_vectors():
    prim = bulk("Fe", "bcc", a=2.87)
    for supercell in (prim.repeat(4), bulk("Fe", "bcc", a=2.87, cubic=True).repeat(3)):
        path = q_path(prim, supercell=supercell)
        n = supercell.cell[:] @ path.q.T / (2 * np.pi)
        assert np.abs(n - np.round(n)).max() < 1e-9
        assert np.all(np.diff(path.x) >= -1e-12)  # along the path, never back
    # the 4×4×4 repeat holds G, H, N, P and the middle of G–H
    path = q_path(prim, supercell=prim.repeat(4))
    dense = q_path(prim, npoints=200)
    assert [s for _, s in path.special] == [s for _, s in dense.special]
    assert np.allclose([x for x, _ in path.special], [x for x, _ in dense.special])
    H = 2 * np.pi / 2.87
    on_GH = path.q[path.x <= path.special[1][0] + 1e-9]
    assert np.allclose(np.linalg.norm(on_GH, axis=1), H * np.arange(3) / 2)
    with pytest.raises(ValueError, match="no wave vector"):
        q_path(prim, path="PN", supercell=prim.repeat(3))


# -- linear spin waves against analytic dispersions ---------------------------------

@pytest.mark.parametrize("lattice, a, rc", [("sc", 2.6, 4.0), ("bcc", 2.87, 3.4),
                                            ("fcc", 3.54, 4.0)])
@pytest.mark.parametrize("gyromagnetic", ["moment", "lammps"])
def test_ferromagnet_bands_are_the_analytic_dispersion(lattice, a, rc, gyromagnetic):
    """Exchange of several shells, uniaxial anisotropy and a field: ħω(q) =
    r [Σ_δ J_δ (1 − cos q·δ) + 2K + μ μB H], r = g_e/μ (a moment) or 1 (LAMMPS)."""
    atoms = bulk("Fe", lattice, a=a)
    mu, K, H = 2.2, 0.0007, 3.0
    ase_spin.set_spins(atoms, [0, 0, 1], magnitudes=mu)
    atoms.calc = SpinLatticeCalculator([Exchange(FE_EXCHANGE, rc=rc),
                                        UniaxialAnisotropy(K, [0, 0, 1]), Zeeman(H, [0, 0, 1])])
    path = q_path(atoms, npoints=40)
    bands = magnon_bands(atoms, path, gyromagnetic=gyromagnetic)
    rate = G_ELECTRON / mu if gyromagnetic == "moment" else 1.0
    exact = 1000 * ferromagnet_dispersion(path.q, atoms.cell[:], FE_EXCHANGE, rc, rate,
                                          2 * K + mu * MU_B * H)
    assert np.abs(bands.energy_meV[:, 0] - exact).max() < 1e-8 * exact.max()
    assert bands.energy_meV[0, 0] == pytest.approx(1000 * rate * (2 * K + mu * MU_B * H))


def test_bands_follow_the_integrators_precession():
    """The rate of the integrator given (gyromagnetic, g) sets the bands; the
    spin convention reverses the precession but not |ω| of a symmetric crystal."""
    atoms = bulk("Fe", "bcc", a=2.87)
    ase_spin.set_spins(atoms, [0, 0, 1], magnitudes=2.0)
    atoms.calc = SpinLatticeCalculator([Exchange(FE_EXCHANGE, rc=3.4)])
    path = q_path(atoms, npoints=12)
    moment = magnon_bands(atoms, path).energy_meV
    big = atoms.repeat(2)
    big.calc = atoms.calc
    dyn = CollectivePRK(big, 0.1 * units.fs, gyromagnetic="lammps")
    lammps = magnon_bands(atoms, path, dynamics=dyn).energy_meV
    assert np.allclose(lammps * G_ELECTRON / 2.0, moment, rtol=1e-12, atol=1e-12)
    assert np.allclose(magnon_bands(atoms, path, g=2.0).energy_meV * G_ELECTRON / 2.0, moment)
    assert np.allclose(magnon_bands(atoms, path, precession="spin").energy_meV, moment)


def test_a_cubic_cell_folds_the_primitive_bands():
    """Two atoms of the cubic bcc cell: at q, the bands of the primitive cell at
    q and at q + (2π/a)(1, 1, 1)."""
    a = 2.87
    calc = SpinLatticeCalculator([Exchange(FE_EXCHANGE, rc=3.4)])
    cubic = bulk("Fe", "bcc", a=a, cubic=True)
    prim = bulk("Fe", "bcc", a=a)
    for atoms in (cubic, prim):
        ase_spin.set_spins(atoms, [0, 0, 1], magnitudes=2.2)
        atoms.calc = calc
    path = q_path(cubic, npoints=15)
    folded = magnon_bands(cubic, path).energy_meV
    G = np.full(3, 2 * np.pi / a)
    both = np.sort(np.c_[magnon_bands(prim, path).energy_meV,
                         magnon_bands(prim, path.q + G).energy_meV], axis=1)
    assert np.abs(folded - both).max() < 1e-9 * both.max()


def test_antiferromagnet_bands():
    """A two-sublattice antiferromagnet on the bcc lattice (nearest neighbours
    J < 0): ħω = r z|J| √(1 − γ_q²), γ_q = Π_k cos(q_k a/2), z = 8."""
    a, J, mu = 2.87, -0.01, 2.0
    atoms = bulk("Fe", "bcc", a=a, cubic=True)
    ase_spin.set_spins(atoms, [[0, 0, 1], [0, 0, -1]], magnitudes=mu)
    atoms.calc = SpinLatticeCalculator([ShellExchange([(a * np.sqrt(3) / 2, J)])])
    path = q_path(atoms, npoints=25)
    bands = magnon_bands(atoms, path).energy_meV
    gamma = np.prod(np.cos(path.q * a / 2), axis=1)
    exact = 1000 * G_ELECTRON / mu * 8 * abs(J) * np.sqrt(np.clip(1 - gamma**2, 0, None))
    assert np.abs(bands - exact[:, None]).max() < 1e-9 * exact.max()


def test_cubic_anisotropy_gap_from_its_nonlinear_field():
    """E = −K1 Σ (s·n₁)²(s·n₂)² + ...: a spin along a cube axis tilted by θ has
    E ≈ −K1 θ², the gap r(−2K1) (K1 < 0: the axes are easy). The field is
    cubic in s: central differences, error O(ε²)."""
    atoms = bulk("Ni", "fcc", a=3.524)
    K1, mu = -2e-4, 0.63
    ase_spin.set_spins(atoms, [0, 0, 1], magnitudes=mu)
    atoms.calc = SpinLatticeCalculator([Exchange(FE_EXCHANGE, rc=3.0), CubicAnisotropy(K1)])
    bands = magnon_bands(atoms, QPath.from_q(np.zeros(3)))
    assert bands.energy_meV[0, 0] == pytest.approx(1000 * G_ELECTRON / mu * (-2 * K1),
                                                   rel=1e-6)


def dmi_chain(n=None, J=0.01, D=0.002, H=20.0, a=2.5):
    """A chain along x (spacing a) with exchange, interfacial DMI (D along z:
    the pair vector e_ij × D along ∓y) and a field along y holding the spins
    along the DM vector: magnons that differ between q and −q."""
    atoms = Atoms("Fe", positions=[[0, 0, 0]], cell=[a, 10, 10], pbc=True)
    terms = [ShellExchange([(a, J)]), DMI(D, [0, 0, 1], rc=1.1 * a), Zeeman(H, [0, 1, 0])]
    ase_spin.set_spins(atoms, [0, 1, 0], magnitudes=1.0)
    atoms.calc = SpinLatticeCalculator(terms)
    return atoms


def test_dmi_makes_the_bands_nonreciprocal():
    """ħω(q) = r [2J(1 − cos qa) + μB H − 2D sin qa]: the DMI part changes sign
    with q (the sign checked against the dynamics below)."""
    J, D, H, a = 0.01, 0.002, 20.0, 2.5
    atoms = dmi_chain(J=J, D=D, H=H, a=a)
    q = np.zeros((21, 3))
    q[:, 0] = np.linspace(-np.pi / a, np.pi / a, 21)
    bands = magnon_bands(atoms, q).energy_meV[:, 0]
    qa = q[:, 0] * a
    exact = 1000 * G_ELECTRON * (2 * J * (1 - np.cos(qa)) + MU_B * H - 2 * D * np.sin(qa))
    assert np.abs(bands - exact).max() < 1e-9 * exact.max()


def test_spin_waves_refuse_states_and_terms_they_cannot_take():
    atoms = bulk("Fe", "bcc", a=2.87, cubic=True)
    calc = SpinLatticeCalculator([ShellExchange([(2.87 * np.sqrt(3) / 2, 0.01)])])
    atoms.calc = calc
    path = q_path(atoms, npoints=5)
    atoms.set_initial_magnetic_moments(None)
    with pytest.raises(ValueError, match="no magnetic moments"):
        magnon_bands(atoms, path)
    ase_spin.set_spins(atoms, [[0, 0.1, 1], [0, 0, -1]], magnitudes=2.0)
    with pytest.raises(ValueError, match="not in equilibrium.*relax"):
        magnon_bands(atoms, path)
    ase_spin.set_spins(atoms, [[0, 0, 1], [0, 0, -1]], magnitudes=2.0)
    before = atoms.copy()
    with pytest.raises(ValueError, match="not an energy minimum"):
        magnon_bands(atoms, path)  # antiparallel spins with a ferromagnetic J
    assert np.array_equal(atoms.arrays["initial_magmoms"], before.arrays["initial_magmoms"])
    assert np.array_equal(atoms.positions, before.positions)
    ase_spin.set_spins(atoms, [0, 0, 1], magnitudes=2.0)
    with pytest.raises(ValueError, match="beyond the Hamiltonian's cutoff"):
        magnon_bands(atoms, path, hamiltonian=[Dipolar(rc=3.0, method="ewald")])
    with pytest.raises(TypeError, match="SpinLatticeCalculator"):
        magnon_bands(Atoms("Fe", cell=[3, 3, 3], pbc=True), path)
    with pytest.raises(ValueError, match="gyromagnetic"):
        magnon_bands(atoms, path, gyromagnetic="spin")


# -- S(q, ω): normalisation and conventions -------------------------------------

def wave_frames(q0, omega, n=16, a=2.5, samples=256, dt=2.0, angle=0.05):
    """Frames of a spin wave δs_i = ε (cos(q0 x_i − ωt), sin(q0 x_i − ωt), 0)
    on a chain of n atoms along x, spins about +z."""
    frames = []
    x = a * np.arange(n)
    for k in range(samples):
        phi = q0 * x - omega * k * dt
        s = np.column_stack([angle * np.cos(phi), angle * np.sin(phi), np.ones(n)])
        atoms = Atoms(f"Fe{n}", positions=np.column_stack([x, np.zeros((n, 2))]),
                      cell=[n * a, 10, 10], pbc=True)
        ase_spin.set_spins(atoms, s, magnitudes=2.0)
        frames.append(atoms)
    return frames


def test_a_wave_of_q_appears_at_positive_energy_at_q():
    """Re u e^{i(q₀x − ω₀t)} with ω₀ > 0: S(q₀, +ħω₀) and S(−q₀, −ħω₀), in
    the "plus" or "minus" part by its sense of rotation about the axis."""
    n, a, dt = 16, 2.5, 2.0
    q0 = 2 * np.pi * 3 / (n * a)
    omega = 2 * np.pi * 20 / (256 * dt)   # on a bin of a 256-sample block
    frames = wave_frames(q0, omega, n, a, 256, dt)
    q = np.array([[q0, 0, 0], [-q0, 0, 0], [2 * q0, 0, 0]])
    series = read_spin_series(frames, q, timestep=dt)
    spectrum = dynamical_structure_factor(series)
    E = spectrum.energy_meV
    target = 1000 * ase_spin.HBAR * omega
    assert spectrum.resolution_meV == pytest.approx(1000 * ase_spin.HBAR * 2 * np.pi / (256 * dt))
    assert E[np.argmax(spectrum.transverse[0])] == pytest.approx(target)
    assert E[np.argmax(spectrum.transverse[1])] == pytest.approx(-target)
    # the spins turn counter-clockwise about +z at q0: s⁺ = (s1 + i s2)/√2 ∝ e^{i(q0 x - ωt)}
    assert spectrum.plus[0].sum() > 1e6 * spectrum.minus[0].sum()
    assert spectrum.transverse[2].max() < 1e-12 * spectrum.transverse[0].max()
    # the sum rule: Σ_E S ΔE = ⟨|δs(q)|²⟩/N = ε²N/(2(1 + ε²)) for the wave at q0
    weight = n * 0.05**2 / (2 * (1 + 0.05**2))
    assert spectrum.sum_rule()[0] == pytest.approx(weight, rel=1e-10)
    assert np.allclose(spectrum.sum_rule("total"), spectrum.sum_rule() + spectrum.sum_rule(
        "longitudinal"))


def test_sum_rule_is_the_equal_time_correlation_of_noise():
    """Random s(q, t): Σ_E S ΔE against (1/N)⟨|δs(q)|²⟩ from the samples, exactly
    for one rectangular block, and within the statistics for Hann blocks."""
    rng = np.random.default_rng(5)
    T, M, N = 4096, 3, 10
    sq = rng.normal(size=(T, M, 3)) + 1j * rng.normal(size=(T, M, 3))
    series = SpinSeries(sq, 1.0, N, QPath.from_q(rng.normal(size=(M, 3))),
                        np.tile([0.0, 0.0, 5.0], (T, 1)))
    delta = sq - sq.mean(axis=0)
    equal_time = (np.abs(delta) ** 2).sum(axis=2).mean(axis=0) / N
    one = dynamical_structure_factor(series, window="none")
    assert np.allclose(one.sum_rule("total"), equal_time, rtol=1e-12)
    hann = dynamical_structure_factor(series, block=256)
    assert hann.blocks == 31
    # each sample's |δs|² has a relative spread 1/√3 per component pair: 3 % over 4096
    assert np.allclose(hann.sum_rule("total"), equal_time, rtol=0.05)


def test_spectrum_refuses_bad_options():
    frames = wave_frames(0.5, 0.1, samples=16)
    series = read_spin_series(frames, [[0.5, 0, 0]], timestep=2.0)
    with pytest.raises(ValueError, match="block must be between"):
        dynamical_structure_factor(series, block=17)
    with pytest.raises(ValueError, match="window"):
        dynamical_structure_factor(series, window="hamming")
    with pytest.raises(ValueError, match="overlap"):
        dynamical_structure_factor(series, overlap=1.0)
    other = read_spin_series(frames, [[0.5, 0, 0]], timestep=3.0)
    with pytest.raises(ValueError, match="same time between samples"):
        dynamical_structure_factor([series, other])
    with pytest.raises(ValueError, match="positions"):
        read_spin_series(frames, [[0.5, 0, 0]], timestep=2.0, positions="wrapped")
    with pytest.raises(ValueError, match="at least two frames"):
        read_spin_series(frames[:1], [[0.5, 0, 0]], timestep=2.0)


# -- the dynamics on the spin-wave bands ---------------------------------------------

def bcc_iron_run(n, steps, every, timestep_fs, cone_deg=10.0, lattice="frozen", seed=1,
                 trajectory=None, extra=()):
    prim = bulk("Fe", "bcc", a=2.87)
    terms = [Exchange(FE_EXCHANGE, rc=3.4), *extra]
    ase_spin.set_spins(prim, [0, 0, 1], magnitudes=2.2)
    prim.calc = SpinLatticeCalculator(terms)
    atoms = prim.repeat(n)
    ase_spin.set_spins(atoms, cone(len(atoms), np.random.default_rng(seed), cone_deg),
                       magnitudes=2.2)
    atoms.calc = SpinLatticeCalculator(terms)
    path = q_path(prim, supercell=atoms)
    dyn = CollectivePRK(atoms, timestep_fs * units.fs, lattice=lattice,
                        trajectory=trajectory, loginterval=every)
    recorder = StructureFactorRecorder(dyn, path)
    dyn.attach(recorder, interval=every)
    dyn.run(steps)
    return prim, recorder


def check_peaks_on_bands(spectrum, bands, tolerance_bins=1.0):
    """Peaks of the transverse S(q, E) within ``tolerance_bins`` of the band,
    where the band lies two bins above 0 (below, the elastic line's remainder)."""
    peaks = spectrum.peaks()
    band = bands.energy_meV[:, 0]
    resolved = band > 2 * spectrum.resolution_meV
    assert resolved.sum() >= 5
    error = np.abs(peaks - band)[resolved]
    assert error.max() < tolerance_bins * spectrum.resolution_meV, (peaks, band)
    return error.max()


def test_run_spectrum_peaks_on_the_spin_wave_bands(tmp_path):
    """bcc Fe, 64 spins in a 10° cone, frozen lattice, 400 steps: the transverse
    peaks lie on the bands within a bin (21 meV of 283)."""
    prim, recorder = bcc_iron_run(4, 400, 2, 0.5)
    spectrum = recorder.spectrum()
    bands = magnon_bands(prim, recorder.qpath)
    check_peaks_on_bands(spectrum, bands)
    pytest.importorskip("matplotlib")
    ax = spectrum.plot(bands=bands)
    assert [t.get_text() for t in ax.get_xticklabels()][:3] == ["Γ", "H", "N"]
    ax.figure.savefig(tmp_path / "sqw.png")


def test_the_spectrum_of_a_trajectory_file_is_the_recorders(tmp_path):
    _, recorder = bcc_iron_run(2, 20, 2, 0.5, trajectory=str(tmp_path / "fe.traj"))
    from_file = read_spin_series(str(tmp_path / "fe.traj"), recorder.qpath,
                                 timestep=2 * 0.5 * units.fs)
    assert len(from_file) == len(recorder) == 11
    assert np.allclose(from_file.sq, recorder.series().sq, rtol=0, atol=1e-12)
    assert recorder.series().dt == pytest.approx(from_file.dt, rel=1e-12)


def test_nonreciprocal_magnons_in_the_dynamics():
    """The DMI chain: the run's peaks at +q and −q follow the two different
    bands (the sign convention of q and ω in S and in the bands agree)."""
    atoms = dmi_chain()
    chain = atoms.repeat((16, 1, 1))
    s = cone(len(chain), np.random.default_rng(2), 8.0)
    ase_spin.set_spins(chain, s[:, [0, 2, 1]] * [1, 1, -1], magnitudes=1.0)  # about +y
    chain.calc = atoms.calc
    k = np.arange(-7, 8)
    q = np.zeros((len(k), 3))
    q[:, 0] = 2 * np.pi * k / (16 * 2.5)
    dyn = CollectivePRK(chain, 2.0 * units.fs, lattice="frozen")
    recorder = StructureFactorRecorder(dyn, q)
    dyn.attach(recorder, interval=2)
    dyn.run(600)
    spectrum = recorder.spectrum()
    bands = magnon_bands(atoms, q)
    assert spectrum.axis[1] == pytest.approx(1.0, abs=1e-2)
    check_peaks_on_bands(spectrum, bands, tolerance_bins=0.6)
    # the difference between −q and q (up to 16 meV: 3.4 meV bins) as the bands'
    peaks, band = spectrum.peaks(), bands.energy_meV[:, 0]
    far = np.abs(k) > 1
    run = (peaks[::-1] - peaks)[far & (k > 0)]
    theory = (band[::-1] - band)[far & (k > 0)]
    assert theory.max() > 4 * spectrum.resolution_meV
    assert np.abs(run - theory).max() < spectrum.resolution_meV


def test_a_recorder_sees_what_any_observer_sees_and_changes_nothing():
    """needs_results = False: no energies or frames computed for it, yet it
    reads the same spins as an ordinary observer, and the run is bit for bit
    the run without it."""
    def run(with_recorder):
        atoms = bulk("Fe", "bcc", a=2.87).repeat(3)
        ase_spin.set_spins(atoms, cone(len(atoms), np.random.default_rng(4), 20.0),
                           magnitudes=2.2)
        atoms.calc = SpinLatticeCalculator([Exchange(FE_EXCHANGE, rc=3.4)])
        dyn = CollectivePRK(atoms, 0.5 * units.fs, lattice="frozen")
        seen = []
        if with_recorder:
            recorder = StructureFactorRecorder(dyn, [[0.4, 0.1, 0.0]])
            dyn.attach(recorder, interval=3)
            dyn.attach(lambda: seen.append(atoms.get_initial_magnetic_moments().copy()),
                       interval=3)
        dyn.run(30)
        return atoms, (recorder.series().sq if with_recorder else None), seen
    plain, _, _ = run(False)
    atoms, sq, seen = run(True)
    assert np.array_equal(plain.arrays["initial_magmoms"], atoms.arrays["initial_magmoms"])
    phases = np.exp(-1j * atoms.positions @ np.array([0.4, 0.1, 0.0]))
    expected = np.array([phases @ (m / 2.2) for m in seen])
    assert np.allclose(sq[:, 0, :], expected, rtol=0, atol=1e-12)
    # alone, it has the integrator publish nothing (an ordinary observer would)
    atoms = bulk("Fe", "bcc", a=2.87).repeat(2)
    ase_spin.set_spins(atoms, [0, 0, 1], magnitudes=2.2)
    atoms.calc = SpinLatticeCalculator([Exchange(FE_EXCHANGE, rc=3.4)])
    dyn = CollectivePRK(atoms, 0.5 * units.fs, lattice="frozen")
    dyn.attach(StructureFactorRecorder(dyn, [[0.4, 0.1, 0.0]]), interval=3)
    dyn.run(4)
    assert "energy" not in atoms.calc.results
    dyn.attach(lambda: None, interval=3)
    dyn.run(3)
    assert "energy" in atoms.calc.results


def test_recorder_refuses_uneven_samples():
    atoms = bulk("Fe", "bcc", a=2.87).repeat(2)
    ase_spin.set_spins(atoms, [0, 0, 1], magnitudes=2.2)
    atoms.calc = SpinLatticeCalculator([Exchange(FE_EXCHANGE, rc=3.4)])
    dyn = CollectivePRK(atoms, 0.5 * units.fs, lattice="frozen")
    recorder = StructureFactorRecorder(dyn, [[0, 0, 0]])
    dyn.attach(recorder, interval=1)
    dyn.run(3)
    dyn.dt *= 2
    dyn.run(3)
    with pytest.raises(ValueError, match="not evenly spaced"):
        recorder.spectrum()
    with pytest.raises(TypeError, match="integrator"):
        StructureFactorRecorder(atoms, [[0, 0, 0]])


@pytest.mark.slow
def test_long_runs_peak_on_the_bands_frozen_and_moving():
    """bcc Fe 8×8×8 (512 spins), 4000 steps, blocks of 512 samples averaged,
    frozen lattice with a field and an anisotropy: within a bin (4 meV). fcc
    Co (216 spins, bands up to 551 meV) with its Lennard-Jones lattice moving,
    5° cone, 8000 steps of 0.25 fs: within the Hann peak's half width (1.5
    bins, 6 meV): the spins' thermal softening (1 − cos 5°) and the midpoint
    rule's (ωh)²/12 lower the highest peaks by about 0.6 %."""
    extra = (UniaxialAnisotropy(0.001, [0, 0, 1]), Zeeman(2.0, [0, 0, 1]))
    prim, recorder = bcc_iron_run(8, 4000, 4, 0.5, extra=extra)
    spectrum = recorder.spectrum(block=512)
    check_peaks_on_bands(spectrum, magnon_bands(prim, recorder.qpath))
    prim = bulk("Co", "fcc", a=3.54)
    terms = [LennardJones(epsilon=0.4, sigma=2.2742, rc=4.7, cutoff="shift"),
             Exchange(BetheSlater(0.0446928, 0.003496, 1.4885), rc=4.0)]
    ase_spin.set_spins(prim, [0, 0, 1], magnitudes=1.72)
    prim.calc = SpinLatticeCalculator(terms)
    atoms = prim.repeat(6)
    ase_spin.set_spins(atoms, cone(len(atoms), np.random.default_rng(3), 5.0),
                       magnitudes=1.72)
    atoms.calc = SpinLatticeCalculator(terms)
    path = q_path(prim, supercell=atoms)
    dyn = CollectivePRK(atoms, 0.25 * units.fs)
    recorder = StructureFactorRecorder(dyn, path)
    dyn.attach(recorder, interval=8)
    dyn.run(8000)
    moved = np.abs(atoms.positions - prim.repeat(6).positions).max()
    assert moved > 1e-4  # the lattice did move
    check_peaks_on_bands(recorder.spectrum(block=512), magnon_bands(prim, path),
                         tolerance_bins=1.5)
