"""The gravity tilt of an estimate's world (semslam/eval/gravity.py) on analytic cases: an
estimate in a world turned about the vertical has no tilt, one turned about a horizontal
axis by an angle has that tilt, whatever the path's shape; no matching stamps is one error."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from semslam.core.trajectory import Trajectory
from semslam.errors import EvalError
from semslam.eval.gravity import gravity_tilt_deg


def _turned(ref: Trajectory, R: np.ndarray, noise_deg: float, rng: np.random.Generator) -> Trajectory:
    """``ref`` seen from a world turned by ``R`` (x_est = R @ x_ref), orientations jittered."""
    poses = ref.poses.copy()
    jitter = Rotation.from_rotvec(np.radians(noise_deg) * rng.normal(size=(len(poses), 3))).as_matrix()
    poses[:, :3, :3] = R @ poses[:, :3, :3] @ jitter
    poses[:, :3, 3] = poses[:, :3, 3] @ R.T
    return Trajectory(ref.timestamps + 0.001, poses, "est")


@pytest.mark.parametrize("yaw_deg, tilt_deg", [(0.0, 0.0), (73.0, 0.0), (0.0, 3.0), (-140.0, 25.0)])
def test_tilt_of_a_turned_world(yaw_deg: float, tilt_deg: float) -> None:
    rng = np.random.default_rng(1)
    n = 50
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, :3, :3] = Rotation.from_rotvec(0.3 * rng.normal(size=(n, 3))).as_matrix()
    poses[:, 0, 3] = np.linspace(0, 1, n)  # a straight line: positions alone would not fix the turn
    ref = Trajectory(np.arange(n) / 30.0, poses, "ref")
    R = (Rotation.from_euler("z", yaw_deg, degrees=True) * Rotation.from_euler("x", tilt_deg, degrees=True)).as_matrix()
    assert gravity_tilt_deg(ref, _turned(ref, R, 0.5, rng)) == pytest.approx(tilt_deg, abs=0.2)


def test_no_matching_stamps_is_an_error() -> None:
    ref = Trajectory(np.arange(5.0), np.tile(np.eye(4), (5, 1, 1)), "ref")
    est = Trajectory(np.arange(5.0) + 100.0, np.tile(np.eye(4), (5, 1, 1)), "est.txt")
    with pytest.raises(EvalError, match="est.txt"):
        gravity_tilt_deg(ref, est)
