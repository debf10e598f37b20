"""Relaxing spins by damped precession: :func:`relax_spins`, zero-temperature
:class:`~ase_spin.md.langevin.Langevin` dynamics on a frozen lattice. The
quasi-Newton and velocity-projection minimisers of :mod:`ase_spin.optimize`
reach the same minima in far fewer evaluations (docs/landscapes.md)."""

from __future__ import annotations

import numpy as np

from ..validate import integer, real_scalar
from . import bath_parameters as parameters
from .base import fastest_precession
from .langevin import Langevin

__all__ = ["relax_spins", "largest_torque", "RELAX_PHASE", "RELAX_CHECK"]


#: relax_spins's default timestep turns the fastest spin by this angle (rad)
#: per step (with the Gilbert factor: h·max r_i|B_i|/(ħ(1+λ²)), the quantity of
#: the timestep warning, which it keeps clear of)
RELAX_PHASE = 0.2
#: relax_spins checks the torque after steps 1, 2, 4, ..., RELAX_CHECK and then
#: every RELAX_CHECK steps (and at its last step): between two checks the
#: steps run as one ``dyn.run(k)``
RELAX_CHECK = 32


def relax_spins(atoms, *, fmax=1e-6, damping=1.0, timestep=None, steps=100_000,
                hbar=None, gyromagnetic=None, **kwargs):
    r"""Relax the spins to a (local) minimum of the energy at fixed positions:
    zero-temperature damped Landau–Lifshitz–Gilbert dynamics (:class:`Langevin`
    with T_s = 0, frozen lattice), the damped-precession path of each spin
    towards its field, until every torque |s_i × B_i| ≤ ``fmax`` (eV). Spins
    pinned by :class:`~ase_spin.constraints.FixSpins` stay as they are (their
    torques are not counted): the fixed boundary of a domain wall, say.

    ``damping``: λ (1 is the fastest relaxation of a spin in a fixed field);
    ``timestep``: default :data:`RELAX_PHASE`·ħ(1+λ²)/max_i(r_i|B_i|) from the
    initial fields (0.2 rad per step for the fastest spin: no TimestepWarning;
    one given is checked as any integrator's).

    The steps run in blocks, ``dyn.run(k)`` (the cost of a Langevin step), and
    the torque is checked between blocks from the fields the last step
    computed: after steps 1, 2, 4, ..., :data:`RELAX_CHECK` (32) and then every
    32 steps, and after step ``steps``. It stops at the first check where the
    largest torque is ≤ ``fmax`` and returns the number of steps taken, so the
    count is one of 0, 1, 2, 4, 8, 16, a multiple of 32 or ``steps``; the
    torque may have reached ``fmax`` up to 31 steps before (the spins are then
    relaxed further). The spins are written back to ``atoms``; positions and
    momenta are not touched. Raises RuntimeError (the Atoms keep their spins
    from before the call) if ``fmax`` is not reached in ``steps`` steps.
    """
    fmax = parameters.non_negative(fmax, "fmax", "eV")
    damping = real_scalar(damping, "damping")
    if not damping > 0.0:
        raise ValueError(f"damping must be > 0 to relax spins, got {damping}")
    steps = integer(steps, "steps", minimum=0)
    before = atoms.arrays.get("initial_magmoms")
    before = None if before is None else before.copy()
    try:
        chosen = timestep is None
        dyn = Langevin(atoms, 1.0 if chosen else timestep, 0.0, spin_damping=damping,
                       friction=0.0, hbar=hbar, gyromagnetic=gyromagnetic, lattice="frozen",
                       **kwargs)
        if chosen:  # its timestep follows from the fields below: no check of the 1.0
            dyn._checked_dt = dyn.dt
        st = dyn._sync()
        B = dyn._spin_energy_fields(energy=False).B if dyn.magnetic else np.zeros_like(st.s)
        torque = largest_torque(st.s, B, st.pinned)
        if torque <= fmax:
            return 0
        if chosen:
            omega = fastest_precession(st.rate, B, dyn.hbar)  # st.rate: with 1/(1+λ²)
            dyn.dt = dyn._checked_dt = RELAX_PHASE / omega
        done = 0
        while done < steps:
            # the next check: at 1, 2, 4, ..., RELAX_CHECK, then every RELAX_CHECK
            check = 1 if done == 0 else min(2 * done, done + RELAX_CHECK)
            block = min(check, steps) - done
            dyn.run(block)
            done += block
            st = dyn._sync()
            # the run's last step ends with its closing bath, whose fields at
            # the spins it leaves are kept (st.EB): no evaluation of their own
            EB = st.EB if st.EB is not None else dyn._spin_energy_fields(energy=False)
            torque = largest_torque(st.s, EB.B, st.pinned)
            if torque <= fmax:
                return done
        raise RuntimeError(f"relax_spins: largest torque {torque:.3g} eV "
                           f"> fmax = {fmax:g} eV after {steps} steps; raise steps or "
                           "damping. The spins are as they were before the call.")
    except BaseException:
        if before is None:
            atoms.arrays.pop("initial_magmoms", None)
        else:
            atoms.arrays["initial_magmoms"] = before
        raise


def largest_torque(s, B, pinned=None):
    """max_i |s_i × B_i| (eV) over the spins that move (``pinned``: a mask of
    those FixSpins holds, or None), 0 without spins."""
    if pinned is not None:
        s, B = s[~pinned], B[~pinned]
    if not len(s):
        return 0.0
    t = np.cross(s, B)
    return float(np.sqrt(np.einsum("ij,ij->i", t, t).max()))
