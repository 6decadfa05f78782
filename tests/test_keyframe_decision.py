"""Tracking's keyframe decision (ORB-SLAM2 NeedNewKeyFrame, RGB-D) and its one deviation:
with tracking weak, a keyframe is taken while local mapping has a backlog of up to
``slam.max_queued_keyframes_when_weak`` (ORB-SLAM2: 3), so that fast turns keep points."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from semslam.config.schema import SlamConfig
from semslam.slam.orb.tracking import Tracking


def _tracker(inliers: int, queued: int, **cfg: object) -> tuple[SimpleNamespace, SimpleNamespace]:
    """A tracker 40 frames after its last keyframe, local mapping busy with ``queued``
    keyframes, the reference keyframe tracking 200 points, the frame ``inliers`` of them."""
    slam = SlamConfig(**cfg)  # type: ignore[arg-type]
    n = 300
    tracker = SimpleNamespace(
        cfg=slam, map=SimpleNamespace(keyframes=dict.fromkeys(range(50))), last_reloc_frame=-1000,
        ref_kf=SimpleNamespace(tracked_points=lambda min_obs: 200),
        keyframes=SimpleNamespace(idle=lambda: False, queue_size=lambda: queued),
        th_depth_m=3.0, n_matches_inliers=inliers, last_kf_frame=60)
    rows = np.full(n, -1)
    rows[:inliers] = np.arange(inliers)
    # Far points only: the close-point rule (bNeedToInsertClose) stays out of the way.
    cur = SimpleNamespace(index=100, depth=np.full(n, 5.0), points=SimpleNamespace(rows=rows),
                          outlier=np.zeros(n, bool))
    return tracker, cur


def _need(inliers: int, queued: int, **cfg: object) -> bool:
    tracker, cur = _tracker(inliers, queued, **cfg)
    return Tracking._need_new_keyframe(tracker, cur)  # type: ignore[arg-type]


@pytest.mark.parametrize("queued", [0, 2])
def test_a_short_queue_takes_the_keyframe_as_orb_slam2(queued: int) -> None:
    assert _need(40, queued)  # 40 < 0.25 * 200: weak, and 40 frames since the last keyframe
    assert _need(140, queued)  # 140 < 0.75 * 200 after max_frames (c1a and c2)


def test_weak_tracking_takes_a_keyframe_past_orb_slam2s_queue_of_three() -> None:
    assert _need(40, 5)
    assert not _need(40, 5, max_queued_keyframes_when_weak=3)  # ORB-SLAM2
    assert not _need(40, 12)  # the bound holds


def test_tracking_that_is_not_weak_waits_for_local_mapping() -> None:
    assert not _need(140, 5)  # c1a and c2 hold, but not weak: ORB-SLAM2's queue of 3 applies
    assert not _need(10, 0)  # too few inliers for any keyframe (c2: > 15)
