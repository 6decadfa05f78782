"""The tracker on real Kinect v1 frames (slambook2's 5 frames, depth in mm, poses given).

These are wide-baseline views (0.2-2 m apart), not a video: the tracker runs its
unguided path (brute-force matching, PnP-RANSAC, guided re-match, >= 50 inliers unless the
identity prediction already gives a good guided match). Frames 3-5 see the same part of the
room (baselines 0.23-0.96 m). Bound: Kinect depth noise is 2-6 cm per point at the 3-6 m
these points lie at (sigma ~ 1.2 mm + 1.9 mm (z - 0.4)^2), there is no bundle adjustment,
so relative poses within 10 cm and 2 deg are what a correct two-view PnP gives here.

Each of the six pairs among frames 3-5 has its outcome asserted (PAIRS). Two are known to
fail and must be *reported* lost, not tracked to a wrong pose: with frame 3 as the keyframe
and frame 4 or 5 (0.73 / 0.96 m away, 7 / 5.5 deg turned) to track, brute-force matching
gives 79 / 74 matches of which none survive PnP-RANSAC and the depth check (measured), so
the unguided path cannot start; the reverse pairs (4->3, 5->3) track to 2 cm.
Pairs with frame 1 or 2 (25 deg turn, 1.1-2.1 m) are not asserted: measured, the
unguided path either loses them or, for 4->2 and 5->2, accepts a pose 0.2-0.3 m off.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from semslam.config import load_config
from semslam.geometry.camera import PinholeCamera
from semslam.geometry.se3 import invert, pose_from_tum, rotation_angle
from semslam.io.images import read_depth, read_rgb
from semslam.core.protocols import FramePacket
from semslam.core.types import Frame
from semslam.slam.trackers.frame_to_keyframe import FrameToKeyframeTracker
from semslam.core.types import TrackingState

CAMERA = PinholeCamera(518.0, 519.0, 325.5, 253.5)  # from the data's README
# Wide-baseline settings: more features and looser matching than frame-to-frame video.
WIDE_BASELINE = ["features.n_features=2000", "frame_to_keyframe.max_hamming=80", "frame_to_keyframe.ratio=0.85"]


@pytest.fixture(scope="module")
def kinect(shared_data: Path) -> tuple[list[Frame], np.ndarray]:
    root = shared_data / "kinect_rgbd_5frames"
    frames = [Frame(i, float(i), read_rgb(root / f"color/{i + 1}.png"), read_depth(root / f"depth/{i + 1}.pgm", 1000.0))
              for i in range(5)]
    return frames, pose_from_tum(np.loadtxt(root / "pose.txt"))


#: (keyframe, frame) 1-based -> expected state; measured errors of the tracked pairs:
#: 4->3 1.8 cm 0.27 deg, 4->5 1.6 cm 0.43 deg, 5->3 2.0 cm 0.40 deg, 5->4 8.0 cm 1.48 deg.
PAIRS = {
    (3, 4): TrackingState.LOST,  # no usable unguided matches (see above)
    (3, 5): TrackingState.LOST,  # same
    (4, 3): TrackingState.OK,
    (4, 5): TrackingState.OK,
    (5, 3): TrackingState.OK,
    (5, 4): TrackingState.OK,
}


@pytest.mark.parametrize("pair", list(PAIRS), ids=[f"{a}->{b}" for a, b in PAIRS])
def test_relative_pose_on_real_kinect_pair(kinect: tuple[list[Frame], np.ndarray], pair: tuple[int, int]) -> None:
    frames, gt = kinect
    i, j = pair[0] - 1, pair[1] - 1
    tracker = FrameToKeyframeTracker(load_config("f2kf", WIDE_BASELINE), CAMERA)
    assert tracker.track(FramePacket(frames[i])).state is TrackingState.OK  # the first frame is the keyframe
    res = tracker.track(FramePacket(frames[j]))
    assert res.state is PAIRS[pair], f"{pair}: {res.state.value}, {res.n_inliers} inliers"
    if res.state is not TrackingState.OK:
        assert not res.is_keyframe  # a lost frame must not become a keyframe either
        return
    err = invert(invert(gt[i]) @ gt[j]) @ res.pose_wc
    t_err, r_err = float(np.linalg.norm(err[:3, 3])), float(np.degrees(rotation_angle(err[:3, :3])))
    assert t_err < 0.10 and r_err < 2.0, f"{pair}: {t_err * 100:.1f} cm {r_err:.2f} deg"
    assert res.n_inliers >= 20  # min_inliers; measured 28-140


def test_depth_is_read_in_metres(kinect: tuple[list[Frame], np.ndarray]) -> None:
    frames, _ = kinect
    depth = frames[0].depth
    assert depth is not None
    valid = depth[depth > 0]
    assert 0.3 < np.median(valid) < 8.0  # an indoor room, in metres
