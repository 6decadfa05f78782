"""The semantic presets end to end: STDC-SLAM (``stdc``) and DDL-SLAM (``ddl``) through the
CLI on the shared 90-frame walking render, and DDL-SLAM's multi-view geometry culling map
points on a mover no class covers.

References are independent of the code under test: the renderer's exact poses (ATE, also
recomputed by evo) and its per-pixel labels (15 = person, 21 = the unlabelled mover).

Bounds. With people masked the ORB core keeps static-scene accuracy (< 2 cm; measured on
this render: stdc 0.47 cm, ddl 0.42 cm, default 0.46 cm), while ``orb`` without masks
follows the people (measured 51 cm on 120 frames of the same sequence, too slow to run
here: the map fills with points on people). The masked fraction of the image must match the
true person fraction: measured 0.98x (stdc: segmentation + SRM) and 1.09x (ddl: its
multi-view mask adds a little) of the labelled 15.6 %.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from semslam.config import load_config
from semslam.eval.metrics import ate
from semslam.geometry.camera import PinholeCamera
from semslam.core.types import Frame
from semslam.core.trajectory import Trajectory
from semslam.api import System
from semslam.core.types import TrackingState
from semslam.synth import SEQUENCES, Renderer
from tests.conftest import E2E_FRAMES, evo_ate, rendered_frames, run_cli

PERSON, MOVER = 15, 21


def _label_fraction(seq: Path, label: int) -> float:
    """Mean fraction of pixels with ``label`` over the rendered ``semantic/`` images."""
    files = sorted((seq / "semantic").glob("*.png"))
    assert len(files) == E2E_FRAMES
    return float(np.mean([(cv2.imread(str(f), cv2.IMREAD_UNCHANGED) == label).mean() for f in files]))


@pytest.mark.slow
@pytest.mark.parametrize("preset", ["stdc", "ddl"])
def test_semantic_preset_masks_people_and_keeps_accuracy(walking_render: Path, tmp_path: Path,
                                                         preset: str) -> None:
    pytest.importorskip("mediapipe")
    seq, out = walking_render, tmp_path / preset
    stats = run_cli(seq, out, "--preset", preset, "--sequential", "--no-report")
    assert stats["preset"] == preset
    assert stats["tracked_frames"] == stats["frames"] == E2E_FRAMES
    truth = _label_fraction(seq, PERSON)
    assert truth > 0.1  # people really are in view
    assert 0.8 * truth < stats["dynamic_ratio_mean"] < 1.25 * truth, (stats["dynamic_ratio_mean"], truth)
    assert stats["ate"]["rmse"] < 0.02
    assert abs(stats["ate"]["rmse"] - evo_ate(seq / "groundtruth.txt", out / "trajectory.txt")) < 1e-9


# ---------------------------------------------------------------- multi-view culling
#: mover_xyz rendered over 6 s, tracked from 2 s on: the cabinet is near the end of its
#: swing (slow) when the map is built, so points land on it, then it rolls back across the
#: view and only the multi-view check can tell (the person segmenter sees no class there).
MOVER_RENDER, MOVER_START = 180, 60


@pytest.fixture(scope="module")
def mover_frames() -> tuple[list[Frame], Trajectory, PinholeCamera]:
    cfg = SEQUENCES["mover_xyz"].replace(frames=MOVER_RENDER)
    r = Renderer(cfg)
    frames = rendered_frames(r, range(MOVER_START, MOVER_RENDER))
    gt = Trajectory(r.times[MOVER_START:].copy(), r.poses[MOVER_START:].copy())
    return frames, gt, PinholeCamera(*cfg.intrinsics())


@pytest.mark.slow
def test_ddl_multiview_culls_points_on_unlabelled_mover(mover_frames: tuple[list[Frame], Trajectory, PinholeCamera]) -> None:
    """DDL-SLAM's multi-view geometry finds the cabinet moving, culls the map points mapped
    on it and the pose stays right: ATE < 2 cm (measured 0.76 cm, 3 points culled), where
    the same preset with ``dynamics.multiview=false`` measured 55.7 cm and ``orb`` 55.3 cm
    on these frames (not run here, 45 s each)."""
    pytest.importorskip("mediapipe")
    frames, gt, cam = mover_frames
    system = System(load_config("ddl", ["slam.sequential=true"]), cam)
    states = [system.track_frame(system.prepare(f)).state for f in frames]
    system.close()
    assert all(s is TrackingState.OK for s in states)
    # Not in stats.json (yet): the tracker's own counter, through the Python API.
    assert system.tracker.stats()["culled_dynamic_points"] > 0
    assert ate(gt, system.trajectory(), align="se3").stats["rmse"] < 0.02
