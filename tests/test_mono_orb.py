"""Plain monocular ORB core (``--preset mono``: no depth at all) end to end through the CLI,
``--sequential`` (deterministic): two-view initialisation (slam/orb/mono_init.py), tracking
with 2-residual observations, points only from local mapping's triangulation.

Numbers measured here (this machine), the bounds a little above them:

- ``static_xyz`` render, 90 frames: initialised at frame 19 (the pairs before are refused by
  geometry/two_view as ambiguous: under ~1.5 deg of parallax; 27 before R_H 0.50 and the
  multi-start E), no frame lost afterwards, 9 keyframes, Sim(3) ATE 0.37 cm against the RGB-D
  preset's 0.36 cm SE(3) on the same frames (issue 40's target: within 2x of RGB-D). 300
  frames: initialised at frame 29, 0.45 cm (RGB-D 0.35 cm).
- Real TUM fr2_desk, first 50 frames: initialised at frame 11, the 39 frames after all tracked,
  12 keyframes, Sim(3) ATE 0.47 cm (RGB-D ``orb``: 0.93 cm SE(3) over all 50 frames,
  tests/test_real_fr2_desk.py; Sim(3) has one more degree of freedom and 10 frames fewer).

The Sim(3) ATE is checked against evo's scale-corrected alignment, an independent reference.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from semslam.config import load_config
from semslam.features import create_extractor
from semslam.features.matching import matcher_for
from semslam.geometry.camera import PinholeCamera
from semslam.slam.orb.frame_builders import MonocularFrameBuilder, is_monocular
from semslam.slam.orb.frame_state import FrameState
from semslam.slam.orb.mono_init import MonocularInitializer
from semslam.slam.orb.tracker import create_tracker
from tests.conftest import evo_ate, run_cli

FR2_DESK = "rgbd_dataset_freiburg2_desk_first50"


def _frames(gray: np.ndarray, shifts: list[tuple[float, float]]) -> tuple[MonocularInitializer, list[FrameState]]:
    """The image and copies translated by ``shifts`` (pixels) as monocular frames."""
    h, w = gray.shape
    camera = PinholeCamera(520.9, 521.0, w / 2, h / 2, width=w, height=h)
    extractor = create_extractor(load_config("mono").features, (w, h))
    builder = MonocularFrameBuilder(camera)
    frames = []
    for i, (dx, dy) in enumerate([(0.0, 0.0), *shifts]):
        img = cv2.warpAffine(gray, np.float32([[1, 0, dx], [0, 1, dy]]), (w, h), borderMode=cv2.BORDER_REFLECT)
        frames.append(builder.build(i, i / 30, extractor.extract(img, None)))
    spec = extractor.spec
    return MonocularInitializer(camera, matcher_for(spec), spec.th_low, 0), frames


def test_search_for_initialization_finds_a_known_shift_inside_its_window(real_gray: np.ndarray) -> None:
    # An image and its copy moved by (12, -7) px: every true match moved by exactly that
    # (away from the reflected border); by 150 px (outside ORB-SLAM's 100 px window) none can be found.
    init, (f0, near, far) = _frames(real_gray, [(12.0, -7.0), (150.0, 0.0)])
    i0, i1 = init.match(f0, near)
    shift = near.xy[i1] - f0.xy[i0]
    # Within 1.5 px at the keypoint's pyramid scale (measured: 471 matches of 1004
    # keypoints, 97.9 % right, median error 0.52 px).
    right = np.linalg.norm(shift - [12.0, -7.0], axis=1) < 1.5 * 1.2 ** f0.keypoints.octave[i0]
    assert len(i0) >= 350, len(i0)
    assert right.mean() > 0.95, right.mean()
    assert len(np.unique(i1)) == len(i1)  # one match per keypoint of the current frame
    i0, i1 = init.match(f0, far)
    moved = np.linalg.norm(far.xy[i1] - f0.xy[i0] - [150.0, 0.0], axis=1) < 3.0
    assert moved.sum() == 0


def test_reference_is_dropped_when_too_few_matches(real_gray: np.ndarray) -> None:
    # ORB-SLAM's MonocularInitialization: < 100 matches drops the reference; the next frame
    # with > 100 keypoints becomes it.
    init, (f0, far, f2) = _frames(real_gray, [(150.0, 0.0), (2.0, 1.0)])
    assert init.attempt(f0) is None and init.reference is f0
    assert init.attempt(far) is None and init.reference is None
    assert init.attempt(f2) is None and init.reference is f2
    assert init.attempt(f0) is None  # a 2 px shift has no parallax: refused, reference kept
    assert init.reference is f2 and init.attempts == 1 and sum(init.reasons.values()) == 1


def test_mono_preset_builds_a_depthless_tracker() -> None:
    cfg = load_config("mono", ["slam.sequential=true"])
    assert cfg.sensor == "mono" and cfg.depth.source == "sensor" and is_monocular(cfg)
    assert cfg.slam.loop_closing and cfg.slam.new_map_after_s == 1.5  # Sim(3) loops and merges (test_mono_atlas.py)
    camera = PinholeCamera(520.9, 521.0, 325.1, 249.7, width=640, height=480)
    tracker = create_tracker(cfg, camera)  # refused before issue 40
    try:
        assert isinstance(tracker.tracking.builder, MonocularFrameBuilder)
        assert tracker.tracking.mono and tracker.mapper.mono and tracker.closer.mono
    finally:
        tracker.shutdown()
    assert not is_monocular(load_config("orb"))
    assert not is_monocular(load_config("sdf_rgbd"))  # mono camera on a depth network: RGB-D path


@pytest.mark.slow
def test_mono_tracks_a_render_close_to_rgbd(static_render: Path, tmp_path: Path) -> None:
    mono = run_cli(static_render, tmp_path / "mono", "--preset", "mono", "--sequential", "--no-report")
    rgbd = run_cli(static_render, tmp_path / "orb", "--preset", "orb", "--sequential", "--no-report")
    n = mono["frames"]
    assert mono["uninitialized_frames"] <= 22, mono["uninitialized_frames"]  # measured 19
    # Every pair before was tried and refused by geometry/two_view (too little parallax).
    assert mono["mono_init_attempts"] == sum(mono["mono_init_refused"].values()) + 1
    assert "mono_init_attempts" not in rgbd
    # Every frame after initialisation tracked: none lost, no relocalisation.
    assert mono["lost_frames"] == 0 and mono["relocalisations"] == 0
    assert mono["tracked_frames"] == n - mono["uninitialized_frames"]
    assert mono["ate_alignment"] == "sim3"
    ate = mono["ate"]["rmse"]
    assert ate == pytest.approx(evo_ate(static_render / "groundtruth.txt",
                                    tmp_path / "mono" / "trajectory.txt", correct_scale=True), abs=1e-9)
    assert ate < 0.0045, ate  # measured 0.37 cm
    # The map's scale is the initial pair's (median depth 1), not metres.
    assert not 0.8 < mono["ate_sim3_scale"] < 1.25, mono["ate_sim3_scale"]
    ratio = ate / rgbd["ate"]["rmse"]
    assert ratio < 2.0, ratio  # issue 40's target; measured 1.03
    assert 3 <= mono["keyframes"] <= n // 5, mono["keyframes"]  # measured 9
    assert mono["triangulated_points"] > 0  # the map grows by triangulation only


@pytest.mark.slow
def test_mono_keeps_its_scale_over_a_longer_render(tmp_path: Path) -> None:
    # 300 frames: the map outgrows the initial pair, local BA windows hold one fixed keyframe
    # only, and a monocular BA's free scale shrank the whole map to nothing (Sim(3) ATE
    # 27.6 cm before the second fixed keyframe, 0.45 cm with it; RGB-D orb 0.35 cm).
    from semslam.synth import SEQUENCES, render_sequence

    seq = render_sequence(SEQUENCES["static_xyz"].replace(frames=300), tmp_path / "seq")
    stats = run_cli(seq, tmp_path / "run", "--preset", "mono", "--sequential", "--no-report", "--map", "none")
    assert stats["lost_frames"] == 0
    assert stats["uninitialized_frames"] <= 30, stats["uninitialized_frames"]  # measured 29 (slower motion)
    assert stats["ate"]["rmse"] < 0.006, stats["ate"]["rmse"]  # measured 0.45 cm
    traj = np.loadtxt(tmp_path / "run" / "trajectory.txt")
    # The camera still moves in the map's units at the end: no collapse of the scale.
    last = np.linalg.norm(np.diff(traj[-60:, 1:4], axis=0), axis=1).sum()
    first = np.linalg.norm(np.diff(traj[:60, 1:4], axis=0), axis=1).sum()
    assert last > 0.2 * first, (first, last)


@pytest.mark.slow
def test_mono_initialises_on_real_fr2_desk(shared_data: Path, tmp_path: Path) -> None:
    seq = shared_data / FR2_DESK
    if not seq.is_dir():
        pytest.skip(f"{seq} not found")
    out = tmp_path / "run"
    stats = run_cli(seq, out, "--preset", "mono", "--sequential", "--no-report")
    assert stats["uninitialized_frames"] <= 30, stats["uninitialized_frames"]  # measured 11
    assert stats["lost_frames"] == 0
    assert stats["tracked_frames"] == stats["frames"] - stats["uninitialized_frames"]
    ate = stats["ate"]["rmse"]
    assert ate == pytest.approx(evo_ate(seq / "groundtruth.txt", out / "trajectory.txt", correct_scale=True), abs=1e-9)
    assert ate < 0.0065, ate  # measured 0.47 cm; a camera standing still scores 12 cm
    assert np.isfinite(stats["ate_sim3_scale"])


def _aligned_errors(seq: Path, run: Path) -> tuple[np.ndarray, int]:
    """Position errors (m) of every tracked frame once the run is aligned to the ground truth
    by a Sim(3) fitted on the frames before the first gap only: the rotation from their
    orientations (their positions are nearly collinear), then scale and translation by least
    squares. Returns the errors and the index of the last frame before the gap."""
    from semslam.io.trajectory import read_tum

    gt, est = read_tum(seq / "groundtruth.txt"), read_tum(run / "trajectory.txt")
    rows = np.array([int(np.argmin(np.abs(gt.timestamps - t))) for t in est.timestamps])
    gap = int(np.argmax(np.diff(rows)))
    Rg, pg, pe = gt.poses[rows, :3, :3], gt.poses[rows, :3, 3], est.poses[:, :3, 3]
    U, _, Vt = np.linalg.svd(np.einsum("nij,nkj->ik", Rg[:gap + 1], est.poses[:gap + 1, :3, :3]))
    R = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    A = np.column_stack([(pe[:gap + 1] @ R.T).reshape(-1), np.tile(np.eye(3), (gap + 1, 1))])
    x = np.linalg.lstsq(A, pg[:gap + 1].reshape(-1), rcond=None)[0]
    return np.linalg.norm(x[0] * pe @ R.T + x[1:] - pg, axis=1), gap


@pytest.mark.slow
def test_mono_relocalises_after_a_blackout(tmp_path: Path) -> None:
    """1 s of black frames (30) from 1.4 s into a 120-frame xyz render: monocular tracking is
    lost, stays lost (no new map in mono) and relocalises (bag of words, EPnP RANSAC, pose
    optimisation) on the first frame after; the poses after are in the map of before.

    Measured (seed 13 layout 0 here; seeds/layouts 3/2 and 5/3 beside it): relocalised on frame
    72, errors after it 0.42 cm RMSE, 0.89 cm worst (0.58/1.08, 1.06/1.51) against 0.35 cm
    before; 240-frame jump_back renders (a 90 deg cut to an unmapped wall and back) relocalise
    on the way back with 1.0-1.4 cm RMSE after."""
    from semslam.synth import SEQUENCES, render_sequence

    cfg = SEQUENCES["blackout_xyz"].replace(frames=120, blackout_start_s=1.4, blackout_s=1.0)
    seq = render_sequence(cfg, tmp_path / "seq")
    out = tmp_path / "run"
    stats = run_cli(seq, out, "--preset", "mono", "--sequential", "--no-report", "--map", "none")
    assert stats["uninitialized_frames"] < 42  # initialised before the lens goes black
    assert stats["relocalisations"] == 1
    assert stats["lost_frames"] == 30, stats["lost_frames"]  # the black frames only
    err, gap = _aligned_errors(seq, out)
    after = err[gap + 1:]
    assert len(after) == stats["frames"] - 72
    assert np.sqrt(np.mean(after ** 2)) < 0.008, after  # measured 0.42 cm
    assert after.max() < 0.015, after.max()  # measured 0.89 cm
