r"""Observers of a run: ``dyn.attach(observer, interval=k)`` on any ase_spin
integrator (``CollectivePRK``, ``SuzukiTrotter``, ``Langevin``) or on
:class:`~ase_spin.md.montecarlo.MonteCarlo`; each call measures the current
state and appends it to the observer's series (``observer.series``, one row
per call, with ``observer.steps`` the step or sweep numbers), from which the
averages and their errors follow (block averages:
:mod:`ase_spin.analysis.statistics`).

They read the spins from ``dyn.atoms`` (written there before observers run)
and energies from ``dyn.get_magnetic_energy()``, fields from
``dyn.get_spin_temperature_sums()``: nothing is recomputed that the
integrator has. With ``info=True`` an observer also puts its latest value in
``atoms.info[observer.name]``, which a ``Trajectory`` attached *after* it
writes into each frame; ``observer.write(path)`` saves the series as text.

Averages assume the samples come from equilibrium: discard the
equilibration first (``observer.reset()``, or ``discard=`` in the methods).
"""

from __future__ import annotations

import weakref

import numpy as np
from ase import units
from ase.neighborlist import neighbor_list

from ..spins import get_spins
from ..validate import integer, positive_scalar
from .statistics import block_average, jackknife
from .topology import LayerTriangulation

__all__ = ["Observer", "SublatticeMagnetisation", "TopologicalCharge", "SpinCorrelation",
           "Fluctuations", "SpinTemperature"]


class Observer:
    """Base of the observers: ``__call__`` appends :meth:`measure` to the
    series. Subclasses set ``name`` and implement :meth:`measure`.

    An observer measures through the integrator (spins, magnetisation, the
    magnetic energy, the spin-temperature sums), never from the calculator's
    results: it declares ``needs_results = False``, so that observing a step
    computes no forces, virial or trajectory frame (which a plain function
    attached to the dynamics gets, since it might read them)."""

    name = "observer"
    needs_results = False

    def __init__(self, dyn, info=False):
        self._dyn = weakref.ref(dyn)
        self.info = bool(info)
        self.steps = []
        self._values = []

    @property
    def dyn(self):
        dyn = self._dyn()
        if dyn is None:
            raise RuntimeError(f"the dynamics {type(self).__name__} observes no longer exists")
        return dyn

    def measure(self):
        raise NotImplementedError

    def __call__(self):
        value = self.measure()
        self.steps.append(self.dyn.nsteps)
        self._values.append(value)
        if self.info:
            self.dyn.atoms.info[self.name] = value

    def reset(self):
        """Forget the samples so far (e.g. after equilibration)."""
        self.steps.clear()
        self._values.clear()

    @property
    def series(self):
        """The samples, one row per call (an array)."""
        if not self._values:
            raise ValueError(f"{type(self).__name__} has no samples yet: attach it with "
                             "dyn.attach(observer, interval=k) and run")
        return np.array(self._values)

    def _samples(self, discard):
        discard = integer(discard, "discard", 0)
        x = self.series
        if len(x) - discard < 2:
            raise ValueError(f"{type(self).__name__} has {len(x)} samples; at least 2 "
                             f"are needed after discarding {discard}")
        return x[discard:]

    def average(self, discard=0):
        """Block average of the series (:func:`block_average`): an
        :class:`Estimate`, or (mean, error) arrays for a series of arrays."""
        x = self._samples(discard)
        if x.ndim == 1:
            return block_average(x)
        mean, err = block_average(x.reshape(len(x), -1))
        return mean.reshape(x.shape[1:]), err.reshape(x.shape[1:])

    def write(self, path):
        """The series as a text file: the step, then the value(s) of each call."""
        x = self.series.reshape(len(self.steps), -1)
        np.savetxt(path, np.column_stack([self.steps, x]),
                   header=f"{self.name}: step, then the values of each call")


def _unit_spins(dyn):
    return get_spins(dyn.atoms)


class SublatticeMagnetisation(Observer):
    """Mean unit spin of each sublattice, (n_sublattices, 3) per call.

    ``by``: "species" (chemical symbols, default), "tags" (``atoms.get_tags()``)
    or an array of one label per atom. Non-magnetic atoms are left out; a
    sublattice without magnetic atoms is refused. ``labels``: the sublattices'
    labels, in the order of the rows."""

    name = "sublattice_magnetisation"

    def __init__(self, dyn, by="species", info=False):
        super().__init__(dyn, info)
        atoms = dyn.atoms
        if isinstance(by, str):
            if by == "species":
                labels = np.array(atoms.get_chemical_symbols())
            elif by == "tags":
                labels = atoms.get_tags()
            else:
                raise ValueError(f'by must be "species", "tags" or one label per atom, got {by!r}')
        else:
            labels = np.asarray(by)
            if labels.shape != (len(atoms),):
                raise ValueError(f"by must hold one label per atom ({len(atoms)}), got shape "
                                 f"{labels.shape}")
        magnetic = np.linalg.norm(atoms.get_initial_magnetic_moments().reshape(len(atoms), -1),
                                  axis=1) > 0
        self.labels, index = np.unique(labels, return_inverse=True)
        counts = np.bincount(index[magnetic], minlength=len(self.labels))
        if np.any(counts == 0):
            raise ValueError(f"sublattices {self.labels[counts == 0].tolist()} have no "
                             "magnetic atoms")
        self._index = np.where(magnetic, index, len(self.labels))
        self._counts = counts

    def measure(self):
        s = _unit_spins(self.dyn)
        sums = np.zeros((len(self.labels) + 1, 3))
        np.add.at(sums, self._index, s)
        return sums[:-1] / self._counts[:, None]

    def magnitudes(self, discard=0):
        """⟨|m_α|⟩ of each sublattice α with its block-average error: a list
        of :class:`Estimate`."""
        m = np.linalg.norm(self._samples(discard), axis=2)
        return [block_average(m[:, k]) for k in range(m.shape[1])]


