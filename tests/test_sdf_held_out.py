"""Monocular SDF-SLAM in the held-out room (layout 1, the lounge): the shipped SDFCNN never saw
it, so this is the issue's held-out setting on a short render, with bounds from what was
measured (a regression check; the 300-frame numbers are in the README)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.conftest import run_cli


@pytest.fixture(scope="module")
def lounge_static(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``static_xyz`` in layout 1, 60 frames at 320x240."""
    from semslam.synth import SEQUENCES, render_sequence

    cfg = SEQUENCES["static_xyz"].replace(frames=60, width=320, height=240, layout=1)
    return render_sequence(cfg, tmp_path_factory.mktemp("held_out") / "static_xyz_l1")


#: preset -> (extra options, Sim(3) bound m, SE(3) bound m, |scale - 1| bound), from what the
#: shipped SDFCNN (trained on the office and random rooms 4-99, 2026-11-29 evening) gave, with
#: margin: ``sdf_paper`` (SDF-SLAM's own tracker) on RootSIFT 0.71 cm Sim(3), 1.07 cm SE(3), scale 1.063; ``sdf_rgbd`` 3.12 /
#: 3.63 cm, scale 0.877. The office-only weights shipped before gave 1.28 / 5.3 cm, scale 1.63
#: (their depth was ~40 % short in this larger room) and 4.9 / 5.1 cm, scale 1.13.
RUNS = {
    "sdf_paper": (["--set", "features.extractor=sift", "--set", "features.matcher=default"], 0.02, 0.03, 0.2),
    "sdf_rgbd": ([], 0.07, 0.08, 0.3),
}


@pytest.mark.parametrize("preset", sorted(RUNS))
def test_held_out_room_tracks_with_bounded_ate(lounge_static: Path, tmp_path: Path, preset: str) -> None:
    extra, sim3_bound, se3_bound, scale_bound = RUNS[preset]
    stats = run_cli(lounge_static, tmp_path / "run", "--preset", preset, "--set", "slam.sequential=true",
                    "--map", "none", *extra)
    assert stats["frames"] == 60 and stats["tracked_frames"] >= 55
    assert stats["ate"]["rmse"] < sim3_bound
    assert np.isfinite(stats["ate_se3"]["rmse"]) and stats["ate_se3"]["rmse"] < se3_bound
    assert abs(stats["ate_sim3_scale"] - 1.0) < scale_bound
