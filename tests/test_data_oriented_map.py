"""The data-oriented map (point store, array gathers, compiled search) computes what the
object map computed: same trajectory on short deterministic runs (references recorded by
the last commit before it, see tests/data/README.md)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.conftest import E2E_FRAMES, run_cli

DATA = Path(__file__).parent / "data"


def _poses(path: Path) -> np.ndarray:
    return np.loadtxt(path, comments="#")


# Static scene only: with people in view the ORB core fails (26 cm ATE) and its run is
# chaotic, so the local BA's solver change (Schur LM, equal to GTSAM to its tolerance)
# moves that trajectory by centimetres; the walking reference is kept for the record.
@pytest.mark.parametrize("fixture,name", [("static_render", "static_xyz")])
def test_same_trajectory_as_the_object_map(fixture: str, name: str, request: pytest.FixtureRequest,
                                           tmp_path: Path) -> None:
    assert E2E_FRAMES == 90
    seq = request.getfixturevalue(fixture)
    run_cli(seq, tmp_path, "--preset", "orb", "--sequential", "--no-report", "--set",
            "features.extractor=orb_opencv")
    new = _poses(tmp_path / "trajectory.txt")
    ref = _poses(DATA / f"orb_opencv_{name}90_object_map.txt")
    assert new.shape == ref.shape
    assert np.array_equal(new[:, 0], ref[:, 0])
    # Numerical noise only (the references were byte-identical when recorded).
    assert np.abs(new[:, 1:4] - ref[:, 1:4]).max() < 1e-6