class TopologicalCharge(Observer):
    """Berg–Lüscher topological charge Q of a layer per call
    (:class:`~ase_spin.analysis.topology.LayerTriangulation`, triangulated once
    at the positions of the first call: a frozen or nearly frozen lattice).
    ``indices``: the layer's atoms (default all), ``normal``: its normal."""

    name = "topological_charge"

    def __init__(self, dyn, indices=None, normal=None, info=False):
        super().__init__(dyn, info)
        self.triangulation = LayerTriangulation(dyn.atoms, indices, normal)

    def measure(self):
        return self.triangulation.charge(_unit_spins(self.dyn))


class SpinCorrelation(Observer):
    r"""The spin–spin correlation function by neighbour shell and the
    second-moment correlation length.

    Per call: C_n = ⟨s_i·s_j⟩ over the pairs of shell n (distance r_n within
    ``tol`` Å, up to ``rmax``), and the structure factor S(k) = |Σ_i s_i
    e^{ik·r_i}|²/N at k = 0 and at the smallest reciprocal vectors of the
    periodic cell (k_min: the three along a*, b*, c* averaged over those that
    are periodic). Pairs are found once, at the first positions.

    :meth:`correlation_function`: (r_n, C(r_n), errors), optionally connected,
    C(r) − ⟨|m|²⟩; :meth:`correlation_length`: the second-moment length

    .. math:: \xi = \frac{1}{2\sin(k_{\min}/2)}\sqrt{\frac{S(0)}{S(k_{\min})} - 1}

    (k_min in 1/Å, ξ in Å; Ornstein–Zernike S(k) ∝ 1/(1 + ξ²k²) for small
    k), meaningful in the paramagnet, where S(0) is not dominated by order.
    """

    name = "spin_correlation"

    def __init__(self, dyn, rmax, tol=1e-3, info=False):
        super().__init__(dyn, info)
        atoms = dyn.atoms
        rmax = positive_scalar(rmax, "rmax")
        i, j, d = neighbor_list("ijd", atoms, rmax)
        magnetic = np.linalg.norm(atoms.get_initial_magnetic_moments().reshape(len(atoms), -1),
                                  axis=1) > 0
        keep = magnetic[i] & magnetic[j]
        i, j, d = i[keep], j[keep], d[keep]
        if not len(d):
            raise ValueError(f"no pairs of magnetic atoms within rmax = {rmax} Å")
        order = np.argsort(d)
        d_sorted = d[order]
        new_shell = np.concatenate([[True], np.diff(d_sorted) > tol])
        shell_sorted = np.cumsum(new_shell) - 1
        shell = np.empty_like(shell_sorted)
        shell[order] = shell_sorted
        self.distances = np.array([d_sorted[shell_sorted == k].mean()
                                   for k in range(shell_sorted[-1] + 1)])
        self._pairs = (i, j, shell, np.bincount(shell))
        self._magnetic = magnetic
        periodic = np.flatnonzero(atoms.pbc & (np.linalg.norm(atoms.cell.array, axis=1) > 0))
        recip = 2.0 * np.pi * atoms.cell.reciprocal()
        self._k = recip[periodic]
        self._positions = atoms.positions[magnetic]

    def measure(self):
        s = _unit_spins(self.dyn)
        i, j, shell, counts = self._pairs
        dots = np.einsum("ij,ij->i", s[i], s[j])
        C = np.bincount(shell, weights=dots, minlength=len(counts)) / counts
        sm = s[self._magnetic]
        n = len(sm)
        S0 = float((sm.sum(axis=0) ** 2).sum()) / n
        Sk = []
        for k in self._k:
            phase = np.exp(1j * (self._positions @ k))
            Sk.append(float((np.abs(phase @ sm) ** 2).sum()) / n)
        Sk = float(np.mean(Sk)) if Sk else np.nan
        return np.concatenate([C, [S0, Sk]])

    def correlation_function(self, connected=False, discard=0):
        """(r_n in Å, C(r_n), their errors); ``connected``: C − ⟨m²⟩ (m the
        mean spin per call: S(0)/N), jackknife errors."""
        x = self._samples(discard)
        n = int(self._magnetic.sum())
        nshell = len(self.distances)
        if not connected:
            mean, err = block_average(x[:, :nshell])
            return self.distances, mean, err
        values = [jackknife(lambda c, s0: c.mean() - s0.mean() / n, x[:, k], x[:, nshell])
                  for k in range(nshell)]
        return (self.distances, np.array([v.value for v in values]),
                np.array([v.error for v in values]))

    def correlation_length(self, discard=0, blocks=32):
        """ξ (Å) by the second moment (class docstring), jackknife error."""
        if not len(self._k):
            raise ValueError("the correlation length needs a periodic cell")
        x = self._samples(discard)
        kmin = float(np.mean(np.linalg.norm(self._k, axis=1)))

        def xi(s0, sk):
            ratio = s0.mean() / sk.mean() - 1.0
            return np.sqrt(max(ratio, 0.0)) / (2.0 * np.sin(kmin / 2.0))

        return jackknife(xi, x[:, -2], x[:, -1], blocks=blocks)


