"""ORB-SLAM's Fuse: project map points into a keyframe and merge them with the points
already at the matched keypoints. Used by local mapping (new keyframe vs. its neighbours)
and by loop closing (the loop's points into the corrected keyframes).

Split in two so the search can run without the map lock: :meth:`PointFusion.plan` only reads
(the points' arrays are gathered once by :class:`PointArrays` and reused for every target
keyframe) and returns the matches; :meth:`PointFusion.apply` changes the map (the caller holds
``map.lock``) and checks each match again against the map as it is then.
"""

from __future__ import annotations

from dataclasses import dataclass
from operator import attrgetter
from typing import Any

import numpy as np
from numpy.typing import NDArray

from semslam.geometry.camera import PinholeCamera
from semslam.slam.orb.map import KeyFrame, Map
from semslam.slam.orb.point_store import MapPoint
from semslam.slam.orb.map_batch import distinctive_descriptors, shared_store, store_rows
from semslam.geometry.projection import project

_ID = attrgetter("id")


def adopt_matched_points(slam_map: Map, kf: KeyFrame, matched: dict[int, MapPoint]) -> None:
    """Verified matches (kf keypoint -> a point of the other side: a loop's, or another
    map's) win: each replaces kf's own point there, or is observed by kf where it had none.
    The caller holds the map lock."""
    for idx, lp in matched.items():
        if lp.bad:
            continue
        cur = kf.points[idx]
        if cur is not None and not cur.bad:
            slam_map.replace_point(cur, lp)
        elif not lp.is_observed_by(kf):
            lp.add_observation(kf, idx)
            kf.points[idx] = lp


@dataclass
class PointArrays:
    """Positions, depth ranges, normals, descriptors and ids of a list of good points."""

    points: list[MapPoint]
    ids: NDArray[np.int64]
    pos: NDArray[np.float64]
    min_dist: NDArray[np.float64]
    max_dist: NDArray[np.float64]
    normal: NDArray[np.float64]
    descriptors: NDArray[Any]

    @classmethod
    def of(cls, points: list[MapPoint]) -> "PointArrays":
        """The good ones of ``points``, gathered by store rows (attribute by attribute only
        for points that do not share one store: made outside a map, in tests)."""
        store = shared_store(points)
        if store is None:
            pts = [p for p in points if not p.bad]
            rows = None
        else:
            rows = store_rows(points)
            keep = np.flatnonzero(~store.bad[rows])
            pts = [points[i] for i in keep.tolist()]
            rows = rows[keep]
        n = len(pts)
        if n == 0:
            return cls([], np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0), np.zeros(0),
                       np.zeros((0, 3)), np.zeros((0, 0), np.uint8))
        ids = np.fromiter(map(_ID, pts), np.int64, n)
        if store is not None and rows is not None:
            return cls(pts, ids, store.pos[rows], store.min_dist[rows], store.max_dist[rows], store.normal[rows],
                       store.descriptor[rows])
        return cls(pts, ids, np.array([p.pos for p in pts]),
                   np.fromiter((p.min_dist for p in pts), np.float64, n),
                   np.fromiter((p.max_dist for p in pts), np.float64, n),
                   np.array([p.normal for p in pts]), np.stack([p.descriptor for p in pts]))


