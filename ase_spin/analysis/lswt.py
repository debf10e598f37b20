r"""Linear spin-wave theory (LSWT) for any of the package's spin terms, on a
periodic ground state.

Around a state where every spin is parallel to its field, B_i⁰ = λ_i s_i⁰
(λ_i = s_i⁰·B_i⁰), a small turn δs_i ⊥ s_i⁰ changes the fields by
δB_i = Σ_j M_ij δs_j, M_ij = ∂B_i/∂s_j = −∂²E/∂s_i∂s_j, and the integrators'
equation of motion ds_i/dt = (σ r_i/ħ) s_i × B_i (:mod:`ase_spin.conventions`:
σ = −1 for a moment, r_i = g/μ_i or 1) becomes, to first order,

.. math:: \hbar\,\frac{d\,\delta\mathbf s_i}{dt} = -\sigma r_i\, \mathbf s_i^0\times
          \sum_j K_{ij}\,\delta\mathbf s_j,\qquad
          K_{ij} = P_i^{T}\,(\lambda_i\delta_{ij} - M_{ij})\,P_j ,

with P_i = (e₁, e₂) a right-handed tangent frame of s_i⁰ (K is the Hessian of
the energy on the spheres). For a Bloch wave δs_j = u_b e^{iq·r_j} (b the atom
of the cell that j repeats) the 2n × 2n matrix is

.. math:: K_{ab}(\mathbf q) = \sum_{j \equiv a} K_{jb}\, e^{-i\mathbf q\cdot(\mathbf r_j - \mathbf r_b)}

(sum over the copies j of cell atom a around atom b), and with
A = −σ diag(r_a J), J = [[0, −1], [1, 0]] the rotation by 90° in each tangent
plane, the magnon energies of wave vector q are the n positive eigenvalues of
the Hermitian K^{1/2}(iA)K^{1/2} (those of iAK: a wave
Re u e^{i(q·r − ωt)} with ω > 0). They do not depend on ħ; the integrators'
frequencies are E/ħ with their ħ.

**Term-agnostic**: M comes from the terms' own fields (the same compiled
operators the integrators call), by central differences: each spin of the cell
is turned by ±ε along e₁ and e₂ inside a supercell large enough that each
neighbour within the Hamiltonian's cutoff is one atom of it (every lattice
vector of the supercell longer than twice the cutoff), and the change of every
field is read off. Exchange with any J(r), DMI, fields and uniaxial anisotropy
are linear in the spins (exact up to round-off); cubic anisotropy and
biquadratic exchange have an error O(ε²). A term coupling spins farther than
its cutoff (the Ewald sum of ``Dipolar``) is refused.

Any periodic state given in the cell works: a ferromagnet (one atom per cell
or more), a collinear antiferromagnet or any commensurate non-collinear state,
as long as it is an energy minimum (K(q) positive semi-definite; otherwise
the error names the wave vector). The lattice is held at the given positions
(the frozen lattice; the magnon–phonon coupling of a moving lattice is not
included). Incommensurate spirals (a rotating frame) are not.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from ase.geometry import find_mic

from ..calculator import SpinLatticeCalculator
from ..conventions import conventions as as_conventions
from ..hamiltonian import Hamiltonian
from ..spins import get_moments, split_moments
from ..terms.base import Want, tangent_directions
from ..validate import positive_scalar
from .qpath import QPath, as_qpath

__all__ = ["MagnonBands", "magnon_bands", "spin_wave_matrix"]

#: the turn (rad) of the central differences of the fields
TURN = 1e-4
#: largest torque |s × B| / max |B| of a state taken as an equilibrium
TORQUE_TOL = 1e-6
#: most negative eigenvalue of K(q), relative to its largest, of a minimum
CURVATURE_TOL = 1e-7
#: meV per eV
MEV = 1000.0
_FIELD = Want(magnetic_forces=True)


@dataclass
class MagnonBands:
    """Spin-wave energies along a q path: ``energy_meV`` (M, n), ascending at
    each q, n the magnetic atoms of the cell; ``qpath`` the
    :class:`~ase_spin.analysis.qpath.QPath`."""

    qpath: QPath
    energy_meV: np.ndarray

    def __len__(self):
        return len(self.qpath)


def _hamiltonian(atoms, hamiltonian):
    if hamiltonian is None:
        calc = getattr(atoms, "calc", None)
        if not isinstance(calc, SpinLatticeCalculator):
            raise TypeError("magnon_bands needs the atoms' SpinLatticeCalculator, or "
                            "hamiltonian= (a Hamiltonian or SpinLatticeCalculator)")
        return calc.hamiltonian
    if isinstance(hamiltonian, SpinLatticeCalculator):
        return hamiltonian.hamiltonian
    if isinstance(hamiltonian, Hamiltonian):
        return hamiltonian
    return Hamiltonian(hamiltonian)


def _rates(mu, gyromagnetic, g):
    """r_i of the precession, as the integrators' (``_precession_rates``)."""
    if gyromagnetic == "lammps":
        return np.ones_like(mu)
    return g / mu


