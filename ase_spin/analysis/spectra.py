r"""The dynamical structure factor S(q, ω) of a spin run: what inelastic neutron
scattering measures, and what linear spin-wave theory predicts
(:mod:`ase_spin.analysis.lswt`).

The spin Fourier components of a sample at time t,

.. math:: \mathbf s(\mathbf q, t) = \sum_i \mathbf s_i(t)\, e^{-i\mathbf q\cdot\mathbf r_i},

are taken over the magnetic atoms with unit spins s_i (or the moments μ_i s_i,
``moments=True``) at the **reference positions** r_i of the first sample (the
lattice sites: what spin-wave theory describes; for q held by a periodic
supercell, :func:`~ase_spin.analysis.qpath.q_path`, the phase is the same for any
periodic image, so atoms wrapped across the cell do not matter), or at the
positions of each sample (``positions="current"``: the thermal displacements then
enter as a Debye–Waller factor and magnon–phonon terms; only meaningful for q
held by the cell, since wrapping an atom changes its phase otherwise).

From a series of samples every Δt, :func:`dynamical_structure_factor` forms,
in blocks of L samples (Welch's method: overlapping blocks, a window w_n, Hann
by default, averaged over the blocks of all runs given),

.. math:: S^{\alpha\alpha}(\mathbf q, E_k) = \frac{\langle |X^\alpha_k(\mathbf q)|^2\rangle_{\rm blocks}}
          {N\,L\,\overline{w^2}\;\Delta E},\qquad
          X^\alpha_k = \sum_{n=0}^{L-1} w_n\,\delta s^\alpha(\mathbf q, t_n)\,e^{+i\omega_k t_n},

with E_k = ħω_k (meV), ω_k = 2πk/(LΔt), the bin width ΔE = 2πħ/(LΔt), N the
number of magnetic atoms and δs = s − ⟨s⟩_t (the time mean of each run removed:
the elastic, Bragg part is not in S). The normalisation is the sum rule

.. math:: \sum_k S^{\alpha\alpha}(\mathbf q, E_k)\,\Delta E = \frac{1}{N}\langle|\delta s^\alpha(\mathbf q)|^2\rangle,

the equal-time correlation (the static structure factor), exactly for the
window-weighted mean over the blocks (Parseval). S is per magnetic atom, in 1/meV.
A wave δs_i ∝ Re u e^{i(q·r_i − ω₀t)} (ω₀ > 0: a magnon of wave vector q) appears
at E = +ħω₀ in S(q, E) and at −ħω₀ in S(−q, E): positive energies at q are the
magnons of q (and S(q, −E) = S(−q, E) for classical spins).

Components, in the frame (e₁, e₂, n) of an axis n (default: the mean
magnetisation of the runs): ``longitudinal`` S^{nn}, ``transverse`` S^{11} +
S^{22}, and the transverse split by the sense of precession about n,
``plus`` from s⁺ = (s₁ + i s₂)/√2 and ``minus`` from s⁻ = (s₁ − i s₂)/√2
(``plus + minus = transverse``); ``total`` = transverse + longitudinal.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from ase.io import read

from ..conventions import PHYSICAL
from ..spins import get_moments, split_moments
from ..terms.base import tangent_directions
from ..validate import flag, integer, positive_scalar, real_scalar, unit_vector
from .plotting import plot_spectrum
from .qpath import QPath, as_qpath

__all__ = ["SpinSeries", "StructureFactorRecorder", "read_spin_series", "Spectrum",
           "dynamical_structure_factor"]

#: relative tolerance on the spacing of samples in time
_EVEN = 1e-6
#: meV per eV
MEV = 1000.0


@dataclass
class SpinSeries:
    """Spin Fourier components of one run, sampled every ``dt``.

    ``sq``: (T, M, 3) complex s(q, t) for the M wave vectors of ``qpath``;
    ``dt``: the time between samples (ASE time units); ``natoms``: the number
    of magnetic atoms N; ``magnetisation``: (T, 3) Σ_i s_i per sample (the
    default axis of the longitudinal component); ``hbar``: ħ (eV·(ASE time))
    that turns ω into energies (the integrator's)."""

    sq: np.ndarray
    dt: float
    natoms: int
    qpath: QPath
    magnetisation: np.ndarray
    hbar: float = PHYSICAL.hbar

    def __len__(self):
        return len(self.sq)


class _Fourier:
    """s(q) of one configuration, with the phases of the reference positions
    kept (the bookkeeping :class:`StructureFactorRecorder` and
    :func:`read_spin_series` share)."""

    def __init__(self, q, positions, moments):
        self.qpath = as_qpath(q)
        if not isinstance(positions, str) or positions not in ("reference", "current"):
            raise ValueError(f'positions must be "reference" or "current", got {positions!r}')
        self.positions = positions
        self.moments = flag(moments, "moments")
        self.magnetic = None
        self.phases = None

    def __call__(self, atoms):
        """(s(q) (M, 3) complex, Σ_i s_i) of ``atoms`` now."""
        vectors = get_moments(atoms)
        spins, mu = split_moments(vectors)
        magnetic = mu > 0.0
        if self.magnetic is None:
            if not magnetic.any():
                raise ValueError("the atoms carry no magnetic moments (initial_magmoms): "
                                 "no spins to correlate")
            self.magnetic = magnetic
        elif magnetic.shape != self.magnetic.shape or np.any(magnetic != self.magnetic):
            raise ValueError("the magnetic atoms changed between samples: S(q, ω) needs the "
                             "same spins throughout")
        weights = vectors if self.moments else spins
        weights = weights[self.magnetic]
        if self.phases is None or self.positions == "current":
            r = atoms.get_positions()[self.magnetic]
            self.phases = np.exp(-1j * (self.qpath.q @ r.T))
        return self.phases @ weights, weights.sum(axis=0)


class StructureFactorRecorder:
    """Records s(q, t) during a run, for S(q, ω)::

        rec = StructureFactorRecorder(dyn, q_path(crystal, supercell=atoms))
        dyn.attach(rec, interval=10)
        dyn.run(5000)
        spectrum = rec.spectrum(block=256)

    ``dyn``: the integrator (its Atoms are read at each call, its
    ``get_time()`` gives the sample times, its ħ turns ω into energies).
    ``q``: a :class:`~ase_spin.analysis.qpath.QPath`, an ASE ``BandPath`` or
    (M, 3) Cartesian wave vectors (1/Å, with 2π). ``positions``: "reference"
    (the first sample's, default) or "current" (see the module docstring).
    ``moments``: correlate μ_i s_i instead of unit spins.

    Samples must be evenly spaced in time: attach with a fixed interval and
    keep ``dyn.dt``. A second call at the same time (ASE calls the observers
    at step 0 of a run) is not recorded twice.

    It reads only positions and spins, so it declares ``needs_results =
    False``: the integrators then compute no energies or calculator results
    for the steps it samples.
    """

    #: read by the integrators: this observer needs no energies or forces
    needs_results = False

    def __init__(self, dyn, q, *, positions="reference", moments=False):
        if not hasattr(dyn, "atoms") or not hasattr(dyn, "get_time"):
            raise TypeError(f"StructureFactorRecorder takes the integrator (an ASE "
                            f"MolecularDynamics), got {type(dyn).__name__}")
        self.dyn = dyn
        self._fourier = _Fourier(q, positions, moments)
        self.qpath = self._fourier.qpath
        self.times = []
        self._sq = []
        self._magnetisation = []

    def __call__(self):
        t = float(self.dyn.get_time())
        if self.times and t == self.times[-1]:
            return
        sq, m = self._fourier(self.dyn.atoms)
        self.times.append(t)
        self._sq.append(sq)
        self._magnetisation.append(m)

    def __len__(self):
        return len(self.times)

    def series(self):
        """The samples so far as a :class:`SpinSeries`."""
        dt = _spacing(np.array(self.times), "the recorded samples")
        hbar = real_scalar(getattr(self.dyn, "hbar", PHYSICAL.hbar), "hbar")
        return SpinSeries(np.array(self._sq), dt, int(self._fourier.magnetic.sum()),
                          self.qpath, np.array(self._magnetisation), hbar)

    def spectrum(self, **options):
        """:func:`dynamical_structure_factor` of this run (same options)."""
        return dynamical_structure_factor(self.series(), **options)


def _spacing(times, what):
    if len(times) < 2:
        raise ValueError(f"{what}: at least two samples are needed, got {len(times)}")
    steps = np.diff(times)
    dt = float(np.mean(steps))
    if dt <= 0.0 or np.max(np.abs(steps - dt)) > _EVEN * abs(dt):
        raise ValueError(f"{what} are not evenly spaced in time (spacings from "
                         f"{steps.min():.6g} to {steps.max():.6g}): attach the recorder with "
                         f"a fixed interval and keep dyn.dt during the run")
    return dt


def read_spin_series(frames, q, timestep, *, positions="reference", moments=False,
                     hbar=None):
    """A :class:`SpinSeries` from a trajectory: a file name (read with
    ``ase.io.read(name, ":")``) or a list of Atoms, spins in
    ``initial_magmoms`` as ase_spin writes them.

    ``timestep``: the time between frames (ASE time units: the integrator's
    timestep times its ``loginterval``; trajectory frames carry no time).
    ``hbar``: the ħ of the run (default: CODATA, the physical conventions).
    """
    if isinstance(frames, (str, bytes)) or hasattr(frames, "__fspath__"):
        frames = read(frames, ":")
    frames = list(frames)
    dt = positive_scalar(timestep, "timestep (time between frames)")
    fourier = _Fourier(q, positions, moments)
    if len(frames) < 2:
        raise ValueError(f"a spectrum needs at least two frames, got {len(frames)}")
    samples = [fourier(atoms) for atoms in frames]
    hbar = PHYSICAL.hbar if hbar is None else positive_scalar(hbar, "hbar")
    return SpinSeries(np.array([s for s, _ in samples]), dt, int(fourier.magnetic.sum()),
                      fourier.qpath, np.array([m for _, m in samples]), hbar)


@dataclass
class Spectrum:
    """S(q, E) on a q path (see the module docstring).

    ``energy_meV``: (K,) energies E = ħω in meV, ascending, negative and
    positive; ``transverse``, ``longitudinal``, ``plus``, ``minus``: (M, K)
    spectra in 1/meV per magnetic atom; ``resolution_meV``: the bin width
    ΔE = 2πħ/(LΔt) (a Hann window's peak is about two bins wide at half
    height); ``blocks``: how many blocks were averaged; ``axis``: the
    longitudinal direction n."""

    qpath: QPath
    energy_meV: np.ndarray
    transverse: np.ndarray
    longitudinal: np.ndarray
    plus: np.ndarray
    minus: np.ndarray
    resolution_meV: float
    blocks: int
    axis: np.ndarray

    @property
    def total(self):
        return self.transverse + self.longitudinal

    def component(self, name):
        """One of "transverse", "longitudinal", "plus", "minus", "total"."""
        if name not in ("transverse", "longitudinal", "plus", "minus", "total"):
            raise ValueError(f'component must be "transverse", "longitudinal", "plus", "minus" '
                             f'or "total", got {name!r}')
        return getattr(self, name)

    def sum_rule(self, component="transverse"):
        """Σ_E S(q, E) ΔE per q: the equal-time (1/N)⟨|δs(q)|²⟩ of the component."""
        return self.component(component).sum(axis=1) * self.resolution_meV

    def peaks(self, component="transverse", min_meV=None):
        """The energy (meV) of the highest peak of each q at E > ``min_meV``
        (default: one bin above 0, away from the remainder of the elastic
        line), refined by a parabola through the top bin and its neighbours."""
        s = self.component(component)
        lo = self.resolution_meV if min_meV is None else real_scalar(min_meV, "min_meV")
        keep = np.flatnonzero(self.energy_meV > lo)
        if len(keep) < 3:
            raise ValueError(f"fewer than three energies above {lo:g} meV")
        out = np.empty(len(s))
        for m, row in enumerate(s[:, keep]):
            k = int(np.argmax(row))
            e = self.energy_meV[keep[k]]
            if 0 < k < len(row) - 1:
                a, b, c = row[k - 1], row[k], row[k + 1]
                den = a - 2.0 * b + c
                if den < 0.0:
                    e += 0.5 * (a - c) / den * self.resolution_meV
            out[m] = e
        return out

    def plot(self, ax=None, bands=None, component="transverse", max_meV=None, log=True,
             **options):
        """An intensity map over the q path (see
        :func:`~ase_spin.analysis.plotting.plot_spectrum`)."""
        return plot_spectrum(self, ax=ax, bands=bands, component=component, max_meV=max_meV,
                             log=log, **options)


def dynamical_structure_factor(series, *, block=None, window="hann", overlap=0.5, axis=None):
    """S(q, E) from one :class:`SpinSeries` (or a recorder) or a list of them
    (runs of the same scene: their blocks are averaged).

    ``block``: samples per block L (default: the whole of the shortest run;
    shorter blocks average more and resolve less, ΔE = 2πħ/(LΔt)).
    ``window``: "hann" (default) or "none" (rectangular). ``overlap``: the
    fraction of a block the next one overlaps (0 ≤ overlap < 1; 0.5 with
    Hann gives every sample the same weight). ``axis``: the longitudinal
    direction (default: the mean magnetisation of all samples).
    """
    runs = series if isinstance(series, (list, tuple)) else [series]
    runs = [r.series() if isinstance(r, StructureFactorRecorder) else r for r in runs]
    if not runs or not all(isinstance(r, SpinSeries) for r in runs):
        raise TypeError("dynamical_structure_factor takes SpinSeries or recorders")
    first = runs[0]
    for r in runs[1:]:
        if (r.sq.shape[1:] != first.sq.shape[1:] or r.natoms != first.natoms
                or not np.allclose(r.qpath.q, first.qpath.q, rtol=0.0, atol=1e-12)):
            raise ValueError("runs averaged together need the same wave vectors and atoms")
        if abs(r.dt - first.dt) > _EVEN * first.dt or abs(r.hbar - first.hbar) > 1e-12 * first.hbar:
            raise ValueError("runs averaged together need the same time between samples and ħ")
    shortest = min(len(r) for r in runs)
    L = shortest if block is None else integer(block, "block", minimum=4)
    if L < 4 or L > shortest:
        raise ValueError(f"block must be between 4 and the shortest run ({shortest} samples), "
                         f"got {L}")
    overlap = real_scalar(overlap, "overlap")
    if not 0.0 <= overlap < 1.0:
        raise ValueError(f"overlap must be in [0, 1), got {overlap}")
    if window == "hann":
        w = np.hanning(L + 1)[:L]  # periodic Hann: 50 % overlaps sum to a constant
    elif window == "none":
        w = np.ones(L)
    else:
        raise ValueError(f'window must be "hann" or "none", got {window!r}')
    if axis is None:
        total = sum(r.magnetisation.sum(axis=0) for r in runs)
        if not np.linalg.norm(total) > 1e-12 * first.natoms * sum(len(r) for r in runs):
            total = np.array([0.0, 0.0, 1.0])  # no mean magnetisation: any axis will do
        axis = total
    n = np.array(unit_vector(axis, "axis"))
    e1, e2 = (t[0] for t in tangent_directions(n[None, :]))
    frame = np.array([e1, e2, n])
    step = max(1, int(round(L * (1.0 - overlap))))
    power = np.zeros((3, first.sq.shape[1], L))
    blocks = 0
    for r in runs:
        local = r.sq @ frame.T                      # (T, M, 3): s1, s2, s_n
        local = local - local.mean(axis=0)
        parts = np.stack([(local[..., 0] + 1j * local[..., 1]) / np.sqrt(2.0),
                          (local[..., 0] - 1j * local[..., 1]) / np.sqrt(2.0),
                          local[..., 2]])             # (3, T, M): s+, s-, s_n
        for start in range(0, len(r) - L + 1, step):
            chunk = parts[:, start:start + L, :] * w[None, :, None]
            # Σ_n x_n e^{+iω_k t_n}: L·ifft
            X = np.fft.ifft(chunk, axis=1) * L
            power += np.transpose(np.abs(X) ** 2, (0, 2, 1))
            blocks += 1
    dE = 2.0 * np.pi * first.hbar / (L * first.dt) * MEV
    scale = 1.0 / (blocks * first.natoms * L * np.mean(w ** 2) * L * dE)
    order = np.argsort(np.fft.fftfreq(L))
    energies = np.fft.fftfreq(L)[order] * L * dE
    plus, minus, longitudinal = (power[k][:, order] * scale for k in range(3))
    return Spectrum(first.qpath, energies, plus + minus, longitudinal, plus, minus, dE, blocks,
                    n)
