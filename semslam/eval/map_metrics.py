"""Map metrics against a scene's true static geometry (SDF-SLAM Table 11, plus what a
static map needs: no ghosts of movers).

Everything here is pure: points and labels in, numbers out. The true geometry is anything
with the ``SceneTruth`` methods (``synth.static_geometry.StaticGeometry`` for semslam's
renders). Map points are in the SLAM map's frame; ``to_truth`` (the ATE alignment of the run's
trajectory to the ground truth, 4x4) brings them into the truth's frame first.

- **Point accuracy** (SDF-SLAM's "position accuracy"): the share of map points within a
  tolerance of the true surface (5 cm by default; SDF-SLAM does not state its tolerance).
- **Class accuracy (CA)** per class and **MPA** (SDF-SLAM eq. 16): for map points of true
  class i (the class of the nearest true surface), the share labelled i; MPA is their mean
  over the classes present. Points labelled "unknown" count as wrong.
- **Octree precision / recall**: an occupied voxel is right if its centre lies within one
  voxel of a true surface; recall is the share of the *observed* true surface (surface
  samples that some keyframe saw, see ``observed_surface``) within one voxel of an occupied
  voxel centre.
- **Ghost share**: occupied voxels inside the volume a mover (person, carried box) ever
  occupied and farther than one voxel from any static surface, over all occupied voxels.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from semslam.geometry.camera import PinholeCamera

Array = NDArray[np.float64]


class SceneTruth(Protocol):
    def distance(self, points: Array) -> tuple[Array, NDArray[np.int64]]:
        """Distance of each point to the nearest static surface, and that surface's class id."""
        ...

    def sample_surface(self, spacing_m: float) -> tuple[Array, NDArray[np.int64]]: ...

    def in_any_mover(self, points: Array) -> NDArray[np.bool_]: ...


def transform_points(T: Array, points: Array) -> Array:
    return points @ T[:3, :3].T + T[:3, 3]


@dataclass
class ClassAccuracy:
    """Per true class: map points, correctly labelled share; MPA over classes with points."""

    per_class: dict[str, tuple[int, float]] = field(default_factory=dict)
    mpa: float = 0.0
    overall: float = 0.0


def point_accuracy(dist: Array, tolerance_m: float) -> float:
    return float(np.mean(dist <= tolerance_m)) if len(dist) else 0.0


def class_accuracy(true_names: list[str] | NDArray[np.str_], pred_names: list[str] | NDArray[np.str_]
                   ) -> ClassAccuracy:
    """CA per true class and their mean (MPA, SDF-SLAM eq. 16: rows of the confusion matrix)."""
    t, p = np.asarray(true_names), np.asarray(pred_names)
    res = ClassAccuracy()
    if not len(t):
        return res
    for name in np.unique(t):
        sel = t == name
        res.per_class[str(name)] = (int(sel.sum()), float(np.mean(p[sel] == name)))
    res.mpa = float(np.mean([acc for _, acc in res.per_class.values()]))
    res.overall = float(np.mean(t == p))
    return res


def observed_surface(samples: Array, views: list[tuple[Array, NDArray[np.float32]]], camera: PinholeCamera,
                     tolerance_m: float, max_depth_m: float) -> NDArray[np.bool_]:
    """Which true surface samples some view saw: they project inside its image, in front of
    ``max_depth_m``, and its measured depth there agrees (within the tolerance plus 2 % of the
    depth, the sensor's noise) so they are not hidden. ``views`` are (T_wc ground truth, depth)."""
    seen = np.zeros(len(samples), bool)
    for T_wc, depth in views:
        T_cw = np.linalg.inv(T_wc)
        pc = transform_points(T_cw, samples)
        front = (pc[:, 2] > 0.1) & (pc[:, 2] < max_depth_m)
        idx = np.nonzero(front & ~seen)[0]
        if not len(idx):
            continue
        uv = camera.project(pc[idx])
        inside = camera.in_image(uv)
        idx, uv = idx[inside], uv[inside]
        u = np.clip(np.round(uv[:, 0]).astype(int), 0, depth.shape[1] - 1)
        v = np.clip(np.round(uv[:, 1]).astype(int), 0, depth.shape[0] - 1)
        d = depth[v, u]
        z = pc[idx, 2]
        ok = np.isfinite(d) & (d > 0) & (np.abs(d - z) <= tolerance_m + 0.02 * z)
        seen[idx[ok]] = True
    return seen


@dataclass
class OctreeScores:
    occupied: int
    precision: float
    recall: float
    ghost_voxels: int
    ghost_share: float


def octree_scores(centres: Array, truth: SceneTruth, resolution_m: float, observed: Array) -> OctreeScores:
    """Precision / recall of occupied voxels (centres in the truth's frame) and the ghost share."""
    if not len(centres):
        return OctreeScores(0, 0.0, 0.0, 0, 0.0)
    dist, _ = truth.distance(centres)
    on_surface = dist <= resolution_m
    ghosts = truth.in_any_mover(centres) & ~on_surface
    recall = 0.0
    if len(observed):
        near, _ = cKDTree(centres).query(observed, k=1, distance_upper_bound=resolution_m)
        recall = float(np.mean(np.isfinite(near)))
    return OctreeScores(len(centres), float(np.mean(on_surface)), recall, int(ghosts.sum()),
                        float(np.mean(ghosts)))
