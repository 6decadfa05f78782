"""Multi-view geometry with the settings of the ``default`` preset: it finds the large box
of ``walking_box`` (class 21, which no segmenter flags) and leaves a static scene alone.

Frames come from the renderer in memory with exact poses and labels; the reference
keyframes are the frames 8-40 before the tested one (ORB keypoints with depth, as the
tracker gives them), so the check sees the box where it stood up to ~1.3 s earlier.
The lift test shows why the default preset prefers keyframes at least 0.7 s old.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from semslam.config import load_config
from semslam.dynamics.masks import dilate
from semslam.dynamics.multiview import multiview_mask, pick_references
from semslam.features import create_extractor
from semslam.geometry.camera import PinholeCamera
from semslam.geometry.se3 import invert
from semslam.synth import SEQUENCES, Renderer

PERSON, MOVER = 15, 21
LAGS = (8, 16, 24, 32, 40)


class Views:
    """Rendered frames and keyframe-like views (pose, undistorted keypoints, their depth)."""

    def __init__(self, sequence: str, frames: int) -> None:
        cfg = SEQUENCES[sequence].replace(frames=frames)
        self.r = Renderer(cfg)
        self.cam = PinholeCamera(*cfg.intrinsics())
        self.ext = create_extractor(load_config("orb").features)

    def depth(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        f = self.r.render(i)
        return f.depth.astype(np.float32) / 5000.0, f.semantic

    def keyframe(self, i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        f = self.r.render(i)
        kps = self.ext.extract(cv2.cvtColor(f.rgb, cv2.COLOR_RGB2GRAY))
        depth = f.depth.astype(np.float32) / 5000.0
        u = np.clip(np.rint(kps.xy[:, 0]).astype(int), 0, depth.shape[1] - 1)
        v = np.clip(np.rint(kps.xy[:, 1]).astype(int), 0, depth.shape[0] - 1)
        return invert(self.r.poses[i]), self.cam.undistort_points(kps.xy), depth[v, u]

    def check(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """(moving-region mask of frame ``i`` with the default preset's settings, labels)."""
        dyn = load_config("default").dynamics
        refs = [self.keyframe(i - lag) for lag in LAGS][: dyn.multiview_keyframes]
        depth, sem = self.depth(i)
        return multiview_mask(invert(self.r.poses[i]), depth, self.cam, refs, dyn).mask, sem


def test_default_runs_the_multiview_check() -> None:
    dyn = load_config("default").dynamics
    assert dyn.semantic and dyn.multiview


@pytest.mark.slow
@pytest.mark.parametrize("frame", [75, 200])
def test_default_multiview_flags_the_box(frame: int) -> None:
    """Frame 75: the box is pushed along the floor (20 % of the image); frame 200: it is
    carried up to the camera (54 %). Measured: 0.9 of the box flagged in both, no static
    pixel."""
    mask, sem = Views("walking_box", frame + 1).check(frame)
    box = sem == MOVER
    assert box.mean() > 0.15
    assert (mask & box).sum() > 0.8 * box.sum()
    static = (sem >= 100) & ~dilate(box | (sem == PERSON), 4)  # silhouettes are uncertain
    assert (mask & static).sum() < 0.02 * box.sum()


@pytest.mark.slow
def test_default_multiview_leaves_static_scene_alone() -> None:
    """static_xyz: in these frames the check without its static-occluder test flags
    0.5-0.9 % of the image at downscale 4 (0.9-2.1 % at 2): a desk leg or the chair post
    hides background points the reference views saw beside it once the camera has moved.
    Measured with the test: nothing."""
    views = Views("static_xyz", 271)
    for frame in (105, 120, 135, 270):
        mask, sem = views.check(frame)
        assert mask.mean() < 0.005, (frame, mask.mean())


def test_pick_references_prefers_old_enough_keyframes_in_overlap_order() -> None:
    stamps = [9.9, 9.8, 9.0, 9.7, 8.5, 8.0]  # best overlap first; now = 10.0
    assert pick_references(stamps, 10.0, 3, 0.7) == [2, 4, 5]
    assert pick_references(stamps, 10.0, 5, 0.7) == [2, 4, 5, 0, 1]  # too few old ones: young fill in
    assert pick_references(stamps, 10.0, 3, 0.0) == [0, 1, 2]  # DDL-SLAM as written: overlap only
    assert pick_references([], 10.0, 3, 0.7) == []


@pytest.mark.slow
def test_lifted_box_is_found_only_against_keyframes_old_enough() -> None:
    """walking_box frame 432: the box stood still on the floor for ~0.7 s, and is being lifted
    (~3 cm a frame, 15 % of the image). When keyframes come on consecutive frames (tracking
    weakens while a mover covers the view) the best-overlapping ones are 1-5 frames old: the
    box has moved too little since for the depth test, and the check sees nothing (measured:
    0 of the box); in SLAM, tracking then followed the lifted box (15.1 cm ATE on the full
    render). The keyframes the default preset picks, at least 0.7 s old, show it (measured:
    0.71 of the box, no static pixel)."""
    views = Views("walking_box", 433)
    frame, fps = 432, SEQUENCES["walking_box"].fps
    lags = (1, 2, 3, 4, 5, 22, 24, 26, 28, 30)  # candidates, best overlap first
    dyn = load_config("default").dynamics
    pick = pick_references([(frame - lag) / fps for lag in lags], frame / fps, dyn.multiview_keyframes,
                           dyn.multiview_min_age_s)
    assert [lags[i] for i in pick] == [22, 24, 26, 28, 30]
    depth, sem = views.depth(frame)
    box = sem == MOVER
    static = (sem >= 100) & ~dilate(box | (sem == PERSON), 4)
    T_cw = invert(views.r.poses[frame])
    young = multiview_mask(T_cw, depth, views.cam, [views.keyframe(frame - lag) for lag in lags[:5]], dyn).mask
    old = multiview_mask(T_cw, depth, views.cam, [views.keyframe(frame - lags[i]) for i in pick], dyn).mask
    assert box.mean() > 0.1
    assert (young & box).sum() < 0.1 * box.sum()
    assert (old & box).sum() > 0.5 * box.sum()
    assert (old & static).sum() < 0.02 * box.sum()
