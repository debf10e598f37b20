"""The integrators' errors and warnings: a step that could not be taken (the
Atoms keep the state before it) and an implausible timestep."""

from __future__ import annotations

__all__ = ["TimestepWarning", "IntegrationError", "SpinConvergenceError", "UnstableStepError"]


class TimestepWarning(UserWarning):
    """The timestep is implausible for the system (too large for its fastest
    precession or vibration, or absurdly small).

    Its figures are kept apart from its wording, for a front end that speaks
    to its users in its own terms (``ase-spin run`` names the input file's
    ``timestep = ... (fs)``): ``timestep_fs``, ``problems`` (one phrase each),
    ``advice`` (the rule the timestep should keep) and ``hint`` (for a Python
    caller, where the numbers suggest a unit slip; else empty). The text is
    ``timestep <fs> fs: <problems>; <advice>. <hint>``.
    """

    def __init__(self, timestep_fs, problems, advice, hint=""):
        super().__init__(timestep_fs, tuple(problems), advice, hint)

    timestep_fs = property(lambda self: self.args[0])
    problems = property(lambda self: self.args[1])
    advice = property(lambda self: self.args[2])
    hint = property(lambda self: self.args[3])

    def __str__(self):
        text = f"timestep {self.timestep_fs:.4g} fs: {'; '.join(self.problems)}; {self.advice}."
        return f"{text} {self.hint}" if self.hint else text


class IntegrationError(RuntimeError):
    """A step could not be taken; the Atoms keep the state before it."""


class SpinConvergenceError(IntegrationError):
    """The implicit equation for the midpoint spins was not solved."""


class UnstableStepError(IntegrationError):
    """The step is implausibly large: an atom moved too far, or a spin was to
    rotate too far, in one step."""
