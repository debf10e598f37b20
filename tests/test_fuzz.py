"""The fuzz campaign of tests/fuzz.py: every case a documented error with the
Atoms unchanged, or a correct finite result; no process dies.

The default run takes the quick subset (all families in one sequence of child
processes, restarted after a death, so a crash fails its case's test instead of
killing the run); ``-m slow`` runs the whole
campaign (every interrupt point, every truncation byte, orders 2 and 4).
"""

import os
import subprocess
import sys
import tempfile

import pytest

import fuzz
from conftest import PACKAGE_PATH

FAMILIES = list(fuzz.families(quick=True))


@pytest.fixture(scope="module")
def quick_outcomes():
    """Every quick family's outcome, from one sequence of child processes."""
    return fuzz.run_isolated_all(FAMILIES, quick=True)


def _assert_clean(outcome):
    bad = [(name, verdict, detail) for name, verdict, detail in outcome
           if verdict not in ("ok-error", "ok-result")]
    assert outcome and not bad, "\n".join(f"[{v}] {n}: {d}" for n, v, d in bad)


@pytest.mark.parametrize("family", FAMILIES)
def test_fuzz_family(family, quick_outcomes):
    _assert_clean(quick_outcomes[family])


@pytest.mark.slow
@pytest.mark.parametrize("family", FAMILIES)
def test_fuzz_family_full(family):
    _assert_clean(fuzz.run_isolated(family, quick=False))


def test_hypothesis_spins():
    assert fuzz.hypothesis_spins(max_examples=150) == 150


@pytest.mark.parametrize("examples", [pytest.param(40, id="quick"),
                                      pytest.param(400, id="full", marks=pytest.mark.slow)])
def test_hypothesis_cells_in_a_child_process(examples):
    code = (f"import sys; sys.path.insert(0, {str(fuzz.HERE)!r}); import fuzz; "
            f"print(fuzz.hypothesis_cells({examples}))")
    # from a neutral folder, with the copy the tests import ("-c" puts the working
    # folder first on sys.path: the tree's, when run from it)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=1200, cwd=tempfile.gettempdir(),
                         env={**os.environ, "PYTHONPATH": PACKAGE_PATH})
    assert out.returncode == 0, (out.returncode, out.stdout[-2000:], out.stderr[-4000:])
    assert int(out.stdout.split()[-1]) >= examples