def _repeats(cell, pbc, cutoff):
    """Repeats of the cell along its periodic directions for which every lattice
    vector of the supercell is longer than 2·cutoff (its shortest one is at
    least its smallest height): no two copies of one atom lie within the
    cutoff of a spin."""
    volume = abs(np.linalg.det(cell))
    out = []
    for k in range(3):
        if not pbc[k] or cutoff == 0.0:
            out.append(1)
            continue
        height = volume / np.linalg.norm(np.cross(cell[(k + 1) % 3], cell[(k + 2) % 3]))
        out.append(int(np.floor(2.0 * cutoff * (1.0 + 1e-9) / height)) + 1)
    return tuple(out)


class _Fields:
    """B(W) of all spin terms on a supercell, from the terms' operators (through
    the Evaluator, which runs them serially or threaded by the system's size)."""

    def __init__(self, hamiltonian, atoms, mu):
        self.evaluator = hamiltonian.bind(atoms.numbers, atoms.cell[:], atoms.pbc, mu)
        self.operators = self.evaluator.spin_operators(atoms.positions)

    def __call__(self, W):
        return self.evaluator.spin(self.operators, W, _FIELD).magnetic_forces


def spin_wave_matrix(atoms, q, *, hamiltonian=None, turn=TURN):
    """K(q) (see the module docstring): (M, 2n, 2n) Hermitian matrices in eV for
    the M wave vectors ``q`` (anything :func:`magnon_bands` takes), on the
    tangent frames ``frames`` (n, 2, 3) of the n magnetic atoms of ``atoms``
    (the state s⁰ in its ``initial_magmoms``). Returns (K, frames, magnetic
    indices, moments μ)."""
    ham = _hamiltonian(atoms, hamiltonian)
    qpath = as_qpath(q)
    turn = positive_scalar(turn, "turn")
    spins, mu = split_moments(get_moments(atoms))
    magnetic = np.flatnonzero(mu > 0.0)
    if len(magnetic) == 0:
        raise ValueError("the atoms carry no magnetic moments (initial_magmoms): no spin waves")
    cell = atoms.cell[:]
    pbc = atoms.pbc
    if pbc.any() and atoms.cell.rank < 3:
        raise ValueError("spin waves of a periodic crystal need its cell with three vectors")
    reps = _repeats(cell, pbc, ham.cutoff)
    natoms = len(atoms)
    big = atoms.repeat(reps)
    big.calc = None
    big_spins = np.tile(spins, (np.prod(reps), 1))
    big_mu = np.tile(mu, np.prod(reps))
    fields = _Fields(ham, big, big_mu)
    B0 = fields(big_spins)
    # the copy of cell atom j: the first natoms of atoms.repeat are the cell itself
    home = np.arange(len(big)) % natoms
    scale = float(np.max(np.linalg.norm(B0[:natoms][magnetic], axis=1)))
    torque = np.linalg.norm(np.cross(spins[magnetic], B0[magnetic]), axis=1)
    worst = int(np.argmax(torque))
    if torque[worst] > TORQUE_TOL * max(scale, 1e-300):
        raise ValueError(
            f"the spins are not in equilibrium: atom {magnetic[worst]} feels a torque "
            f"|s × B| = {torque[worst]:.3g} eV (fields up to {scale:.3g} eV); spin waves "
            f"need a ground state: relax it first (ase_spin.relax_spins)")
    lam = np.einsum("ij,ij->i", spins, B0[:natoms])
    t1, t2 = tangent_directions(spins[magnetic])
    frames = np.stack([t1, t2], axis=1)                # (n, 2, 3)
    slot = -np.ones(natoms, dtype=int)
    slot[magnetic] = np.arange(len(magnetic))
    responding = np.flatnonzero(big_mu > 0.0)
    sub = slot[home[responding]]                       # magnetic cell index of each copy
    n = len(magnetic)
    K = np.zeros((len(qpath), 2 * n, 2 * n), dtype=complex)
    onehot = np.zeros((len(responding), n))
    onehot[np.arange(len(responding)), sub] = 1.0
    for b_slot, b in enumerate(magnetic):
        d = big.positions[responding] - big.positions[b]
        d, dist = find_mic(d, big.cell[:], big.pbc)
        near = dist <= ham.cutoff * (1.0 + 1e-9)
        # the Bloch sum runs over the spins within the cutoff (the only ones a
        # finite-range term moves: checked below)
        phase = np.exp(-1j * (qpath.q @ d[near].T))    # (M, near)
        for c in range(2):
            W = big_spins.copy()
            W[b] = spins[b] + turn * frames[b_slot, c]
            Bp = fields(W)
            W[b] = spins[b] - turn * frames[b_slot, c]
            Bm = fields(W)
            dB = (Bp - Bm)[responding] / (2.0 * turn)  # M_jb e_c for every spin j
            if (~near).any() and (np.abs(dB[~near]).max()
                                  > 1e-9 * max(np.abs(dB).max(), 1e-300)):
                raise ValueError(
                    "a spin term couples spins beyond the Hamiltonian's cutoff (a long-range "
                    "sum such as Dipolar(method='ewald')): spin waves here take terms of "
                    "finite range")
            # the response of copy j on the tangent frame of the cell atom it repeats
            proj = np.einsum("jk,jrk->jr", dB[near], frames[sub[near]])  # (near, 2)
            for r in range(2):
                K[:, r::2, 2 * b_slot + c] -= (phase * proj[:, r]) @ onehot[near]
    for a_slot, a in enumerate(magnetic):
        K[:, 2 * a_slot, 2 * a_slot] += lam[a]
        K[:, 2 * a_slot + 1, 2 * a_slot + 1] += lam[a]
    asym = np.abs(K - np.conj(np.transpose(K, (0, 2, 1)))).max()
    if asym > 1e-6 * max(np.abs(K).max(), 1e-300):
        raise ValueError(f"the fields' response is not symmetric (up to {asym:.3g} eV): "
                         f"a term's field is not −∂E/∂s, or it couples copies of one atom")
    K = 0.5 * (K + np.conj(np.transpose(K, (0, 2, 1))))
    return K, frames, magnetic, mu


