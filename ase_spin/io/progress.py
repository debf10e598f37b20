"""A progress bar for any ASE dynamics (tqdm): steps done, steps/s, time left.

``dyn.run(steps, progress=True)`` on the integrators here, or
``run_with_progress(dyn, steps)`` for any ASE ``MolecularDynamics`` /
``Optimizer``. The bar is updated between steps from ``dyn.irun`` (here: after
each step or block of steps ``run`` takes); it adds no observer, so the
integrators still compute energies only on logged steps.
"""

from __future__ import annotations

import sys

__all__ = ["run_with_progress"]


def run_with_progress(dyn, steps=50, progress=True):
    """Run ``dyn`` for ``steps`` steps with a tqdm bar on stderr.

    ``progress``: True, or a dict of options for :class:`tqdm.tqdm` (``desc``,
    ``file``, ``mininterval``, ``disable``...). Returns what ``dyn.run`` returns
    (ASE: True when the requested steps were all taken). The bar is closed
    whatever happens (an error or Ctrl-C in a step).
    """
    try:
        from tqdm import tqdm
    except ImportError:  # pragma: no cover - tqdm is a dependency
        raise ImportError("progress bars need tqdm: pip install tqdm") from None
    options = {"desc": type(dyn).__name__, "unit": "step", "file": sys.stderr,
               "dynamic_ncols": True, "smoothing": 0.1}
    if isinstance(progress, dict):
        options.update(progress)
    elif progress is not True:
        raise TypeError(f"progress must be True, False or a dict of tqdm options, "
                        f"got {progress!r}")
    converged = steps == 0
    # this package's integrators may take several steps between two yields
    # (SpinLatticeDynamics.run's blocks): the bar follows the step counter
    blocks = getattr(dyn, "_irun", None)
    steps_run = blocks(steps, blocks=True) if blocks else dyn.irun(steps=steps)
    with tqdm(total=steps, **options) as bar:
        start = dyn.nsteps
        # yields once before the first step (state at start), then after each step or block
        for converged in steps_run:
            bar.update(dyn.nsteps - start - bar.n)
    return converged
