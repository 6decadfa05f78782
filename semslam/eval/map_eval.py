"""``semslam eval-map RUN_OUT SEQ``: a run's maps against the sequence's true static geometry.

Reads what ``semslam run`` wrote (``trajectory.txt``, ``keyframes.txt``, ``map/*.ply``) and
what ``semslam synth`` wrote (``groundtruth.txt``, ``scene.json``, ``movers.json``, the depth
images), brings the map into the ground truth's frame with the run's ATE alignment (SE(3),
as evo aligns), and computes ``map_metrics`` on the octree and the semantic cloud.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from semslam.core.labels import NYU40_CLASSES, SYNTH_CLASSES, SYNTH_STATIC_OFFSET
from semslam.errors import DataError
from semslam.eval.map_metrics import (class_accuracy, observed_surface, octree_scores, point_accuracy,
                                      transform_points)
from semslam.eval.metrics import ate
from semslam.io.ply import read_vertex_ply, xyz_of
from semslam.io.trajectory import read_trajectory

#: Metres between true-surface samples for the octree's recall, as a share of its resolution.
SURFACE_SPACING = 0.5


@dataclass
class MapEval:
    """The numbers ``eval-map`` prints (and writes as JSON)."""

    run: str
    sequence: str
    tolerance_m: float
    ate_cm: float
    cloud_points: int = 0
    cloud_point_accuracy: float | None = None
    cloud_class_accuracy: dict[str, tuple[int, float]] = field(default_factory=dict)
    cloud_mpa: float | None = None
    cloud_ghost_points: int = 0
    cloud_ghost_share: float | None = None
    octree_resolution_m: float | None = None
    octree_occupied: int = 0
    octree_point_accuracy: float | None = None
    octree_precision: float | None = None
    octree_recall: float | None = None
    octree_ghost_voxels: int = 0
    octree_ghost_share: float | None = None
    octree_class_accuracy: dict[str, tuple[int, float]] = field(default_factory=dict)
    octree_mpa: float | None = None
    mesh_vertices: int = 0
    mesh_point_accuracy: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def true_class_names(ids: NDArray[np.int64]) -> NDArray[np.str_]:
    """Synthetic label ids (100 + NYU-40 id for static surfaces) as class names."""
    names = {**{SYNTH_STATIC_OFFSET + k: v for k, v in NYU40_CLASSES.items()}, **SYNTH_CLASSES}
    return np.array([names.get(int(i), "unknown") for i in ids])


def read_labelled_ply(path: Path) -> tuple[NDArray[np.float64], NDArray[np.int64] | None]:
    """x y z (and the ``label`` field where there is one) of a PLY's vertices."""
    v = read_vertex_ply(path)
    return xyz_of(v), (np.asarray(v["label"], np.int64) if "label" in v else None)


def read_class_table(path: Path) -> dict[int, str]:
    """``{index: name}`` from a map's classes JSON (``{"index": {"name": ..., ...}}`` or ``{"index": name}``)."""
    try:
        raw = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise DataError(path, f"cannot read the class table ({exc})") from None
    return {int(k): (v["name"] if isinstance(v, dict) else str(v)) for k, v in raw.items()}


