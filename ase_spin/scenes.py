"""The reference scenes: the paper's chain, the fcc Co crystal of the LAMMPS
comparison and a DMI monolayer with skyrmions (the energy-landscape checks
against LAMMPS and Spirit), as ready-to-run ASE Atoms (calculator and spins
attached)."""

from __future__ import annotations

import warnings

import numpy as np
from ase import Atoms
from ase.build import bulk

from .calculator import SpinLatticeCalculator
from .spins import set_spins
from .constants import MU_B_LAMMPS
from .terms import (DMI, BetheSlater, BiquadraticExchange, Cubic, CubicAnisotropy, Dipolar,
                    Exchange, LennardJones, ShellExchange, UniaxialAnisotropy, Zeeman)
from .validate import ImplausibleParameterWarning

__all__ = ["paper_chain", "paper_chain_terms", "fcc_cobalt", "fcc_cobalt_terms", "cone",
           "field_anisotropy_terms", "other_spin_terms", "dipolar_sums", "FIELD_ANISOTROPY_LAMMPS",
           "dmi_film", "neel_skyrmion"]


def paper_chain_terms():
    """The paper's Hamiltonian in this package's conventions (docs/conventions.md):
    LJ with ε = U0 = 1 eV, σ = r_m 2^(−1/6) Å, plain cutoff 1.9 Å (nearest
    neighbours only); H_m = +Σ J0 (1 − r/rc)³ w_i·w_{i+1} with J0 = 10 is the
    cubic exchange with J0 = −10 in E = −Σ J s_i·s_j. (The paper's reduced
    units: its J0 = 10 is no slip of units, so no ImplausibleParameterWarning.)"""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ImplausibleParameterWarning)
        coupling = Cubic(J0=-10.0, rc=1.5)
    return [LennardJones(epsilon=1.0, sigma=2.0 ** (-1.0 / 6.0), rc=1.9), Exchange(coupling)]


def paper_chain(n=30):
    """The paper's experiment: n atoms of mass 1 at x_k = k on a periodic line of
    length n, at rest, spins w_k ∝ (0.8 cos 2πk/n + 0.5 sin 4πk/n,
    0.8 sin 2πk/n + 0.5 cos 4πk/n, 1), under the paper's conventions (ħ = 1,
    the spin convention: the integrators' defaults follow them)."""
    k = np.arange(1, n + 1)
    atoms = Atoms(f"H{n}", positions=np.column_stack([k, np.zeros(n), np.zeros(n)]),
                  cell=[float(n), 10.0, 10.0], pbc=[True, False, False])
    atoms.set_masses(np.ones(n))
    w = np.column_stack([0.8 * np.cos(2 * np.pi * k / n) + 0.5 * np.sin(4 * np.pi * k / n),
                         0.8 * np.sin(2 * np.pi * k / n) + 0.5 * np.cos(4 * np.pi * k / n),
                         np.ones(n)])
    set_spins(atoms, w / np.linalg.norm(w, axis=1)[:, None])
    atoms.calc = SpinLatticeCalculator(paper_chain_terms(), conventions="paper")
    return atoms


def cone(n, rng, angle_deg=30.0):
    """n unit vectors uniform in a cone of half-angle ``angle_deg`` about +z."""
    cos_t = rng.uniform(np.cos(np.radians(angle_deg)), 1.0, n)
    phi = rng.uniform(0.0, 2.0 * np.pi, n)
    sin_t = np.sqrt(1.0 - cos_t**2)
    return np.column_stack([sin_t * np.cos(phi), sin_t * np.sin(phi), cos_t])


def fcc_cobalt_terms():
    """peers.md: LJ ε = 0.4 eV, σ = 2.2742 Å, rc = 4.7 Å shifted; Bethe–Slater
    exchange of LAMMPS examples/SPIN/cobalt_fcc, rc = 4.0 Å."""
    return [LennardJones(epsilon=0.4, sigma=2.2742, rc=4.7, cutoff="shift"),
            Exchange(BetheSlater(J1=0.0446928, J2=0.003496, J3=1.4885), rc=4.0)]


#: :func:`field_anisotropy_terms` as LAMMPS ``fix precession/spin`` arguments
FIELD_ANISOTROPY_LAMMPS = "zeeman 10.0 0.0 0.0 1.0 anisotropy 0.01 1.0 0.0 0.0"


def field_anisotropy_terms():
    """A 10 T field along z (LAMMPS's g = 2 and μB under either conventions) and a uniaxial anisotropy
    K = 0.01 eV along x: the single-site terms added to the fcc Co scene for
    the work–precision and long-run comparisons (``fcc_cobalt(extra=...)``)."""
    return [Zeeman(10.0, [0.0, 0.0, 1.0], g=2.0, mu_B=MU_B_LAMMPS),
            UniaxialAnisotropy(0.01, [1.0, 0.0, 0.0])]


def other_spin_terms():
    """Every other spin term the package has, beside fcc_cobalt's exchange: the
    field and anisotropy of :func:`field_anisotropy_terms`, a cubic
    anisotropy, interfacial DMI, biquadratic exchange, shell exchange and the
    dipolar interaction with a cutoff (the set ``ase-spin compile`` compiles
    every term's kernels with; Ewald's real-space part runs the same kernels)."""
    return [*field_anisotropy_terms(), CubicAnisotropy(0.002, 0.001),
            DMI(0.003, [0.0, 0.0, 1.0], rc=2.6),
            BiquadraticExchange(BetheSlater(0.01, 0.001, 1.5), BetheSlater(0.002, 0.0005, 1.5),
                                rc=2.6),
            ShellExchange([(2.503, 0.02), (3.54, 0.004)], tol=0.2), Dipolar(rc=4.0)]


