"""The integrators' errors and warnings: a step that could not be taken (the
Atoms keep the state before it) and an implausible timestep."""

from __future__ import annotations

__all__ = ["TimestepWarning", "IntegrationError", "SpinConvergenceError", "UnstableStepError"]


class TimestepWarning(UserWarning):
    """The timestep is implausible for the system (too large for its fastest
    precession or vibration, or absurdly small)."""


class IntegrationError(RuntimeError):
    """A step could not be taken; the Atoms keep the state before it."""


class SpinConvergenceError(IntegrationError):
    """The implicit equation for the midpoint spins was not solved."""


class UnstableStepError(IntegrationError):
    """The step is implausibly large: an atom moved too far, or a spin was to
    rotate too far, in one step."""
