"""Optimisation back end (ORB-SLAM2 ``Optimizer`` as pure functions over arrays).

* :func:`optimize_pose` - motion-only BA for tracking (one numba call; references
  :func:`optimize_pose_numpy`, vectorised numpy, and :func:`optimize_pose_gtsam`);
* :func:`bundle_adjust` - local / global BA on GTSAM with ORB-SLAM's outlier handling;
* :func:`optimize_pose_graph` - SE(3) essential graph on GTSAM, and
  :func:`correct_points_with_poses` to carry map points along.

Poses are 4x4 numpy arrays; ``T_cw`` maps world to camera (ORB-SLAM's Tcw).
"""

from semslam.backend.bundle_adjustment import (
                                               BAProblem,
                                               BAResult,
                                               bundle_adjust,
                                               reprojection_errors,
)
from semslam.backend.pose_graph import correct_points_with_poses, optimize_pose_graph
from semslam.backend.pose_only import PoseResult, optimize_pose, optimize_pose_gtsam, optimize_pose_numpy

__all__ = [
    "BAProblem",
    "BAResult",
    "PoseResult",
    "bundle_adjust",
    "correct_points_with_poses",
    "optimize_pose",
    "optimize_pose_graph",
    "optimize_pose_gtsam",
    "optimize_pose_numpy",
    "reprojection_errors",
]
