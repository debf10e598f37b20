"""Distance-dependent exchange couplings J(r): the :class:`Coupling`
interface, its compiled forms (:class:`BetheSlater`, :class:`Cubic`) and the
per-species-pair table through which the compiled kernels read them."""

from __future__ import annotations

import numpy as np

from ..validate import MAX_COUPLING, length, real_scalar, warn_implausible
from .parameters import Parameterised

__all__ = ["Coupling", "BetheSlater", "Cubic", "FORM_OFF", "FORM_BETHE_SLATER", "FORM_CUBIC",
           "FORM_PYTHON", "RC2", "FORM", "P0", "P1", "P2", "checked_values", "check_coupling",
           "check_size"]

#: Coupling forms the compiled kernels evaluate directly (a coupling's
#: ``_form``); anything else (FORM_PYTHON) is evaluated by its own
#: (vectorised) ``values(r)``; FORM_OFF: a pair switched off.
FORM_OFF, FORM_BETHE_SLATER, FORM_CUBIC, FORM_PYTHON = 0, 1, 2, 3
#: Columns of the per-species-pair table (:meth:`~ase_spin.terms.exchange.Exchange.bind`):
#: rc², the form, and the form's three parameters (a coupling's ``_params``).
RC2, FORM, P0, P1, P2 = range(5)


class Coupling(Parameterised):
    """A distance-dependent exchange coupling J(r) (eV).

    Subclasses implement :meth:`values` returning ``(J(r), J'(r))`` for an array
    of distances; any object with such a method (and an ``rc`` attribute, the
    distance beyond which J vanishes, or None) plugs into
    :class:`~ase_spin.terms.exchange.Exchange`.
    Parameters of the couplings here may be reassigned (``bs.J1 = ...``); the
    terms and integrators using them notice. Other objects are taken to be
    fixed once given to a term.
    """

    rc = None
    _form = FORM_PYTHON
    _params = (0.0, 0.0, 0.0)

    def values(self, r):
        raise NotImplementedError

    def __call__(self, r):
        return self.values(np.asarray(r, dtype=float))[0]

    def derivative(self, r):
        return self.values(np.asarray(r, dtype=float))[1]


class BetheSlater(Coupling):
    r"""The Bethe–Slater form of LAMMPS ``pair_style spin/exchange``:

    .. math::

        J(r) = 4 J_1 \left(\frac{r}{J_3}\right)^2
               \left[1 - J_2 \left(\frac{r}{J_3}\right)^2\right] e^{-(r/J_3)^2},

        J'(r) = 8 J_1 \frac{r}{J_3^2} e^{-(r/J_3)^2}
               \left[1 - \left(\frac{r}{J_3}\right)^2
               - J_2 \left(\frac{r}{J_3}\right)^2 \left(2 - \left(\frac{r}{J_3}\right)^2\right)\right].

    J1 in eV, J2 dimensionless, J3 in Å. It has no cutoff of its own: the
    :class:`~ase_spin.terms.exchange.Exchange` term's ``rc`` cuts it off hard
    (J(rc) ≠ 0 in general).
    """

    _form = FORM_BETHE_SLATER

    _parameters = {"J1": "J1", "J2": "J2", "J3": "J3"}

    def __init__(self, J1, J2, J3):
        self.J1 = real_scalar(J1, "BetheSlater J1")
        check_size(self.J1, "BetheSlater J1")
        self.J2 = real_scalar(J2, "BetheSlater J2")
        self.J3 = length(J3, "BetheSlater J3")
        # kernel parameters: J1, J2 and 1/J3² (a product per pair, not a division)
        self._params = (self.J1, self.J2, 1.0 / self.J3**2)
        self._finish()

    def values(self, r):
        x = (r / self.J3) ** 2
        ex = np.exp(-x)
        J = 4.0 * self.J1 * x * (1.0 - self.J2 * x) * ex
        dJ = 8.0 * self.J1 * r / self.J3**2 * ex * (1.0 - x - self.J2 * x * (2.0 - x))
        return J, dJ

    def __repr__(self):
        return f"BetheSlater(J1={self.J1}, J2={self.J2}, J3={self.J3})"


class Cubic(Coupling):
    r"""The cubic form of Ma, Woo and Dudarev used in the paper:

    .. math::

        J(r) = J_0 (1 - r/r_c)^3 \,\Theta(r_c - r), \qquad
        J'(r) = -\frac{3 J_0}{r_c} (1 - r/r_c)^2 \,\Theta(r_c - r).

    J and J' both vanish at r_c, so this coupling needs no cutoff of its own.
    """

    _form = FORM_CUBIC

    _parameters = {"J0": "J0", "rc": "rc"}

    def __init__(self, J0, rc):
        self.J0 = real_scalar(J0, "Cubic J0")
        self.rc = length(rc, "Cubic rc")
        # J0 is J(0), where no pair is (J0 = 2 eV gives 10 meV at 5/6 rc): the
        # value at rc/2, J0/8, is at or below any neighbour's within the cutoff
        check_size(self.J0 / 8.0, f"Cubic J(rc/2) = J0/8 (J0 = {self.J0:g} eV)")
        self._params = (self.J0, self.rc, 1.0 / self.rc)
        self._finish()

    def values(self, r):
        x = np.where(r < self.rc, 1.0 - r / self.rc, 0.0)
        return self.J0 * x**3, -3.0 * self.J0 / self.rc * x**2

    def __repr__(self):
        return f"Cubic(J0={self.J0}, rc={self.rc})"


def check_size(J, what):
    """ImplausibleParameterWarning for a coupling |J| above MAX_COUPLING eV
    (per pair; ``J`` a number or an array of them)."""
    J = np.asarray(J, dtype=float)
    warn_implausible(float(np.abs(J).max(initial=0.0)), MAX_COUPLING, what, "eV",
                     "exchange couplings are meV to ~0.1 eV per pair", "energy")


def checked_values(coupling, r):
    """(J, J') of a coupling evaluated by its own ``values(r)``, checked: a NaN
    here would otherwise reach the spins of every atom within a step."""
    J, dJ = coupling.values(r)
    J = np.asarray(J, dtype=float)
    dJ = np.asarray(dJ, dtype=float)
    if J.shape != r.shape or dJ.shape != r.shape:
        raise ValueError(f"coupling {coupling!r}: values(r) must return two arrays shaped "
                         f"like r {r.shape}, got {J.shape} and {dJ.shape}")
    bad = ~(np.isfinite(J) & np.isfinite(dJ))
    if bad.any():
        k = int(np.argmax(bad))
        raise ValueError(f"coupling {coupling!r} returned non-finite values at r = {float(r[k])} Å: "
                         f"J = {J[k]}, J' = {dJ[k]}")
    return J, dJ


def check_coupling(c, what):
    """``c`` if it is a coupling (has ``values(r)``) or None, else TypeError."""
    if c is not None and not callable(getattr(c, "values", None)):
        raise TypeError(f"{what}: a coupling needs a values(r) -> (J, dJ) method; got {c!r}")
    return c