def magnon_bands(atoms, q, *, hamiltonian=None, dynamics=None, gyromagnetic=None, g=None,
                 precession=None):
    """Spin-wave energies ħω(q) (meV) of the state on ``atoms`` (its cell, spins
    and calculator: the crystal's unit cell, or a magnetic cell for an
    antiferromagnet), at the wave vectors ``q`` (a
    :class:`~ase_spin.analysis.qpath.QPath`, an ASE ``BandPath`` or (M, 3)
    Cartesian, 1/Å with 2π). See the module docstring.

    The precession follows the integrator the bands are compared with:
    ``dynamics`` (its ``gyromagnetic``, ``g`` and ``precession``), or those
    given here, by default the calculator's conventions (physical: r_i =
    g_e/μ_i, the Larmor precession; "lammps": r_i = 1).
    ``hamiltonian``: terms, a Hamiltonian or a calculator instead of
    ``atoms.calc``.

    For a ferromagnet of one atom per cell with E = −Σ_{i<j} J(r_ij) s_i·s_j −
    Σ_i K (s_i·n)² − Σ_i g_Z μB μ s_i·H (n, H along the spins):
    ħω(q) = r [Σ_δ J(|δ|)(1 − cos q·δ) + 2K + g_Z μB μ H], δ over all
    neighbour vectors, r = g/μ (physical) or 1 (LAMMPS's).
    """
    ham = _hamiltonian(atoms, hamiltonian)
    conv = as_conventions(ham.conventions)
    if dynamics is not None:
        gyromagnetic = dynamics.gyromagnetic if gyromagnetic is None else gyromagnetic
        g = dynamics.g if g is None else g
        precession = dynamics.precession if precession is None else precession
    gyromagnetic = conv.gyromagnetic if gyromagnetic is None else gyromagnetic
    if gyromagnetic not in ("moment", "lammps"):
        raise ValueError(f'gyromagnetic must be "moment" or "lammps", got {gyromagnetic!r}')
    g = conv.g if g is None else positive_scalar(g, "g")
    precession = conv.precession if precession is None else precession
    if precession not in ("moment", "spin"):
        raise ValueError(f'precession must be "moment" or "spin", got {precession!r}')
    sigma = -1.0 if precession == "moment" else 1.0
    qpath = as_qpath(q)
    K, frames, magnetic, mu = spin_wave_matrix(atoms, qpath, hamiltonian=ham)
    n = len(magnetic)
    rates = _rates(mu[magnetic], gyromagnetic, g)
    # iA = −iσ r J per atom: −iσ r [[0, −1], [1, 0]]
    iA = np.zeros((2 * n, 2 * n), dtype=complex)
    for a in range(n):
        iA[2 * a, 2 * a + 1] = 1j * sigma * rates[a]
        iA[2 * a + 1, 2 * a] = -1j * sigma * rates[a]
    energies = np.empty((len(qpath), n))
    # the scale of curvatures over all q (at Γ a Goldstone mode can be all there is)
    top = max(float(np.abs(K).max()), 1e-300)
    for m, Kq in enumerate(K):
        w, V = np.linalg.eigh(Kq)
        if w[0] < -CURVATURE_TOL * top:
            raise ValueError(
                f"the state is not an energy minimum: K(q) has a negative curvature "
                f"{w[0]:.3g} eV at q = {np.round(qpath.q[m], 6).tolist()} 1/Å (a spin wave "
                f"there would grow): spin waves need a stable ground state")
        root = (V * np.sqrt(np.clip(w, 0.0, None))) @ V.conj().T
        nu = np.linalg.eigvalsh(root @ iA @ root)
        energies[m] = np.clip(nu[n:], 0.0, None)
    return MagnonBands(qpath, energies * MEV)
