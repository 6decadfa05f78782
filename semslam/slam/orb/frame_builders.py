"""What tracking needs of a sensor's frame, per sensor: keypoints (undistorted), a depth and
a right-image coordinate per keypoint where the sensor gives one, empty map-point slots."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from semslam.config import SystemConfig
from semslam.core.types import Keypoints
from semslam.geometry.camera import PinholeCamera
from semslam.slam.orb.frame_state import FrameState
from semslam.frontend.keypoint_depth import sample_depth
from semslam.slam.orb.map import PointSlots
from semslam.slam.orb.stereo_matching import compute_stereo_matches, stereo_pyramid


class FrameBuilder(Protocol):
    """Turns one frame's keypoints (and the depth image, where there is one) into a
    ``FrameState``."""

    camera: PinholeCamera

    def build(self, index: int, timestamp: float, kps: Keypoints,
              depth_img: NDArray[np.float32] | None) -> FrameState: ...


def _frame(index: int, timestamp: float, kps: Keypoints, xy: NDArray[np.float64], z: NDArray[np.float32],
           ur: NDArray[np.float64]) -> FrameState:
    n = len(kps)
    return FrameState(index, timestamp, kps, xy, z, ur, PointSlots([None] * n), np.zeros(n, bool))


class RgbdFrameBuilder:
    """Depth read at each keypoint; the right coordinate a stereo camera of baseline
    ``bf / fx`` would see (ORB-SLAM2's virtual right image), -1 without depth."""

    def __init__(self, camera: PinholeCamera, bf: float) -> None:
        self.camera = camera
        self.bf = bf

    def build(self, index: int, timestamp: float, kps: Keypoints,
              depth_img: NDArray[np.float32] | None) -> FrameState:
        xy = self.camera.undistort_points(kps.xy)
        if depth_img is not None:
            z = sample_depth(depth_img, kps.xy).astype(np.float32)
        else:
            z = np.zeros(len(kps), np.float32)
        ur = np.where(z > 0, xy[:, 0] - self.bf / np.maximum(z, 1e-6), -1.0)
        return _frame(index, timestamp, kps, xy, z, ur)


class MonocularFrameBuilder:
    """No depth: every keypoint's depth is 0 and its right coordinate -1 (none). A depth
    network's image, where there is one, is read at the keypoints as ``prior_depth`` only."""

    def __init__(self, camera: PinholeCamera) -> None:
        self.camera = camera

    def build(self, index: int, timestamp: float, kps: Keypoints,
              depth_img: NDArray[np.float32] | None = None) -> FrameState:
        n = len(kps)
        frame = _frame(index, timestamp, kps, self.camera.undistort_points(kps.xy), np.zeros(n, np.float32),
                       np.full(n, -1.0))
        if depth_img is not None:
            frame.prior_depth = sample_depth(depth_img, kps.xy).astype(np.float32)
        return frame


@dataclass
class StereoViews:
    """What a stereo frame adds to its left keypoints: the right image's keypoints and both
    rectified images (grey, same size), whose pyramids the SAD refinement reads."""

    right_kps: Keypoints
    left_gray: NDArray[np.uint8]
    right_gray: NDArray[np.uint8]


class StereoFrameBuilder:
    """A rectified stereo pair: ORB-SLAM2's stereo matching (``stereo_matching``) gives each
    left keypoint a depth and its matched right coordinate ``ur``; unmatched ones keep depth 0
    and ``ur`` -1. The depth image is not read. ``right`` is the stereo part of the frame;
    without it every keypoint is unmatched. Close/far (ThDepth) stays tracking's job."""

    def __init__(self, camera: PinholeCamera, bf: float, scale_factor: float, n_levels: int) -> None:
        self.camera = camera
        self.bf = bf
        self.baseline = bf / camera.fx  # ORB-SLAM2's minZ: the nearest depth searched
        self.scale_factor = scale_factor
        self.n_levels = n_levels

    def build(self, index: int, timestamp: float, kps: Keypoints,
              depth_img: NDArray[np.float32] | None = None, right: StereoViews | None = None) -> FrameState:
        n = len(kps)
        # Rectified images: undistortion is the identity unless the camera says otherwise.
        xy = self.camera.undistort_points(kps.xy)
        if right is None:
            return _frame(index, timestamp, kps, xy, np.zeros(n, np.float32), np.full(n, -1.0))
        pyr_l = stereo_pyramid(right.left_gray, self.n_levels, self.scale_factor)
        pyr_r = stereo_pyramid(right.right_gray, self.n_levels, self.scale_factor)
        m = compute_stereo_matches(kps, right.right_kps, pyr_l, pyr_r, self.scale_factor, self.bf, self.baseline)
        return _frame(index, timestamp, kps, xy, m.depth, m.ur)


def is_monocular(config: SystemConfig) -> bool:
    """Monocular geometry: a monocular camera without a depth network, or with one whose depth
    is only a prior (``depth.use: prior``)."""
    return config.sensor == "mono" and (config.depth.source == "sensor" or config.depth.use == "prior")


def frame_builder(config: SystemConfig, camera: PinholeCamera) -> FrameBuilder:
    """The builder for the frames ``config`` gives: RGB-D whenever they come with depth, the
    sensor's or a depth network's (a monocular camera as pseudo-RGB-D)."""
    if is_monocular(config):
        return MonocularFrameBuilder(camera)
    return RgbdFrameBuilder(camera, config.slam.bf)
