"""Map metrics on analytic cases: a floor plane z = 0 (class 102) with a mover's volume above it."""

from __future__ import annotations

import numpy as np

from semslam.eval.map_metrics import class_accuracy, observed_surface, octree_scores, point_accuracy
from semslam.geometry.camera import PinholeCamera


class Floor:
    """Truth: the plane z = 0 (class 102, 'floor'); a mover once stood in x, y in [0, 1], z < 1.8."""

    def distance(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.abs(points[:, 2]), np.full(len(points), 102)

    def sample_surface(self, spacing_m: float) -> tuple[np.ndarray, np.ndarray]:
        g = np.arange(-2, 2, spacing_m)
        x, y = np.meshgrid(g, g)
        pts = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
        return pts, np.full(len(pts), 102)

    def in_any_mover(self, points: np.ndarray) -> np.ndarray:
        return ((points[:, 0] >= 0) & (points[:, 0] <= 1) & (points[:, 1] >= 0) & (points[:, 1] <= 1)
                & (points[:, 2] <= 1.8))


def test_point_accuracy_counts_points_within_the_tolerance() -> None:
    assert point_accuracy(np.array([0.0, 0.04, 0.06, 0.2]), 0.05) == 0.5


def test_class_accuracy_is_per_true_class_and_mpa_their_mean() -> None:
    true = ["wall"] * 4 + ["floor"] * 2
    pred = ["wall", "wall", "wall", "unknown", "floor", "wall"]
    res = class_accuracy(true, pred)
    assert res.per_class == {"wall": (4, 0.75), "floor": (2, 0.5)}
    assert res.mpa == 0.625 and abs(res.overall - 4 / 6) < 1e-12


def test_octree_scores_find_ghost_voxels_and_surface_recall() -> None:
    truth, res = Floor(), 0.05
    surface, _ = truth.sample_surface(res)
    observed = surface[(np.abs(surface[:, 0]) < 1) & (np.abs(surface[:, 1]) < 1)]
    floor_vox = observed + [0, 0, res / 2]  # voxel centres half a voxel above the floor
    ghost = np.array([[0.5, 0.5, z] for z in np.arange(0.2, 1.7, res)])  # a person's column left in the map
    scores = octree_scores(np.vstack([floor_vox, ghost]), truth, res, observed)
    assert scores.ghost_voxels == len(ghost)
    assert abs(scores.ghost_share - len(ghost) / (len(floor_vox) + len(ghost))) < 1e-12
    assert abs(scores.precision - len(floor_vox) / (len(floor_vox) + len(ghost))) < 1e-12
    assert scores.recall == 1.0
    half = octree_scores(floor_vox[floor_vox[:, 0] < 0], truth, res, observed)
    assert 0.45 < half.recall < 0.56 and half.ghost_voxels == 0


def test_observed_surface_keeps_what_a_view_saw_and_not_what_was_hidden() -> None:
    cam = PinholeCamera(100.0, 100.0, 49.5, 39.5, width=100, height=80)
    T_wc = np.eye(4)
    T_wc[:3, :3] = np.diag([1.0, -1.0, -1.0])  # looking down -z from 2 m
    T_wc[:3, 3] = [0, 0, 2.0]
    depth = np.full((80, 100), 2.0, np.float32)
    depth[:, :50] = 1.0  # something stands in front of the left half of the floor
    pts, _ = Floor().sample_surface(0.05)
    seen = observed_surface(pts, [(T_wc, depth)], cam, 0.05, 4.0)
    assert seen.any()
    assert (pts[seen, 0] >= -0.02).all()  # only the right half (x >= 0 in the image's right half)
    assert (np.abs(pts[seen, 0]) <= 1.0 + 0.05).all() and (np.abs(pts[seen, 1]) <= 0.8 + 0.05).all()
