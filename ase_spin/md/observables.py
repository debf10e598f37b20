"""What a run shows: the observables (energies by term, magnetic forces,
magnetisation, temperatures), computed only when read, and the calculator's
results published for observers that write frames (trajectories), with what
a frame has no field for in its ``info``.

:class:`Observables` is a part of :class:`~ase_spin.md.base.SpinLatticeDynamics`
(its methods read ``self.atoms``, ``self.ev``, ``self._calc`` and the state
through ``self._sync()``).
"""

from __future__ import annotations

import numpy as np
from ase import units

from .._jit import threads
from ..terms.base import Want
from .logger import SpinMDLogger

__all__ = ["Observables"]

_FORCES = Want(forces=True)


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

    def get_spin_temperature(self):
        r"""The spin temperature of LAMMPS ``compute spin`` (Nurdin et al.):

        .. math:: T_s = \frac{\sum_i |\mathbf s_i \times \mathbf B_i|^2}
                             {2 k_B \sum_i \mathbf s_i\cdot\mathbf B_i}

        (LAMMPS writes it with ω = B/ħ and a factor ħ). NaN without magnetic atoms.
        """
        st = self._sync()
        B = self._observables()["B"]
        den = float(np.einsum("ij,ij->", st.s, B))
        if not self.magnetic or den == 0.0:
            return float("nan")
        num = float((np.cross(st.s, B) ** 2).sum())
        return num / (2.0 * units.kB * den)

    def get_temperature(self):
        dof = len(self.atoms) * 3
        for c in self.atoms.constraints:
            dof -= c.get_removed_dof(self.atoms)
        return 2.0 * self.get_kinetic_energy() / (max(dof, 1) * units.kB)

    # -- the calculator's results for observers (trajectory frames) -------------

    def call_observers(self):
        """ASE's, with the calculator's results for the current state published
        first (:meth:`publish_results`) when an observer other than the log line
        is due: trajectory frames (and a user's ``ase.io.write`` in an observer)
        then hold energy, forces, stress, magnetic forces; on the other steps
        nothing is computed."""
        if self._frame_due(self.nsteps):
            self.publish_results()
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

    def _traj_write_image(self, description):
        """ASE's trajectory writer, with what a .traj frame has no field for in
        the frame's ``info``: ``magnetic_forces`` (N, 3), ``magnetic_energy``,
        ``energy_terms`` (the user's Atoms keep their own info)."""
        calc = self._calc
        current = not calc.check_state(self.atoms)
        info = self.atoms.info
        saved = dict(info)
        for key in ("magnetic_forces", "magnetic_energy", "energy_terms"):
            if current and key in calc.results:
                info[key] = calc.results[key]
        try:
            super()._traj_write_image(description)
        finally:
            info.clear()
            info.update(saved)

    def _observer_due(self, n, frames_only=False):
        for function, interval, _, _ in self.observers:
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
