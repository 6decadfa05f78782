"""The FP dataset (SDF-SLAM III-B): eqs. 5-7 transfer points exactly (analytic plane and
rotation cases, and through a TUM-layout folder read from disk); blurred pairs are
deterministic."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from semslam.errors import DataError
from semslam.eval.feature_eval import transfer_points
from semslam.geometry.se3 import make_pose, so3_exp
from semslam.nets.fp_dataset import FPSequence, harris_corners, motion_blur_kernel
from tests.fpf_plane import CAM, write_plane_sequence


def test_translation_over_a_plane_shifts_pixels_by_f_t_over_z():
    xy1 = np.array([[10.0, 20.0], [320.0, 240.0], [600.5, 470.25]])
    z = np.full(3, 2.0)
    T_wc2 = make_pose(np.eye(3), [0.1, -0.05, 0.0])  # camera 2 moved 10 cm right, 5 cm up
    xy2, z2 = transfer_points(xy1, z, CAM, np.eye(4), T_wc2)
    np.testing.assert_allclose(xy2, xy1 - [CAM.fx * 0.1 / 2.0, -CAM.fy * 0.05 / 2.0], atol=1e-9)
    np.testing.assert_allclose(z2, 2.0)


def test_pure_rotation_is_the_infinite_homography_whatever_the_depth():
    R = so3_exp([0.02, -0.05, 0.01])
    T_wc1 = make_pose(so3_exp([0.1, 0.2, -0.3]), [1.0, 2.0, 0.5])  # arbitrary first pose
    T_wc2 = T_wc1 @ make_pose(R, [0.0, 0.0, 0.0])
    xy1 = np.random.default_rng(0).uniform([0, 0], [640, 480], (50, 2))
    z = np.random.default_rng(1).uniform(0.5, 5.0, 50)
    xy2, _ = transfer_points(xy1, z, CAM, T_wc1, T_wc2)
    h = CAM.K @ R.T @ np.linalg.inv(CAM.K)  # x2 ~ K R^T K^-1 x1 (camera 2 = camera 1 rotated by R)
    ph = np.c_[xy1, np.ones(50)] @ h.T
    np.testing.assert_allclose(xy2, ph[:, :2] / ph[:, 2:], atol=1e-9)


def test_pairs_from_a_tum_folder_transfer_corners_exactly(tmp_path: Path):
    write_plane_sequence(tmp_path / "plane", [0.0, 0.08, 0.2])
    seq = FPSequence(tmp_path / "plane")
    assert len(seq) == 3 and seq.pair_indices(gap=1) == [(0, 1), (1, 2)]
    pair = seq.pair(0, 1)
    assert len(pair.xy1) > 50 and pair.valid.sum() > 0.8 * len(pair.xy1)
    shift = CAM.fx * 0.08 / 2.0  # 21.4 px to the left
    np.testing.assert_allclose(pair.xy2, pair.xy1 - [shift, 0.0], atol=1e-6)
    assert (pair.xy2[pair.valid, 0] >= 0).all() and not pair.valid[pair.xy2[:, 0] < 0].any()
    # The transferred corners are corners of frame 2 (the board moved with the pose).
    corners2 = harris_corners(pair.gray2)
    d = np.linalg.norm(pair.xy2[pair.valid][:, None] - corners2[None], axis=2).min(axis=1)
    assert np.median(d) <= 1.0
    a, b = seq.pair(0, 2, blurred=True, seed=3), seq.pair(0, 2, blurred=True, seed=3)
    assert np.array_equal(a.gray2, b.gray2) and not np.array_equal(a.gray2, seq.pair(0, 2).gray2)


def test_motion_blur_kernel_is_a_normalised_line():
    k = motion_blur_kernel(9, 0.0)
    assert k.shape == (9, 9) and k.sum() == pytest.approx(1.0) and (k[4] > 0).sum() == 9 and k[:4].sum() == 0


def test_folder_without_ground_truth_is_refused(tmp_path: Path):
    write_plane_sequence(tmp_path / "p", [0.0, 0.1])
    (tmp_path / "p" / "groundtruth.txt").unlink()
    with pytest.raises(DataError, match="groundtruth.txt"):
        FPSequence(tmp_path / "p")
