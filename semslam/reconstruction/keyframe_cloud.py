"""The simplest dense map: every keyframe's depth back-projected with its final pose into one
coloured point cloud (PLY, opened by Open3D, CloudCompare, MeshLab), leaving out the pixels
the dynamic stage marked as moving so people leave no ghosts.

It keeps each keyframe's points in camera coordinates and places them with the pose it was
last told about, so loop closing and bundle adjustment move the cloud with the keyframes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from semslam.config import MapsConfig
from semslam.core.protocols import KeyframeSnapshot


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
        s = self.stride
        depth = snapshot.depth[::s, ::s]
        keep = (depth > 0) & (depth < self.max_depth_m) & np.isfinite(depth)
        if snapshot.dynamic is not None:
            keep &= ~snapshot.dynamic[::s, ::s]
        v, u = np.nonzero(keep)
        z = depth[v, u].astype(np.float64)
        cam = snapshot.camera
        xy = cam.undistort_points(np.stack([u * s, v * s], axis=1).astype(np.float64))
        pts_c = cam.backproject(xy, z).astype(np.float32)
        self._points[snapshot.keyframe_id] = (pts_c, snapshot.rgb[::s, ::s][v, u].copy())
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
    """Binary PLY with float x y z and uchar red green blue, through ``plyfile``."""
    from plyfile import PlyData, PlyElement

    rows = np.empty(len(xyz), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"),
                                     ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    rows["x"], rows["y"], rows["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    rows["red"], rows["green"], rows["blue"] = rgb[:, 0], rgb[:, 1], rgb[:, 2]
    PlyData([PlyElement.describe(rows, "vertex")]).write(str(path))
