"""SDF-SLAM's 3D semantic point cloud (IV-C): every keyframe's static points in the world frame
with their colour and class, voxel-downsampled.

Each keyframe's usable pixels (``backproject``) are sampled about one voxel apart at its
median depth and kept in camera coordinates with the pose last told (``correct_poses``), so
loop closing and bundle adjustment move them; ``finish`` places them with the final poses and
merges every voxel of ``cfg.cloud_voxel_m`` into one point: mean position, mean colour,
majority class by count ("unknown" wins only a voxel without any class vote).

``semantic_cloud.ply`` (binary): float x y z, uchar red green blue = the observed colour (what
Open3D and MeshLab show), int ``label`` = global class index (``classes.py``), uchar
``class_red class_green class_blue`` = the class colour and int ``count`` = samples merged
(CloudCompare lists these as scalar fields; ``semslam.io.ply.read_vertex_ply`` reads all), and
``semantic_cloud_classes.json``, the legend (``{"index": {"name", "colour", "points"}}``).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from semslam.config import MapsConfig
from semslam.core.protocols import KeyframeSnapshot
from semslam.io.ply import write_vertex_ply
from semslam.reconstruction import voxels
from semslam.reconstruction.backproject import StaticPoints, static_points, stride_for_voxel
from semslam.core.map_classes import CLASS_COLOURS, UNKNOWN, possible_classes, write_classes_json


@dataclass
class LabelledCloud:
    """Voxel-merged points: positions (N, 3), colours (N, 3) uint8, global class (N,), samples
    merged per point (N,)."""

    xyz: NDArray[np.float64]
    rgb: NDArray[np.uint8]
    labels: NDArray[np.int64]
    counts: NDArray[np.int64]


class SemanticCloud:
    """``MapBuilder``: the keyframes' static points with colour and class, one per voxel."""

    def __init__(self, cfg: MapsConfig | None = None, stride: int | None = None) -> None:
        cfg = cfg or MapsConfig()
        if cfg.cloud_voxel_m <= 0:
            raise ValueError(f"maps.cloud_voxel_m must be > 0, got {cfg.cloud_voxel_m}")
        self.voxel_m = float(cfg.cloud_voxel_m)
        self.max_depth_m = float(cfg.max_depth_m)
        self.stride = stride  # None: about one voxel per sample at each keyframe's median depth
        self._points: dict[int, StaticPoints] = {}
        self._poses: dict[int, NDArray[np.float64]] = {}
        self._lock = threading.Lock()
        self._possible = possible_classes(None)  # what the keyframes' segmenters could label

    def add_keyframe(self, snapshot: KeyframeSnapshot) -> None:
        stride = self.stride or stride_for_voxel(snapshot, self.voxel_m, self.max_depth_m)
        sp = static_points(snapshot, stride, self.max_depth_m)
        if snapshot.labels is not None:
            self._possible |= possible_classes(snapshot.labels.names)
        with self._lock:
            self._points[snapshot.keyframe_id] = sp
            self._poses[snapshot.keyframe_id] = np.array(snapshot.T_wc, np.float64)

    def correct_poses(self, poses_wc: dict[int, NDArray[np.float64]]) -> None:
        with self._lock:
            for kf_id, T in poses_wc.items():
                if kf_id in self._poses:
                    self._poses[kf_id] = np.array(T, np.float64)

    def cloud(self) -> LabelledCloud:
        """The merged cloud with the poses last told."""
        with self._lock:
            parts = [(sp, self._poses[kf_id]) for kf_id, sp in self._points.items() if len(sp)]
        if not parts:
            return LabelledCloud(np.zeros((0, 3)), np.zeros((0, 3), np.uint8), np.zeros(0, np.int64),
                                 np.zeros(0, np.int64))
        xyz = np.concatenate([sp.in_world(T) for sp, T in parts])
        rgb = np.concatenate([sp.rgb for sp, _ in parts])
        classes = np.concatenate([sp.class_ids for sp, _ in parts])
        return merge_voxels(xyz, rgb, classes, self.voxel_m)

    def finish(self, out_dir: Path) -> dict[str, Path]:
        c = self.cloud()
        path = out_dir / "semantic_cloud.ply"
        cc = CLASS_COLOURS[c.labels]
        write_vertex_ply(path, {"x": c.xyz[:, 0].astype(np.float32), "y": c.xyz[:, 1].astype(np.float32),
                                "z": c.xyz[:, 2].astype(np.float32), "red": c.rgb[:, 0], "green": c.rgb[:, 1],
                                "blue": c.rgb[:, 2], "label": c.labels.astype(np.int32),
                                "class_red": cc[:, 0], "class_green": cc[:, 1], "class_blue": cc[:, 2],
                                "count": c.counts.astype(np.int32)})
        legend = write_classes_json(out_dir / "semantic_cloud_classes.json", c.labels, "points",
                                    self._possible)
        return {"semantic_cloud": path, "semantic_cloud_classes": legend}

    def close(self) -> None:
        with self._lock:
            self._points.clear()
            self._poses.clear()


def merge_voxels(xyz: NDArray[np.float64], rgb: NDArray[np.uint8], classes: NDArray[np.integer],
                 voxel_m: float) -> LabelledCloud:
    """One point per occupied voxel: mean position, mean colour, majority class by count."""
    keys = voxels.pack(voxels.voxel_coords(xyz, voxel_m))
    uniq, inv, counts = np.unique(keys, return_inverse=True, return_counts=True)
    n = len(uniq)
    mean_xyz = np.stack([np.bincount(inv, weights=xyz[:, k], minlength=n) for k in range(3)], axis=1) / counts[:, None]
    mean_rgb = np.stack([np.bincount(inv, weights=rgb[:, k].astype(np.float64), minlength=n) for k in range(3)],
                        axis=1) / counts[:, None]
    vote_keys, labels = voxels.majority(keys, classes, None, unknown=UNKNOWN)
    assert np.array_equal(vote_keys, uniq)  # both sorted distinct keys of the same samples
    return LabelledCloud(mean_xyz, np.round(mean_rgb).astype(np.uint8), labels, counts.astype(np.int64))
