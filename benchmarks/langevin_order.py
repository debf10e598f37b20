"""Weak order of Langevin's sampling: the stationary bias of spin averages
against the step, measured with fixed seeds (the same set-ups as
tests/test_langevin.py's order tests, longer).

    python benchmarks/langevin_order.py [--per 2048] [--steps 3000]

Cases: (a) independent spins in a Zeeman field, x = μH/k_B T = 2, λ = 1:
⟨s·ĥ⟩ against coth x − 1/x; (b) exchange-coupled pairs, x = 1, J/k_B T = 2:
⟨s₁·ẑ⟩ and ⟨s₁·s₂⟩ against the exact two-spin averages; (c) the pairs without
field (exchange alone), sampled every 4th step, so that most steps take the
field at their end from their midpoint fields, against a pass there instead
(docs/thermostats.md). ωh: the step in units
of the largest precession period/2π. Variants: the scheme as shipped; its noise
with the first-order variance σ² = 2Dτ; its damping without the corrector
pass (fields frozen at the bath's start). Prints biases ± standard errors
(spread of per-spin time averages) and the order log2(b(h)/b(h/2)).
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))
sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))
sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests"))

import test_langevin as tl  # noqa: E402
from ase_spin.md import baths, langevin  # noqa: E402
from machine import describe  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--per", type=int, default=2048)
    ap.add_argument("--steps", type=int, default=3000)
    args = ap.parse_args(argv)
    print(describe())
    print(f"load average: {os.getloadavg()[0]:.2f}")
    import warnings
    warnings.simplefilter("ignore")
    plain = lambda d: np.sqrt(2.0 * d)  # noqa: E731
    damp_from = baths.damp_from

    def no_corrector(start, B, k, magnetic, out, y0=None, c=None, kick=None, keep=None):
        # keep the predicted spins y0: damping about the bath's first fields only
        np.copyto(out, y0)
        kick[:] = c[:, None] * np.cross(y0, B)
        keep[:] = B

    rows = []
    for case, kw, steps in (("Zeeman, x=2: <s.h>", {}, (2.4, 1.2, 0.6)),
                            ("pairs, x=1, J=2kT: <s1.z>, <s1.s2>",
                             dict(dimer_j=2.0, x=1.0), (1.6, 0.8, 0.4))):
        for variant in ("scheme", "sigma^2 = 2 D tau", "no corrector"):
            if variant == "no corrector" and not kw:
                continue
            if variant == "no corrector":
                baths.damp_from = no_corrector
            amp = plain if variant.startswith("sigma") else None
            try:
                out = []
                for wh in steps:
                    t0 = time.perf_counter()
                    b, se = tl.stationary_bias(wh, per=args.per, steps=args.steps,
                                               amplitude=amp, **kw)
                    out.append((wh, np.atleast_1d(b), np.atleast_1d(se)))
                    print(f"{case:36s} {variant:18s} ωh={wh:4.2f} bias "
                          + "  ".join(f"{x:+.5f} ± {e:.5f}" for x, e in
                                      zip(np.atleast_1d(b), np.atleast_1d(se)))
                          + f"  ({time.perf_counter() - t0:.0f} s)", flush=True)
            finally:
                baths.damp_from = damp_from
            for (h1, b1, _), (h2, b2, _) in zip(out, out[1:]):
                rows.append((case, variant, h1, h2, np.log2(np.abs(b1) / np.abs(b2))))
    # (c) the end field from the midpoint fields (exchange alone, order 2, steps
    # between samples: docs/thermostats.md) against a pass at the step's end
    closing = langevin.Langevin._closing_bath
    for variant in ("scheme", "end field by a pass"):
        if variant != "scheme":  # the closing bath without the midpoint fields
            langevin.Langevin._closing_bath = lambda self, midpoint_field=None: closing(self)
        try:
            for wh in (1.6, 0.8, 0.4):
                t0 = time.perf_counter()
                b, se = tl.stationary_bias(wh, per=args.per, steps=args.steps, dimer_j=2.0,
                                           x=0.0, interval=4)
                print(f"{'pairs, no field, every 4th: <s1.s2>':36s} {variant:18s} ωh={wh:4.2f} "
                      f"bias {b[1]:+.5f} ± {se[1]:.5f}  ({time.perf_counter() - t0:.0f} s)",
                      flush=True)
        finally:
            langevin.Langevin._closing_bath = closing
    print("observed order log2(b(h)/b(h/2)):")
    for case, variant, h1, h2, p in rows:
        print(f"  {case:36s} {variant:18s} {h1:4.2f}->{h2:4.2f}: "
              + "  ".join(f"{x:5.2f}" for x in p))


if __name__ == "__main__":
    main()
