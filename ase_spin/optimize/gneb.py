r"""Minimum energy paths and barriers: the geodesic nudged elastic band (GNEB).

Bessarab, Uzdin and Jónsson, Comput. Phys. Commun. 196, 335 (2015). A band
of images ν = 0 … M−1 between two (relaxed) states; each image a point of
(S²)ᴺ (spins on a frozen lattice), or with ``lattice=True`` of ℝ³ᴺ × (S²)ᴺ
(positions and spins: the lattice relaxes along a magnetic transition).
Distances are geodesic,

.. math:: L_{ν,ν+1} = \Big(\sum_i |\mathbf r_i^{ν+1} - \mathbf r_i^ν|^2
    + \ell^2 \sum_i θ_i^2\Big)^{1/2}, \qquad
    θ_i = ∠(\mathbf s_i^ν, \mathbf s_i^{ν+1}),

with ℓ = ``spin_length`` (Å per rad) weighing a turn against a displacement
(it shapes the path between the states, not the energies of its stationary
points). In the coordinates y = (r, ℓ u), u the tangent displacements of the
spins, the force on an image is F_y = (F, B_⊥/ℓ), F = −∂E/∂r and
B_⊥ = B − (B·s)s. The tangent τ̂ is Henkelman and Jónsson's upwind one from
the differences to the neighbours (spin parts projected on the image's
tangent planes), and

.. math:: \mathbf F^{\rm GNEB}_ν = \mathbf F_y - (\mathbf F_y\cdot\hat τ)\hat τ
    + k\,(L_{ν,ν+1} - L_{ν-1,ν})\,\hat τ,

or, for the climbing image (the highest, with ``climb=True``),
F_y − 2(F_y·τ̂)τ̂ without spring: it climbs to the saddle point along the
path. The band moves by velocity projection (:mod:`~ase_spin.optimize.vp`)
with one projection over all images; the end images stay. Converged when
every row of every inner image's force (spins in eV, atoms in eV/Å) is
≤ ``fmax``. The energy along the path is the cubic Hermite interpolation of
the images' energies with the slopes −F_y·τ̂ (:mod:`~ase_spin.optimize.path`).
"""

from __future__ import annotations

import numpy as np

from ..constraints import lattice_constraints
from ..spins import get_spins
from ..terms.base import Want
from ..validate import flag, integer, positive_scalar
from . import sphere
from .base import checked_fmax
from .objective import FrozenLattice
from .path import hermite_path, path_maximum
from .vp import VP_STEP, project_velocity

__all__ = ["GNEB", "LATTICE_STIFFNESS"]

#: the lattice curvature (eV/Å²) assumed for the band's default step with
#: ``lattice=True`` (ASE's BFGS starts from 70 eV/Å²)
LATTICE_STIFFNESS = 70.0
_ALL = Want(energy=True, forces=True, magnetic_forces=True)


