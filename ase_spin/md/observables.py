"""What a run shows: the observables (energies by term, magnetic forces,
magnetisation, temperatures), computed only when read, and the calculator's
results published for observers that write frames (trajectories), with what
a frame has no field for in its ``info``.

:class:`Observables` is a part of :class:`~ase_spin.md.base.SpinLatticeDynamics`
(its methods read ``self.atoms``, ``self.ev``, ``self._calc`` and the state
through ``self._sync()``).
"""

from __future__ import annotations

from contextlib import contextmanager

import numpy as np
from ase import units

from .._jit import threads
from ..terms.base import Want
from .logger import SpinMDLogger

__all__ = ["Observables"]

_FORCES = Want(forces=True)
#: results a frame carries in ``atoms.info`` (no calculator field for them)
_FRAME_INFO = ("magnetic_forces", "magnetic_energy", "energy_terms")
_ABSENT = object()


class Observables:
    """Observables and the results observers get (see the module docstring)."""

    def _observables(self):
        st = self._sync()
        if st.observables is not None:
            return st.observables
        with threads.threads_for(len(self.atoms)):
            return self._compute_observables(st)

    def _compute_observables(self, st):
        ev = self.ev
        terms = {}
        if st.EL_terms is None:
            res = ev.lattice(st.q, Want(energy=True))
            st.EL, st.EL_terms = res.energy, res.energy_terms
        terms.update(st.EL_terms)
        B = np.zeros_like(st.s)
        if self.magnetic:
            res = ev.spin(st.ops, st.s, Want(energy=True, magnetic_forces=True),
                          magnetic_forces=B)
            terms.update(res.energy_terms)
        for name in ev.hamiltonian.term_names:
            terms.setdefault(name, 0.0)
        extra = 0.0
        for c in self.atoms.constraints:
            if hasattr(c, "adjust_potential_energy"):
                extra += c.adjust_potential_energy(self.atoms)
        st.observables = {"terms": terms, "B": B, "extra": extra}
        return st.observables

    def get_energy_terms(self):
        """Potential energy by term (eV), at the current state."""
        return dict(self._observables()["terms"])

    def get_magnetic_energy(self):
        """Energy of the spin-dependent terms (eV), at the current state."""
        terms = self._observables()["terms"]
        return float(sum(terms[k] for k in self.ev.hamiltonian.spin_term_names))

    def get_potential_energy(self):
        obs = self._observables()
        return float(sum(obs["terms"].values()) + obs["extra"])

    def get_kinetic_energy(self):
        st = self._sync()
        return float(0.5 * np.einsum("ij,ij->", st.p, st.p / self.masses))

    def get_total_energy(self):
        return self.get_potential_energy() + self.get_kinetic_energy()

    def get_magnetic_forces(self):
        """B_i = −∂E/∂s_i (eV) at the current state."""
        return self._observables()["B"].copy()

    def get_magnetization(self):
        """Mean unit spin over the magnetic atoms (LAMMPS ``compute spin``'s first
        three values; their norm is |M|)."""
        st = self._sync()
        n = int(self.ev.magnetic.sum())
        return st.s.sum(axis=0) / n if n else np.zeros(3)

    def get_spin_temperature_sums(self):
        r"""The two sums of the spin temperature at the current state,
        (N, D) with k_B T_s = ⟨N⟩/⟨D⟩ in equilibrium:

        .. math:: N = \sum_i |\mathbf s_i \times \mathbf B_i|^2 \;(\mathrm{eV}^2),
                  \qquad D = \nabla^2 E = \sum_i \Big(2\,\mathbf s_i\cdot\mathbf B_i
                  - \sum_{\mathbf t \perp \mathbf s_i}
                    \mathbf t\cdot\frac{\partial \mathbf B_i}{\partial \mathbf s_i}
                    \mathbf t\Big) \;(\mathrm{eV}),

        N = |∇E|² and D = ∇²E on the product of the spheres: the configurational
        temperature's identity ⟨|∇E|²⟩ = k_B T ⟨∇²E⟩ of the Boltzmann
        distribution. The second part of D (a spin's field depending on that
        spin: anisotropies, biquadratic exchange; zero for exchange, DMI,
        fields) is each operator's ``self_curvature``; without it D is twice
        Σ s·B, Nurdin's and LAMMPS ``compute spin``'s denominator. Spins pinned
        by :class:`~ase_spin.constraints.FixSpins` are left out (zero rows). (0, 0)
        without magnetic atoms.

        The identity holds for averages: D has no sign, and its mean goes to
        zero as T grows (on a sphere ∇²E averages to zero at infinite T), so
        one sample's N/(k_B D) is no temperature above T_C. Average N and D
        apart over a run and divide (the log's Ts column does so over its
        last lines: :class:`~ase_spin.md.logger.SpinMDLogger`)."""
        obs = self._observables()
        if not self.magnetic:
            return 0.0, 0.0
        if "spin_temperature_sums" not in obs:
            st = self._sync()
            B = obs["B"]
            s = st.s
            if st.pinned is not None:  # pinned spins (FixSpins) are no degrees of freedom
                s = np.where(st.pinned[:, None], 0.0, s)
            num = float((np.cross(s, B) ** 2).sum())
            curvature = sum(op.self_curvature(s) for op in st.ops)
            den = 2.0 * float(np.einsum("ij,ij->", s, B)) - curvature
            obs["spin_temperature_sums"] = (num, den)
        return obs["spin_temperature_sums"]

    def get_spin_temperature(self):
        r"""One sample of the configurational spin temperature,
        T_s = N/(k_B D) with N and D of :meth:`get_spin_temperature_sums`;
        for terms linear in each spin (exchange, DMI, fields) that is LAMMPS
        ``compute spin``'s estimator (Nurdin et al.)

        .. math:: T_s = \frac{\sum_i |\mathbf s_i \times \mathbf B_i|^2}
                             {2 k_B \sum_i \mathbf s_i\cdot\mathbf B_i}

        (LAMMPS writes it with ω = B/ħ and a factor ħ). A single sample means
        something only while D is far from zero against its fluctuations
        (below T_C, or many spins): above T_C it can be any number of either
        sign; average N and D apart instead (the log's Ts). NaN without
        magnetic atoms or where D = 0.
        """
        num, den = self.get_spin_temperature_sums()
        if not self.magnetic or den == 0.0:
            return float("nan")
        return num / (units.kB * den)

    def get_temperature(self):
        dof = len(self.atoms) * 3
        for c in self.atoms.constraints:
            dof -= c.get_removed_dof(self.atoms)
        return 2.0 * self.get_kinetic_energy() / (max(dof, 1) * units.kB)

    # -- the calculator's results for observers (trajectory frames) -------------

    def call_observers(self):
        """ASE's, with the calculator's results for the current state published
        first (:meth:`publish_results`) when an observer other than the log line
        is due, and what a frame has no calculator field for put in
        ``atoms.info`` while the observers run (:meth:`_frame_info`): frames
        written by the integrator's ``trajectory=``, by an attached
        ``Trajectory(...).write`` or by a user's ``ase.io.write`` then all hold
        energy, forces, stress, magnetic forces. On the other steps nothing
        is computed."""
        if not self._frame_due(self.nsteps):
            super().call_observers()
            return
        self.publish_results()
        with self._frame_info():
            super().call_observers()

    def publish_results(self):
        """Put the results of the current state into ``atoms.calc`` as if it had
        computed them: ``energy``, ``free_energy``, ``forces`` (the Hamiltonian's,
        before constraints, as any calculator gives them), ``stress`` (a cell
        with three vectors), ``magmoms`` (N, 3), ``magmom`` (|Σ μ_i s_i|),
        ``magnetic_forces`` B = −∂E/∂s (eV), ``magnetic_energy`` and
        ``energy_terms``. From what the step already computed (the lattice part
        once per step) plus one pass over the spin terms; ``atoms.get_forces()``
        etc. then cost nothing until the Atoms change."""
        st = self._sync()
        with threads.threads_for(len(self.atoms)):
            results = self._frame_results(st)
        self._calc.publish(self.atoms, results)

    def _frame_results(self, st):
        ev = self.ev
        obs = self._observables()
        stress = self._stress_available()
        F = (ev.lattice(st.q, _FORCES).forces if self.frozen else st.FL).copy()
        V = np.zeros(6)
        if self.magnetic:
            # operators able to give the virial when it is wanted (those of
            # the step need not be)
            ops = ev.spin_operators(st.q, virial=True, half=True) if stress else st.ops
            res = ev.spin(ops, st.s, Want(forces=True, virial=stress), forces=F)
            if stress:
                V += res.virial
        if stress:
            VL = st.VL
            if VL is None:
                VL = ev.lattice(st.q, Want(virial=True)).virial
            V += VL
        terms = dict(obs["terms"])
        energy = float(sum(terms.values()))
        moments = st.mu[:, None] * st.s
        results = {"energy": energy, "free_energy": energy, "forces": F,
                   "magnetic_forces": obs["B"].copy(), "energy_terms": terms,
                   "magnetic_energy": float(sum(terms[k] for k in
                                                ev.hamiltonian.spin_term_names)),
                   "magmoms": moments}
        results.update(_total_moment(moments))
        if stress:
            results["stress"] = V / abs(np.linalg.det(self.atoms.cell.array))
        return results

    @contextmanager
    def _frame_info(self):
        """``magnetic_forces`` (N, 3), ``magnetic_energy`` and ``energy_terms``
        of the published results in ``atoms.info`` for the duration of the
        block (ASE's .traj stores a fixed list of calculator properties, none
        of them a magnetic force; extxyz writes info in the comment line).
        Afterwards each key is as it was, unless an observer set it to a
        value of its own: the user's Atoms keep their own info."""
        calc = self._calc
        info = self.atoms.info
        put = {}
        if not calc.check_state(self.atoms):
            for key in _FRAME_INFO:
                if key in calc.results:
                    put[key] = (calc.results[key], info.get(key, _ABSENT))
                    info[key] = calc.results[key]
        try:
            yield
        finally:
            for key, (value, before) in put.items():
                if info.get(key, _ABSENT) is not value:
                    continue  # an observer's own value
                if before is _ABSENT:
                    del info[key]
                else:
                    info[key] = before

    def _observer_due(self, n, frames_only=False):
        for function, interval, _, _ in self.observers:
            if not getattr(function, "needs_results", True):
                # an observer that declares needs_results = False reads only the
                # Atoms' positions and spins (written after every step it sees):
                # no energy, no calculator results, no frame for it
                continue
            if frames_only and isinstance(function, SpinMDLogger):
                continue  # the log line reads the state, not the calculator
            if (interval > 0 and n % interval == 0) or (interval <= 0 and n == -interval):
                return True
        return False

    def _frame_due(self, n):
        """An observer other than the log line (a trajectory, a user's function
        that may write the Atoms) runs after step n."""
        return self._observer_due(n, frames_only=True)

    def _stress_available(self):
        return self.atoms.cell.rank == 3

    def _refresh_properties(self):
        # ASE asks the calculator for forces after every step so that loggers
        # find them cached; this integrator's logger reads its own state, so
        # that would be one wasted full evaluation per step.
        pass


def _total_moment(moments):
    """ASE's scalar ``magmom`` for vector moments: |Σ_i μ_i s_i| (μB), and the
    vector itself as ``magmom_vector``."""
    total = moments.sum(axis=0)
    return {"magmom": float(np.sqrt(total @ total)), "magmom_vector": total}