def _temperature(dyn, temperature_K):
    if temperature_K is not None:
        return positive_scalar(temperature_K, "temperature_K") * units.kB
    kT = getattr(dyn, "spin_temp", None)
    if kT is None:
        raise ValueError(f"{type(dyn).__name__} has no bath temperature: give temperature_K")
    return float(kT)


class Fluctuations(Observer):
    r"""Magnetic energy and magnetisation per call, and what their
    fluctuations give at the temperature T of the sampling (the bath's or
    Monte Carlo's, or ``temperature_K``), for the N magnetic atoms, m the mean
    unit spin:

    - :meth:`magnetisation` ⟨|m|⟩, :meth:`energy` ⟨E⟩ (eV);
    - :meth:`susceptibility` χ = N(⟨m²⟩ − ⟨|m|⟩²)/(k_B T) (1/eV per spin; J χ
      is the reduced χ of the Heisenberg literature, m the 3-vector, so the
      sum of the three components' χ), or with ``absolute=False``
      N⟨m²⟩/(k_B T) (the paramagnet's, ⟨m⟩ = 0: 1/(k_B T) for free spins);
    - :meth:`specific_heat` C = (⟨E²⟩ − ⟨E⟩²)/(N k_B T²) (units of k_B per spin);
    - :meth:`binder_cumulant` U = 1 − ⟨m⁴⟩/(3⟨m²⟩²) (2/3 ordered, 4/9 for a
      3-component paramagnet; Chen, Ferrenberg and Landau's U).

    Errors by block jackknife (``blocks`` blocks, each much longer than the
    autocorrelation time: check with ``average()`` of the series). E is the
    magnetic energy: with a moving lattice the lattice part is not in C.
    """

    name = "fluctuations"

    def __init__(self, dyn, temperature_K=None, info=False):
        super().__init__(dyn, info)
        self.kT = _temperature(dyn, temperature_K)
        moments = dyn.atoms.get_initial_magnetic_moments().reshape(len(dyn.atoms), -1)
        self.n = int((np.linalg.norm(moments, axis=1) > 0).sum())
        if not self.n:
            raise ValueError("no magnetic atoms to observe")

    def measure(self):
        dyn = self.dyn
        m = np.asarray(dyn.get_magnetization(), dtype=float)
        return np.array([dyn.get_magnetic_energy(), *m])

    def _columns(self, discard):
        x = self._samples(discard)
        return x[:, 0], np.linalg.norm(x[:, 1:4], axis=1)

    def magnetisation(self, discard=0):
        return block_average(self._columns(discard)[1])

    def energy(self, discard=0):
        return block_average(self._columns(discard)[0])

    def susceptibility(self, absolute=True, discard=0, blocks=32):
        _, m = self._columns(discard)
        n, kT = self.n, self.kT
        if absolute:
            return jackknife(lambda a: n * (np.mean(a * a) - np.mean(a) ** 2) / kT, m,
                             blocks=blocks)
        return jackknife(lambda a: n * np.mean(a * a) / kT, m, blocks=blocks)

    def specific_heat(self, discard=0, blocks=32):
        e, _ = self._columns(discard)
        n, kT = self.n, self.kT
        return jackknife(lambda x: x.var() / (n * kT * kT), e, blocks=blocks)

    def binder_cumulant(self, discard=0, blocks=32):
        _, m = self._columns(discard)
        return jackknife(lambda a: 1.0 - np.mean(a ** 4) / (3.0 * np.mean(a * a) ** 2), m,
                         blocks=blocks)


class SpinTemperature(Observer):
    r"""The configurational spin temperature: per call the sums (N, D) of
    ``dyn.get_spin_temperature_sums()`` (|∇E|² and ∇²E on the spheres);
    :meth:`temperature` gives T_s = ⟨N⟩/(k_B⟨D⟩) (K) with its jackknife error,
    the ratio of averages that the Boltzmann distribution makes the
    temperature (for Monte Carlo: a check of what was sampled)."""

    name = "spin_temperature"

    def measure(self):
        return np.array(self.dyn.get_spin_temperature_sums(), dtype=float)

    def temperature(self, discard=0, blocks=32):
        x = self._samples(discard)
        return jackknife(lambda a, b: a.mean() / (units.kB * b.mean()), x[:, 0], x[:, 1],
                         blocks=blocks)