class GNEB:
    """A geodesic nudged elastic band (module docstring).

    Parameters
    ----------
    images : list of ase.Atoms
        At least three; the first carries the SpinLatticeCalculator that serves
        all (the others need none), the first and last are the end states (relax
        them first) and stay. Without ``lattice`` all share the first's positions.
    k : float, optional
        Spring constant (eV/rad², eV/Å² along atoms); default 0.1·max_i|B_i| over
        the images given, a tenth of the stiffness of the stiffest spin.
    climb : bool
        The highest image climbs to the saddle point.
    lattice : bool
        Images carry positions too, which relax along the path.
    spin_length : float
        ℓ, Å per rad (only with ``lattice``).

    ``band.interpolate()`` places the inner images on the geodesic between the
    ends; ``band.run(fmax, steps)`` relaxes the band (True if converged);
    ``band.energies``, ``band.barrier()``, ``band.path()``, ``band.saddle()``.
    """

    def __init__(self, images, k=None, climb=False, *, lattice=False, spin_length=1.0,
                 h=None, maxmove=0.1):
        images = list(images)
        if len(images) < 3:
            raise ValueError(f"a band needs at least three images (two ends and one "
                             f"between), got {len(images)}")
        first = images[0]
        n = len(first)
        for k_, im in enumerate(images):
            if len(im) != n or not np.array_equal(im.numbers, first.numbers):
                raise ValueError(f"image {k_} has other atoms than image 0")
        self.images = images
        self.lattice = flag(lattice, "lattice")
        self.climb = flag(climb, "climb")
        self.spin_length = positive_scalar(spin_length, "spin_length (Å per rad)")
        self.maxmove = positive_scalar(maxmove, "maxmove")
        self.landscape = FrozenLattice(first, "GNEB")
        if not self.lattice:
            for k_, im in enumerate(images):
                if not np.array_equal(im.positions, first.positions):
                    raise ValueError(f"image {k_} has other positions than image 0: a band "
                                     "of spins on a frozen lattice needs the same positions "
                                     "in every image (lattice=True lets them relax)")
        self.free = self.landscape.free
        self.constraints = lattice_constraints(first)
        self.S = np.array([get_spins(im) for im in images])
        self.Q = np.array([im.positions for im in images], dtype=float)
        self.k = None if k is None else positive_scalar(k, "k (spring constant)")
        self.h = None if h is None else positive_scalar(h, "h (dt²/m)")
        self.evaluations = 0
        self.nsteps = 0
        self._stiffness = 0.0
        self._evaluate(range(len(images)))
        #: max_i |B_i| over the images given (eV): the stiffest spin's curvature
        self.stiffness = self._stiffness

    # -- geometry -----------------------------------------------------------
    def interpolate(self):
        """Place the inner images on the geodesic from the first to the last:
        each spin turned at a constant rate about s⁰ × s^(M−1) (a half turn about
        a perpendicular axis where they are antiparallel), positions linearly."""
        M = len(self.images)
        for nu in range(1, M - 1):
            t = nu / (M - 1)
            self.S[nu][self.free] = sphere.slerp(self.S[0][self.free],
                                                 self.S[-1][self.free], t)
            if self.lattice:
                self.Q[nu] = (1 - t) * self.Q[0] + t * self.Q[-1]
        self._evaluate(range(1, M - 1))
        self._write()

    def distances(self):
        """L_ν,ν+1 (the module docstring), shape (M−1,)."""
        ell = self.spin_length
        out = []
        for nu in range(len(self.images) - 1):
            d2 = ell**2 * np.sum(sphere.angles(self.S[nu], self.S[nu + 1])[self.free] ** 2)
            if self.lattice:
                d2 += np.sum((self.Q[nu + 1] - self.Q[nu]) ** 2)
            out.append(np.sqrt(d2))
        return np.array(out)

    def _difference(self, a, b, at):
        """y_b − y_a in the tangent space at image ``at`` (positions, ℓ·spins)."""
        ds = sphere.tangent(self.S[b] - self.S[a], self.S[at]) * self.spin_length
        ds[~self.free] = 0.0
        dq = self.Q[b] - self.Q[a] if self.lattice else np.zeros_like(ds)
        return np.concatenate([dq, ds])

    def _tangent(self, nu):
        E = self.energies
        plus, minus = self._difference(nu, nu + 1, nu), self._difference(nu - 1, nu, nu)
        up, down = E[nu + 1] - E[nu], E[nu - 1] - E[nu]
        if up > 0.0 > down:
            t = plus
        elif up < 0.0 < down:
            t = minus
        else:
            big, small = max(abs(up), abs(down)), min(abs(up), abs(down))
            t = plus * big + minus * small if E[nu + 1] > E[nu - 1] else \
                plus * small + minus * big
        norm = np.sqrt(sphere.inner(t, t))
        return t / norm if norm > 0.0 else t

    # -- energies and forces --------------------------------------------------
    def _evaluate(self, which):
        if not hasattr(self, "energies"):
            M, n = len(self.images), len(self.images[0])
            self.energies = np.zeros(M)
            self.F = np.zeros((M, 2 * n, 3))  # (positions; ℓ-scaled spin) forces
        n = len(self.images[0])
        for nu in which:
            if self.lattice:
                ev = self.landscape.evaluator
                res = ev.evaluate(self.Q[nu], self.S[nu], _ALL)
                E, B, F = res.energy, res.magnetic_forces, res.forces
                for c in self.constraints:
                    c.adjust_forces(self.images[nu], F)
            else:
                E, B = self.landscape(self.S[nu])
                F = np.zeros((n, 3))
            self.evaluations += 1
            if self.free.any():
                self._stiffness = max(self._stiffness, float(sphere.norms(B[self.free]).max()))
            Bt = sphere.tangent(B, self.S[nu]) / self.spin_length
            Bt[~self.free] = 0.0
            self.energies[nu] = E
            self.F[nu] = np.concatenate([F, Bt])

    @property
    def climbing_image(self):
        """The index of the climbing image (the highest inner one), or None."""
        if not self.climb:
            return None
        return 1 + int(np.argmax(self.energies[1:-1]))

    def forces(self):
        """The GNEB forces of the inner images, (M−2, 2N, 3) in y = (r, ℓu)
        units, and their unit tangents."""
        M = len(self.images)
        L = self.distances()
        if self.k is None:
            self.k = 0.1 * (self.stiffness or 1.0)
        ci = self.climbing_image
        out, tangents = [], []
        for nu in range(1, M - 1):
            t = self._tangent(nu)
            f = self.F[nu]
            along = sphere.inner(f, t)
            if nu == ci:
                g = f - 2.0 * along * t
            else:
                g = f - along * t + self.k * (L[nu] - L[nu - 1]) * t
            n = len(self.images[0])
            g[n:][~self.free] = 0.0
            if self.lattice:
                for c in self.constraints:
                    c.adjust_forces(self.images[nu], g[:n])
            out.append(g)
            tangents.append(t)
        return np.array(out), np.array(tangents)

    def fmax(self, forces=None):
        """The largest row of the inner images' GNEB forces: spins in eV
        (ℓ·|F_y|), atoms in eV/Å."""
        g = self.forces()[0] if forces is None else forces
        n = len(self.images[0])
        spins = sphere.norms(g[:, n:]).max() * self.spin_length
        atoms = sphere.norms(g[:, :n]).max() if self.lattice else 0.0
        return float(max(spins, atoms))

    # -- the band's minimiser -------------------------------------------------
    def run(self, fmax=1e-4, steps=1000):
        """Relax the band by velocity projection until :meth:`fmax` ≤ ``fmax``
        or ``steps`` steps; True if converged. The images' Atoms hold the band
        after the run."""
        fmax = checked_fmax(fmax)
        steps = integer(steps, "steps", minimum=0)
        n = len(self.images[0])
        G, _ = self.forces()
        if self.h is None:
            stiff = self.stiffness / self.spin_length**2
            stiff = max(stiff, LATTICE_STIFFNESS if self.lattice else 0.0)
            self.h = VP_STEP / stiff if stiff > 0.0 else 1.0
        v = np.zeros_like(G)
        G_old = None
        converged = self.fmax(G) <= fmax
        done = 0
        while not converged and done < steps:
            if G_old is not None:
                v = v + 0.5 * self.h * (G_old + G)
                v[:, n:] = sphere.tangent(v[:, n:], self.S[1:-1])
            v = project_velocity(v, G)
            d = v + 0.5 * self.h * G
            largest = float(sphere.norms(d).max())
            if largest > self.maxmove:
                d *= self.maxmove / largest
            for k_, nu in enumerate(range(1, len(self.images) - 1)):
                u = d[k_, n:] / self.spin_length
                self.S[nu][self.free] = sphere.exp_map(self.S[nu][self.free], u[self.free])
                if self.lattice:
                    self.Q[nu] += d[k_, :n]
            self._evaluate(range(1, len(self.images) - 1))
            G_old = G
            G, _ = self.forces()
            done += 1
            self.nsteps += 1
            converged = self.fmax(G) <= fmax
        self._write()
        return converged

    def _write(self):
        land = self.landscape
        for nu, im in enumerate(self.images):
            if 0 < nu < len(self.images) - 1:
                im.arrays["initial_magmoms"] = land.moments_of(self.S[nu])
                if self.lattice:
                    im.positions = self.Q[nu]

    # -- what the band shows ----------------------------------------------------
    def reaction_coordinate(self):
        """R_ν, the distance along the band from the first image."""
        return np.concatenate([[0.0], np.cumsum(self.distances())])

    def slopes(self):
        """dE/dR at the images: −F_y·τ̂ (one-sided tangents at the ends)."""
        _, tangents = self.forces()
        M = len(self.images)
        first = self._difference(0, 1, 0)
        last = self._difference(M - 2, M - 1, M - 1)
        ends = [first / (np.sqrt(sphere.inner(first, first)) or 1.0),
                last / (np.sqrt(sphere.inner(last, last)) or 1.0)]
        t = [ends[0], *tangents, ends[1]]
        return np.array([-sphere.inner(self.F[nu], t[nu]) for nu in range(M)])

    def path(self, points=20):
        """(R, E): the energy along the path, the cubic Hermite interpolation
        through the images (``points`` per interval)."""
        return hermite_path(self.reaction_coordinate(), self.energies, self.slopes(), points)

    def saddle(self):
        """(R*, E*): the highest point of the interpolated path."""
        return path_maximum(self.reaction_coordinate(), self.energies, self.slopes())

    def barrier(self, reverse=False):
        """E* − E_0 (eV), the barrier from the first state (from the last with
        ``reverse``), E* the highest point of the interpolated path."""
        top = self.saddle()[1]
        return top - (self.energies[-1] if reverse else self.energies[0])
