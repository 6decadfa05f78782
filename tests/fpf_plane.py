"""A TUM-layout folder the tests of issue 12's keypoint pieces share: a checkerboard on
the plane Z = z seen by a camera moving sideways, so every correspondence is known
analytically (x2 = x1 - fx * shift / z)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from semslam.geometry.camera import PinholeCamera
from semslam.geometry.se3 import make_pose, pose_to_tum

CAM = PinholeCamera(535.4, 539.2, 320.1, 247.6, width=640, height=480)


def write_plane_sequence(root: Path, shifts: list[float], z: float = 2.0) -> None:
    """A TUM folder: a checkerboard on the plane Z = z, the camera moving sideways."""
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    rgb_lines, depth_lines, gt_lines = [], [], []
    for k, shift in enumerate(shifts):
        t = 1000.0 + 0.1 * k
        xs = np.arange(640)
        # The board is fixed in the world: world X of pixel u is (u - cx) z / fx + shift.
        wx = (xs - CAM.cx) * z / CAM.fx + shift
        wy = (np.arange(480) - CAM.cy) * z / CAM.fy
        board = ((np.floor(wx / 0.1)[None, :] + np.floor(wy / 0.1)[:, None]) % 2 * 200 + 30).astype(np.uint8)
        cv2.imwrite(str(root / f"rgb/{t:.6f}.png"), np.dstack([board] * 3))
        cv2.imwrite(str(root / f"depth/{t:.6f}.png"), np.full((480, 640), int(z * 5000), np.uint16))
        rgb_lines.append(f"{t:.6f} rgb/{t:.6f}.png")
        depth_lines.append(f"{t:.6f} depth/{t:.6f}.png")
        gt_lines.append(f"{t:.6f} " + " ".join(f"{v:.9f}" for v in pose_to_tum(make_pose(np.eye(3), [shift, 0, 0]))))
    (root / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (root / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    (root / "groundtruth.txt").write_text("# timestamp tx ty tz qx qy qz qw\n" + "\n".join(gt_lines) + "\n")
    (root / "calib.txt").write_text(f"{CAM.fx} {CAM.fy} {CAM.cx} {CAM.cy}\n")
