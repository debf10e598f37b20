r"""Velocity projection (VP) on the product of spheres.

Bessarab, Uzdin and Jónsson, Comput. Phys. Commun. 196, 335 (2015), Sec. 3
(Spirit's ``VP``): a damped Verlet motion of the spins in their tangent
forces F_i = B_i − (B_i·s_i)s_i (eV), whose velocity keeps only its part along
the force, and nothing when it points against it:

.. math::

    \mathbf v &\leftarrow \mathbf v + \tfrac12 h(\mathbf F^{\rm old} + \mathbf F), \qquad
    \mathbf v \leftarrow \begin{cases}
        \dfrac{\mathbf v\cdot\mathbf F}{\mathbf F\cdot\mathbf F}\,\mathbf F
            & \mathbf v\cdot\mathbf F > 0\\ 0 & \text{else}\end{cases}\\
    \mathbf d &= \mathbf v + \tfrac12 h\,\mathbf F, \qquad
    \mathbf s_i \leftarrow \exp_{\mathbf s_i}(\mathbf d_i)

(dot products over all spins, and over all images of a band), with
h = dt²/m in rad/eV. Its default, ``VP_STEP``/max_i|B_i| at the start, keeps
the stiffest mode (curvature ≤ 2|B| for a spin among others in a field |B|)
well inside the Verlet stability limit h·2|B| < 4. The velocity is carried to
the new tangent planes by projection. One evaluation per step.
"""

from __future__ import annotations

import numpy as np

from ..validate import positive_scalar
from . import sphere
from .base import SpinOptimizer

__all__ = ["SpinVP", "project_velocity", "VP_STEP"]

#: the default h·max|B| (dimensionless)
VP_STEP = 0.5


def project_velocity(v, F):
    """The velocity v projected on the force F (both arrays of any shape, dot
    products over all their elements): (v·F/F·F) F if v·F > 0, else 0."""
    vf = sphere.inner(v, F)
    ff = sphere.inner(F, F)
    if vf > 0.0 and ff > 0.0:
        return (vf / ff) * F
    return np.zeros_like(F)


class SpinVP(SpinOptimizer):
    """Velocity projection (module docstring): ``SpinVP(atoms, logfile=None,
    trajectory=None, h=None, maxmove=0.2)``, then ``opt.run(fmax, steps)`` as
    :class:`~ase_spin.optimize.base.SpinOptimizer`. ``h``: dt²/m (rad/eV),
    default ``VP_STEP``/max_i|B_i| at the start."""

    def __init__(self, atoms, logfile=None, trajectory=None, *, h=None, maxmove=None,
                 **kwargs):
        self.h_given = None if h is None else positive_scalar(h, "h (dt²/m, rad/eV)")
        super().__init__(atoms, logfile, trajectory, maxmove=maxmove, **kwargs)

    def reset(self):
        self.v = np.zeros_like(self.s)
        self.F_old = None
        if self.h_given is not None:
            self.h = self.h_given
        else:
            stiffest = sphere.norms(self.B[self.free]).max() if self.free.any() else 0.0
            self.h = VP_STEP / stiffest if stiffest > 0.0 else 1.0

    def todict(self):
        return {**super().todict(), "h": self.h}

    def _tangent_forces(self):
        F = sphere.tangent(self.B, self.s)
        F[~self.free] = 0.0
        return F

    def step(self):
        F = self._tangent_forces()
        if self.F_old is not None:
            self.v = sphere.tangent(self.v + 0.5 * self.h * (self.F_old + F), self.s)
        self.v = project_velocity(self.v, F)
        d = self.v + 0.5 * self.h * F
        largest = sphere.norms(d).max()
        if largest > self.maxmove:
            d *= self.maxmove / largest
        s_new = self.s.copy()
        s_new[self.free] = sphere.exp_map(self.s[self.free], d[self.free])
        self.F_old = F
        self._accept(s_new, *self.landscape(s_new))