def evaluate_map(run_dir: Path, seq_dir: Path, tolerance_m: float = 0.05) -> MapEval:
    from semslam.io.sequence import open_sequence
    from semslam.synth.static_geometry import load_movers, load_static_geometry

    for name in ("trajectory.txt", "keyframes.txt"):
        if not (run_dir / name).is_file():
            raise DataError(run_dir / name, "not found: give the output folder of a finished `semslam run`")
    gt_path = seq_dir / "groundtruth.txt"
    if not gt_path.is_file():
        raise DataError(gt_path, "not found: eval-map needs the sequence's ground truth")
    maps = run_dir / "map"
    if not any((maps / f).is_file() for f in ("semantic_cloud.ply", "octree_semantic.ply", "mesh.ply")):
        raise DataError(maps, "no semantic_cloud.ply, octree_semantic.ply or mesh.ply: run with --map "
                              "octree,cloud,mesh (or rebuild them with `semslam map`)")
    truth = _Truth(load_static_geometry(seq_dir), load_movers(seq_dir))
    gt = read_trajectory(gt_path)
    a = ate(gt, read_trajectory(run_dir / "trajectory.txt"), align="se3")
    to_truth = a.transform
    res = MapEval(str(run_dir), str(seq_dir), tolerance_m, 100 * a.rmse)
    table = _class_table(maps)

    cloud = maps / "semantic_cloud.ply"
    if cloud.is_file():
        xyz, labels = read_labelled_ply(cloud)
        xyz = transform_points(to_truth, xyz)
        dist, cls = truth.distance(xyz)
        res.cloud_points = len(xyz)
        res.cloud_point_accuracy = point_accuracy(dist, tolerance_m)
        ghosts = truth.in_any_mover(xyz) & (dist > tolerance_m)
        res.cloud_ghost_points, res.cloud_ghost_share = int(ghosts.sum()), float(np.mean(ghosts)) if len(xyz) else 0.0
        if labels is not None and table:
            near = dist <= tolerance_m  # class accuracy on points that lie on a surface
            ca = class_accuracy(true_class_names(cls[near]), _names(labels[near], table))
            res.cloud_class_accuracy, res.cloud_mpa = ca.per_class, ca.mpa

    octree = maps / "octree_semantic.ply"
    if octree.is_file():
        xyz, labels = read_labelled_ply(octree)
        xyz = transform_points(to_truth, xyz)
        resolution = _octree_resolution(run_dir)
        res.octree_resolution_m = resolution
        seq = open_sequence(seq_dir)
        kf = read_trajectory(run_dir / "keyframes.txt")
        views = _keyframe_views(seq, gt, kf.timestamps)
        samples, _ = truth.sample_surface(SURFACE_SPACING * resolution)
        observed = samples[observed_surface(samples, views, seq.camera, tolerance_m, 4.0)]
        scores = octree_scores(xyz, truth, resolution, observed)
        res.octree_occupied, res.octree_precision, res.octree_recall = scores.occupied, scores.precision, \
            scores.recall
        res.octree_ghost_voxels, res.octree_ghost_share = scores.ghost_voxels, scores.ghost_share
        dist, cls = truth.distance(xyz)
        res.octree_point_accuracy = point_accuracy(dist, tolerance_m)
        if labels is not None and table:
            near = dist <= resolution
            ca = class_accuracy(true_class_names(cls[near]), _names(labels[near], table))
            res.octree_class_accuracy, res.octree_mpa = ca.per_class, ca.mpa

    mesh = maps / "mesh.ply"
    if mesh.is_file():
        xyz, _ = read_labelled_ply(mesh)
        dist, _ = truth.distance(transform_points(to_truth, xyz))
        res.mesh_vertices = len(xyz)
        res.mesh_point_accuracy = point_accuracy(dist, tolerance_m)
    return res


class _Truth:
    """The scene's static surfaces and its movers' volumes behind ``map_metrics.SceneTruth``."""

    def __init__(self, geometry: Any, movers: Any) -> None:
        self.geometry, self.movers = geometry, movers

    def distance(self, points: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
        return self.geometry.distance(points)

    def sample_surface(self, spacing_m: float) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
        return self.geometry.sample_surface(spacing_m)

    def in_any_mover(self, points: NDArray[np.float64]) -> NDArray[np.bool_]:
        return self.movers.in_any_mover(points)


def _names(labels: NDArray[np.int64], table: dict[int, str]) -> NDArray[np.str_]:
    return np.array([table.get(int(i), "unknown") for i in labels])


def _class_table(maps: Path) -> dict[int, str]:
    for name in ("map_classes.json", "octree_classes.json", "semantic_cloud_classes.json"):
        if (maps / name).is_file():
            return read_class_table(maps / name)
    return {}


def _octree_resolution(run_dir: Path) -> float:
    try:
        return float(json.loads((run_dir / "config.json").read_text())["maps"]["octree_resolution_m"])
    except (OSError, KeyError, ValueError, json.JSONDecodeError):
        return 0.05


def _keyframe_views(seq: Any, gt: Any, stamps: NDArray[np.float64]) -> list[tuple[NDArray[np.float64], Any]]:
    """(ground-truth T_wc, depth image) of the frames nearest the keyframes' timestamps."""
    views = []
    for t in stamps:
        i = int(np.argmin(np.abs(seq.timestamps - t)))
        j = int(np.argmin(np.abs(gt.timestamps - t)))
        frame = next(seq.frames(i, i + 1))
        if frame.depth is not None:
            views.append((gt.poses[j], frame.depth))
    return views
