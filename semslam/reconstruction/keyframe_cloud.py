"""The simplest dense map: every keyframe's depth back-projected with its final pose into one
coloured point cloud (PLY, opened by Open3D, CloudCompare, MeshLab), leaving out the pixels
the dynamic stage marked as moving so people leave no ghosts (``backproject.static_points``).

It keeps each keyframe's points in camera coordinates and places them with the pose it was
last told about, so loop closing and bundle adjustment move the cloud with the keyframes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from semslam.config import MapsConfig
from semslam.core.protocols import KeyframeSnapshot
from semslam.io.ply import write_vertex_ply
from semslam.reconstruction.backproject import static_points


class KeyframeCloud:
    """``MapBuilder``: a coloured cloud of the keyframes' static depth, subsampled on a grid."""

    def __init__(self, cfg: MapsConfig | None = None, stride: int = 4) -> None:
        self.stride = stride
        self.max_depth_m = (cfg or MapsConfig()).max_depth_m
        self._points: dict[int, tuple[NDArray[np.float32], NDArray[np.uint8]]] = {}
        self._poses: dict[int, NDArray[np.float64]] = {}

    def add_keyframe(self, snapshot: KeyframeSnapshot) -> None:
        if snapshot.depth is None:
            return
        sp = static_points(snapshot, self.stride, self.max_depth_m)
        self._points[snapshot.keyframe_id] = (sp.points_c, sp.rgb)
        self._poses[snapshot.keyframe_id] = snapshot.T_wc.copy()

    def correct_poses(self, poses_wc: dict[int, NDArray[np.float64]]) -> None:
        for kf_id, T in poses_wc.items():
            if kf_id in self._poses:
                self._poses[kf_id] = np.asarray(T, np.float64).copy()

    def cloud(self) -> tuple[NDArray[np.float64], NDArray[np.uint8]]:
        """World points (N, 3) and their RGB colours (N, 3)."""
        if not self._points:
            return np.zeros((0, 3)), np.zeros((0, 3), np.uint8)
        xyz, rgb = [], []
        for kf_id, (pts_c, colours) in self._points.items():
            T = self._poses[kf_id]
            xyz.append(pts_c @ T[:3, :3].T + T[:3, 3])
            rgb.append(colours)
        return np.concatenate(xyz), np.concatenate(rgb)

    def finish(self, out_dir: Path) -> dict[str, Path]:
        xyz, rgb = self.cloud()
        out_dir.mkdir(parents=True, exist_ok=True)
        path = out_dir / "keyframe_cloud.ply"
        write_ply(path, xyz, rgb)
        return {"keyframe_cloud": path}

    def close(self) -> None:
        self._points.clear()


def write_ply(path: Path, xyz: NDArray[np.float64], rgb: NDArray[np.uint8]) -> None:
    """Binary PLY with float x y z and uchar red green blue."""
    write_vertex_ply(path, {"x": xyz[:, 0].astype(np.float32), "y": xyz[:, 1].astype(np.float32),
                            "z": xyz[:, 2].astype(np.float32), "red": rgb[:, 0], "green": rgb[:, 1],
                            "blue": rgb[:, 2]})
