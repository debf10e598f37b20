r"""Limited-memory BFGS with orthogonal spin optimisation (LBFGS-OSO).

Ivanov, Uzdin and Jónsson, "Fast and robust algorithm for energy minimization
of spin systems applied in an analysis of high temperature spin configurations
in terms of skyrmion density", Comput. Phys. Commun. 260, 107749 (2021)
(arXiv:1904.02669); Spirit's ``LBFGS_OSO`` and LAMMPS's ``min_style
spin/lbfgs``. Each step turns every spin by a rotation vector θ_i
(:func:`~ase_spin.optimize.sphere.rotate`); at the current spins the gradient
of E in θ is g_i = −τ_i = −s_i × B_i, and the step is the L-BFGS direction

.. math:: \boldsymbol\theta = -H_k\,\mathbf g, \qquad
    H_k \text{ from the last } m \text{ pairs } (\Delta\boldsymbol\theta_j,\;
    \Delta\mathbf g_j), \quad H_k^0 = \frac{\Delta\boldsymbol\theta\cdot\Delta\mathbf g}
    {\Delta\mathbf g\cdot\Delta\mathbf g}\,I

(the two-loop recursion), θ_i projected on the tangent plane of s_i (a turn
about s_i moves nothing) and scaled so that no spin turns by more than
``maxmove``. The rotation vectors of all steps live in one fixed frame, so the
pairs need no transport (the OSO construction). The first step, and every
step after the memory is reset, is θ = −g/max_i|B_i|: a spin in a field B
has the curvature |B| about its minimum, so this is a Newton step for the
stiffest spin. The memory is reset when the direction is not a descent
direction or the energy rose in the last step by more than its round-off
(:data:`ENERGY_NOISE` relative to |E| + Σ_i|B_i|: near the minimum the true
changes, of order τ²/|B|, fall below the round-off of E, whose noise must not
reset the memory); a pair whose curvature Δθ·Δg is not positive is not kept.
One evaluation of E and B per step.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from ..validate import integer
from . import sphere
from .base import SpinOptimizer

__all__ = ["SpinLBFGS", "ENERGY_NOISE"]

#: a rise of E smaller than this times |E| + Σ_i|B_i| (eV) is round-off, not a
#: failed step
ENERGY_NOISE = 1e-12


class SpinLBFGS(SpinOptimizer):
    """LBFGS with orthogonal spin optimisation (module docstring).

    ``SpinLBFGS(atoms, logfile=None, trajectory=None, memory=10,
    maxmove=0.2)``, then ``opt.run(fmax=1e-6, steps=...)``: as
    :class:`~ase_spin.optimize.base.SpinOptimizer`. ``memory``: the number of
    past steps kept (m)."""

    def __init__(self, atoms, logfile=None, trajectory=None, *, memory=10, maxmove=None,
                 **kwargs):
        self.memory = integer(memory, "memory", minimum=1)
        super().__init__(atoms, logfile, trajectory, maxmove=maxmove, **kwargs)

    def reset(self):
        self.pairs = deque(maxlen=self.memory)  # (Δθ, Δg, 1/(Δθ·Δg))

    def todict(self):
        return {**super().todict(), "memory": self.memory}

    def _direction(self, g):
        """−H g by the two-loop recursion over the kept pairs."""
        q = g.copy()
        alphas = []
        for d, y, rho in reversed(self.pairs):
            a = rho * sphere.inner(d, q)
            q -= a * y
            alphas.append(a)
        d, y, _ = self.pairs[-1]
        q *= sphere.inner(d, y) / sphere.inner(y, y)
        for (d, y, rho), a in zip(self.pairs, reversed(alphas)):
            b = rho * sphere.inner(y, q)
            q += (a - b) * d
        return -q

    def step(self):
        s, free = self.s, self.free
        g = -self.forces()
        theta = self._direction(g) if self.pairs else None
        if theta is None or not sphere.inner(theta, g) < 0.0:
            self.reset()
            stiffest = sphere.norms(self.B[free]).max() if free.any() else 1.0
            theta = -g / (stiffest if stiffest > 0.0 else 1.0)
        theta = sphere.tangent(theta, s)
        theta[~free] = 0.0
        largest = sphere.norms(theta).max()
        if largest > self.maxmove:
            theta *= self.maxmove / largest
        s_new = s.copy()
        s_new[free] = sphere.rotate(s[free], theta[free])
        energy, B = self.landscape(s_new)
        before = self.energy
        self._accept(s_new, energy, B)
        y = -self.forces() - g
        curvature = sphere.inner(theta, y)
        noise = ENERGY_NOISE * (abs(before) + float(sphere.norms(B[free]).sum()))
        if energy > before + noise:
            self.reset()
        elif curvature > 0.0:
            self.pairs.append((theta, y, 1.0 / curvature))
