"""Frame builders (``slam/orb/frame_builders.py``): RGB-D frames carry each keypoint's depth and
virtual right coordinate; monocular frames carry none."""

from __future__ import annotations

import numpy as np

from semslam.config import load_config
from semslam.core.types import Keypoints
from semslam.geometry.camera import PinholeCamera
from semslam.slam.orb.frame_builders import MonocularFrameBuilder, RgbdFrameBuilder, frame_builder
from semslam.frontend.keypoint_depth import sample_depth

CAM = PinholeCamera(fx=535.4, fy=539.2, cx=320.1, cy=247.6, width=640, height=480)
BF = 40.0


def _keypoints(n: int = 40) -> Keypoints:
    rng = np.random.default_rng(3)
    return Keypoints(xy=rng.uniform([5, 5], [635, 475], (n, 2)).astype(np.float32), octave=np.zeros(n, np.int32),
                     response=np.ones(n, np.float32), angle=np.zeros(n, np.float32),
                     descriptors=np.zeros((n, 32), np.uint8))


def test_rgbd_frame_reads_depth_and_the_virtual_right_coordinate() -> None:
    kps = _keypoints()
    depth = np.random.default_rng(4).uniform(0.5, 4.0, (480, 640)).astype(np.float32)
    depth[:, :100] = 0.0  # no depth on the left
    f = RgbdFrameBuilder(CAM, BF).build(7, 1.5, kps, depth)
    z = sample_depth(depth, kps.xy).astype(np.float32)
    xy = CAM.undistort_points(kps.xy)
    assert (f.index, f.timestamp, len(f)) == (7, 1.5, len(kps))
    np.testing.assert_array_equal(f.xy, xy)
    np.testing.assert_array_equal(f.depth, z)
    np.testing.assert_array_equal(f.ur, np.where(z > 0, xy[:, 0] - BF / np.maximum(z, 1e-6), -1.0))
    assert (f.depth == 0).any() and (f.ur[f.depth == 0] == -1.0).all()
    assert all(p is None for p in f.points) and not f.outlier.any() and f.T_cw is None


def test_rgbd_frame_without_a_depth_image_has_no_depth() -> None:
    f = RgbdFrameBuilder(CAM, BF).build(0, 0.0, _keypoints(), None)
    assert (f.depth == 0).all() and (f.ur == -1.0).all()


def test_monocular_frame_has_no_depth_and_no_right_coordinate() -> None:
    kps = _keypoints()
    f = MonocularFrameBuilder(CAM).build(3, 0.1, kps, None)
    assert len(f) == len(kps) and f.depth.dtype == np.float32
    assert (f.depth <= 0).all() and (f.ur == -1.0).all()
    np.testing.assert_array_equal(f.xy, CAM.undistort_points(kps.xy))
    assert all(p is None for p in f.points) and len(f.outlier) == len(kps)


def test_the_builder_follows_the_frames_depth() -> None:
    assert isinstance(frame_builder(load_config("orb"), CAM), RgbdFrameBuilder)
    assert isinstance(frame_builder(load_config("sdf_rgbd"), CAM), RgbdFrameBuilder)  # a depth network's
    assert isinstance(frame_builder(load_config("orb", ["sensor=mono", "depth.source=sensor"]), CAM),
                      MonocularFrameBuilder)