def dipolar_sums(methods=("ewald", "pme")):
    """The dipolar interaction's long-range sums (rc = 4 Å, accuracy 1e-4: cheap
    at fcc Co's sizes): the Ewald sum over k-vectors and on a mesh, the set
    ``ase-spin compile`` compiles their kernels with (the mesh's spread and
    gather at 2048 atoms too, where they run threaded)."""
    return [Dipolar(4.0, method, accuracy=1e-4) for method in methods]


def fcc_cobalt(n=5, temperature_K=100.0, cone_deg=30.0, seed=0, magnitude=1.72, extra=(),
               conventions="physical"):
    """The benchmark scene of peers.md: fcc Co, a = 3.54 Å, 4n³ atoms in a cubic
    periodic box, mass 58.93 amu, spins uniform in a ``cone_deg`` cone about +z,
    Maxwell–Boltzmann velocities at ``temperature_K`` (total momentum zeroed).
    ``extra``: more terms for the Hamiltonian (e.g. :func:`field_anisotropy_terms`).
    ``conventions``: the calculator's (``"lammps"`` where it is compared with LAMMPS
    step for step)."""
    atoms = bulk("Co", "fcc", a=3.54, cubic=True).repeat(n)
    atoms.set_masses(np.full(len(atoms), 58.93))
    rng = np.random.default_rng(seed)
    set_spins(atoms, cone(len(atoms), rng, cone_deg), magnitudes=magnitude)
    if temperature_K > 0:
        from ase import units

        m = atoms.get_masses()[:, None]
        p = rng.normal(size=(len(atoms), 3)) * np.sqrt(m * units.kB * temperature_K)
        p -= p.sum(axis=0) / len(atoms)
        atoms.set_momenta(p)
    atoms.calc = SpinLatticeCalculator([*fcc_cobalt_terms(), *extra], conventions=conventions)
    return atoms


def dmi_film(n=16, J=0.010, D=0.003, K=0.001, field=2.0, magnitude=2.2, a=2.5, spins=None):
    """A square magnetic monolayer of n × n sites (lattice constant ``a`` Å,
    periodic in-plane; the cell's 10 Å along z is periodic too, beyond every
    cutoff, so that LAMMPS takes it as it is) with nearest-neighbour exchange
    J (eV; a Bethe–Slater J(r) = 4 J1 (r/a)² e^{−(r/a)²} with J(a) = J, cut at
    1.2 a), interfacial DMI D (eV, D_ij = D e_ij × ẑ), uniaxial anisotropy K
    (eV) along z and a field ``field`` (T) along +z; moments ``magnitude`` μB.
    Every term maps on LAMMPS SPIN (docs/lammps.md) and on Spirit. The spins
    are ``spins`` ((n², 3)), default all along +z (the ferromagnet); site
    (i, j) is atom i + n j. With the defaults (J = 10 meV, D = 3 meV,
    K = 1 meV, 2 T) the ferromagnet is the ground state and an isolated Néel
    skyrmion (:func:`neel_skyrmion`, relaxed) a metastable state some 60 meV
    above it (with a weaker field or anisotropy, skyrmions or spirals can
    become lower than the ferromagnet on a large film)."""
    ij = np.array([(i, j) for j in range(n) for i in range(n)], dtype=float)
    atoms = Atoms(f"Fe{n * n}", positions=np.column_stack([ij * a, np.zeros(n * n)]),
                  cell=[n * a, n * a, 10.0], pbc=True)
    set_spins(atoms, np.tile([0.0, 0.0, 1.0], (n * n, 1)) if spins is None else spins,
              magnitudes=magnitude)
    rc = 1.2 * a  # nearest neighbours only (the next are at a√2)
    atoms.calc = SpinLatticeCalculator([
        Exchange(BetheSlater(J * np.e / 4.0, 0.0, a), rc=rc), DMI(D, [0.0, 0.0, 1.0], rc=rc),
        UniaxialAnisotropy(K, [0.0, 0.0, 1.0]), Zeeman(field, [0.0, 0.0, 1.0])])
    return atoms


def neel_skyrmion(positions, radius, centre=None, chirality=1):
    """Unit spins of a Néel skyrmion profile in the xy plane: θ(ρ) = 2 atan(R/ρ)
    from +z about ``centre`` (default: the middle of the positions' extent,
    off every site by 0.01 Å so that no spin sits on the core), s = (χ sin θ
    ρ̂, cos θ): down at the core, up far away, in-plane part radial (χ = +1:
    outwards, the chirality :func:`dmi_film`'s DMI favours)."""
    positions = np.asarray(positions, dtype=float)
    if centre is None:
        centre = 0.5 * (positions[:, :2].min(axis=0) + positions[:, :2].max(axis=0)) + 0.01
    d = positions[:, :2] - np.asarray(centre, dtype=float)[:2]
    rho = np.linalg.norm(d, axis=1)
    theta = 2.0 * np.arctan2(radius, rho)
    radial = d / np.where(rho > 0.0, rho, 1.0)[:, None]
    return np.column_stack([chirality * np.sin(theta)[:, None] * radial, np.cos(theta)])

