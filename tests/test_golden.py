"""The golden record (tests/golden.py): every reference scene ends on the same
bits as recorded: before the reorganisation, and twice since, when the end points
of the locally exact sweeps stopped accumulating W's rounding, and when
CollectivePRK took F_L at the q̃ of its couplings (so that the compiled step
makes it beside the solve; within round-off of the last drift's q̃)."""

import numpy as np
import pytest

import golden

RECORD = golden.load()


@pytest.mark.parametrize("name", list(golden.SCENES))
def test_scene_ends_on_the_recorded_bits(name, monkeypatch):
    golden.general_path(name, monkeypatch.setattr)
    digest, fingerprint = golden.run(name)
    hashes = RECORD["hashes"].get(golden.cpu())
    if hashes is not None and name in hashes:
        assert digest == hashes[name], f"{name}: the trajectory's bits changed"
    else:  # another CPU: the last bits may differ, ten digits may not
        np.testing.assert_allclose(fingerprint, RECORD["fingerprints"][name], rtol=1e-9,
                                   atol=1e-12)


def test_the_record_holds_every_scene():
    assert set(RECORD["fingerprints"]) == set(golden.SCENES)
    assert any(set(h) == set(golden.SCENES) for h in RECORD["hashes"].values())