class PointFusion:
    """Merges duplicate map points found by projection; counts what it fused."""

    def __init__(self, slam_map: Map, camera: PinholeCamera, bf: float) -> None:
        self.map = slam_map
        self.camera = camera
        self.pyr = slam_map.spec.pyramid  # the pyramid of the map's features
        self.bf = bf
        self.n_fused = 0

    def fuse(self, kf: KeyFrame, points: list[MapPoint], th: float = 3.0,
             touched: dict[int, MapPoint] | None = None) -> int:
        """Project points into ``kf``; merge with the point already at the matched keypoint
        (keep the one with more observations) or add the observation (ORB-SLAM Fuse).
        The caller holds ``map.lock``."""
        return self.apply(kf, self.plan(kf, PointArrays.of(points), th), touched)

    def plan(self, kf: KeyFrame, src: PointArrays, th: float = 3.0) -> list[tuple[MapPoint, int]]:
        """The (point, keypoint index) pairs Fuse would merge in ``kf``; reads only.

        Points ``kf`` already observes (its own map points) are skipped."""
        if not src.points or kf.bad:
            return []
        own = np.fromiter(map(_ID, kf.valid_points()), np.int64)
        keep = ~np.isin(src.ids, own) if own.size else np.ones(len(src.points), bool)
        cand = np.flatnonzero(keep)
        if cand.size == 0:
            return []
        fx, fy, cx, cy = self.camera.fx, self.camera.fy, self.camera.cx, self.camera.cy
        pos = src.pos[cand]
        uv, z = project(kf.T_cw, pos, fx, fy, cx, cy)
        center = kf.center
        dist = np.linalg.norm(pos - center, axis=1)
        max_d = src.max_dist[cand]
        min_d = src.min_dist[cand]
        view_cos = np.einsum("ij,ij->i", pos - center, src.normal[cand]) / np.maximum(dist, 1e-9)
        ok = (z > 0) & (dist >= 0.8 * min_d) & (dist <= 1.2 * max_d) & (view_cos >= 0.5)
        ok &= self.camera.in_image(uv)
        sel = np.nonzero(ok)[0]
        if len(sel) == 0:
            return []
        level = self.pyr.predict_level(max_d[sel], dist[sel])
        # Keypoints within th * scale pixels at the predicted level or one below (compiled,
        # without the GIL), per point in keypoint order.
        cq, ct = kf.grid(*self.camera.image_size).pairs_in_radius(
            uv[sel], th * self.pyr.scales[level], level - 1, level, np.ones(len(kf.xy), bool))
        if cq.size == 0:
            return []
        order = np.lexsort((ct, cq))
        cq, ct = cq[order], ct[order]
        lvl = kf.keypoints.octave[ct]
        # Reprojection check (chi2 with 3 dof where the keypoint has depth, 2 otherwise).
        e = ((uv[sel][cq] - kf.xy[ct]) ** 2).sum(1)
        ur_pred = uv[sel][cq, 0] - self.bf / np.maximum(z[sel][cq], 1e-9)
        has_r = kf.ur[ct] >= 0
        e = e + np.where(has_r, (ur_pred - kf.ur[ct]) ** 2, 0.0)
        e = e * self.pyr.inv_sigma2[lvl]
        good = np.where(has_r, e < 7.8, e < 5.99)
        cq, ct = cq[good], ct[good]
        desc = src.descriptors[cand[sel]]
        qi, ti, _ = self.map.matcher.match_candidates(desc, kf.keypoints.descriptors, cq, ct,
                                                      self.map.spec.th_low, 1.0)
        return [(src.points[cand[sel[q]]], int(t)) for q, t in zip(qi.tolist(), ti.tolist())]

    def apply(self, kf: KeyFrame, matches: list[tuple[MapPoint, int]],
              touched: dict[int, MapPoint] | None = None) -> int:
        """Merge planned matches into ``kf`` (the caller holds ``map.lock``).  A match whose
        point went bad, or that ``kf`` observes by now, is dropped."""
        if kf.bad:
            return 0
        n = 0
        merged: dict[int, MapPoint] = {}  # points that took another's observations
        for p, t in matches:
            if p.bad or p.is_observed_by(kf):
                continue
            existing = kf.points[t]
            if existing is not None and not existing.bad:
                keep, drop = (existing, p) if existing.n_observers > p.n_observers else (p, existing)
                self.map.replace_point(drop, keep, descriptor=False)
                merged[keep.id] = keep
            else:
                p.add_observation(kf, t)
                kf.points[t] = p
                keep = p
            if touched is not None:
                touched[keep.id] = keep
            n += 1
        # Their distinctive descriptors, as replace_point computes them, in one batch: no
        # descriptor is read in between, and a point's observations change after its last
        # merge here only by another merge into it (a point kf observes is not matched again).
        distinctive_descriptors([p for p in merged.values() if not p.bad], self.map.matcher).write()
        self.n_fused += n
        return n
