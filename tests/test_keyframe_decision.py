"""Tracking's keyframe decision (ORB-SLAM2 NeedNewKeyFrame, RGB-D) and its one deviation:
with tracking weak, a keyframe is taken while local mapping has a backlog of up to
``slam.max_queued_keyframes_when_weak`` (ORB-SLAM2: 3), so that fast turns keep points. With
an IMU, ORB-SLAM3's temporal condition too: a keyframe once ``imu.keyframe_every_s`` passed."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from semslam.config.schema import SlamConfig
from semslam.slam.orb.tracking import Tracking


def _tracker(inliers: int, queued: int, every_s: float = 0.0, ref_points: int = 200,
             **cfg: object) -> tuple[SimpleNamespace, SimpleNamespace]:
    """A tracker 40 frames (1.33 s at 30 Hz) after its last keyframe, local mapping busy with
    ``queued`` keyframes, the reference keyframe tracking ``ref_points`` points, the frame
    ``inliers`` of them; ``every_s``: the IMU's temporal condition (0: no IMU)."""
    slam = SlamConfig(**cfg)  # type: ignore[arg-type]
    n = 300
    tracker = SimpleNamespace(
        cfg=slam, map=SimpleNamespace(keyframes=dict.fromkeys(range(50))), last_reloc_frame=-1000,
        ref_kf=SimpleNamespace(tracked_points=lambda min_obs: ref_points),
        keyframes=SimpleNamespace(idle=lambda: False, queue_size=lambda: queued),
        th_depth_m=3.0, n_matches_inliers=inliers, last_kf_frame=60, last_kf_time=2.0,
        keyframe_every_s=every_s)
    rows = np.full(n, -1)
    rows[:inliers] = np.arange(inliers)
    # Far points only: the close-point rule (bNeedToInsertClose) stays out of the way.
    cur = SimpleNamespace(index=100, timestamp=2.0 + 40 / 30, depth=np.full(n, 5.0), points=SimpleNamespace(rows=rows),
                          outlier=np.zeros(n, bool))
    return tracker, cur


def _need(inliers: int, queued: int, every_s: float = 0.0, ref_points: int = 200, **cfg: object) -> bool:
    tracker, cur = _tracker(inliers, queued, every_s, ref_points, **cfg)
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


def test_a_reference_keyframe_no_other_keyframe_sees_stops_orb_slam2s_keyframes() -> None:
    """A keyframe whose points no other keyframe observes (a new view after a turn): its
    tracked-point count is 0, c2 never holds, and without an IMU no keyframe ever comes."""
    assert not _need(40, 0, ref_points=0)
    assert not _need(5, 0, ref_points=0)


@pytest.mark.parametrize("inliers", [0, 40, 190])
def test_with_an_imu_a_keyframe_comes_once_its_interval_passed(inliers: int) -> None:
    """ORB-SLAM3's c3: 1.33 s since the last keyframe >= 0.5 s, whatever the matches (none:
    a frame the IMU posed alone) and the reference's count; not before the interval."""
    assert _need(inliers, 0, every_s=0.5, ref_points=0)
    assert _need(inliers, 0, every_s=0.5)
    assert not _need(inliers, 0, every_s=2.0, ref_points=0)
    assert _need(inliers, 2, every_s=0.5)  # local mapping busy, but its queue short (ORB-SLAM3: < 3)
    assert not _need(190, 5, every_s=0.5)  # tracking not weak and a long queue: it waits
