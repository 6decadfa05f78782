"""ORB-SLAM's Fuse: project map points into a keyframe and merge them with the points
already at the matched keypoints. Used by local mapping (new keyframe vs. its neighbours)
and by loop closing (the loop's points into the corrected keyframes)."""

from __future__ import annotations

import numpy as np

from semslam.geometry.camera import PinholeCamera
from semslam.slam.map import KeyFrame, Map, MapPoint
from semslam.slam.search import project


class PointFusion:
    """Merges duplicate map points found by projection; counts what it fused."""

    def __init__(self, slam_map: Map, camera: PinholeCamera, bf: float) -> None:
        self.map = slam_map
        self.camera = camera
        self.pyr = slam_map.spec.pyramid  # the pyramid of the map's features
        self.bf = bf
        self.n_fused = 0

    def fuse(self, kf: KeyFrame, points: list[MapPoint], th: float = 3.0, touched: dict[int, MapPoint] | None = None) -> int:
        """Project points into ``kf``; merge with the point already at the matched keypoint
        (keep the one with more observations) or add the observation (ORB-SLAM Fuse)."""
        cand = [p for p in points if not p.bad and kf not in p.observations]
        if not cand:
            return 0
        fx, fy, cx, cy = self.camera.fx, self.camera.fy, self.camera.cx, self.camera.cy
        pos = np.array([p.pos for p in cand])
        uv, z = project(kf.T_cw, pos, fx, fy, cx, cy)
        dist = np.linalg.norm(pos - kf.center, axis=1)
        max_d = np.array([p.max_dist for p in cand])
        min_d = np.array([p.min_dist for p in cand])
        normals = np.array([p.normal for p in cand])
        view_cos = np.einsum("ij,ij->i", pos - kf.center, normals) / np.maximum(dist, 1e-9)
        ok = (z > 0) & (dist >= 0.8 * min_d) & (dist <= 1.2 * max_d) & (view_cos >= 0.5)
        ok &= self.camera.in_image(uv)
        sel = np.nonzero(ok)[0]
        if len(sel) == 0:
            return 0
        level = self.pyr.predict_level(max_d[sel], dist[sel])
        lists = kf.tree().query_ball_point(uv[sel], r=th * self.pyr.scales[level])
        counts = np.fromiter((len(x) for x in lists), np.intp, len(lists))
        if counts.sum() == 0:
            return 0
        cq = np.repeat(np.arange(len(lists)), counts)
        ct = np.fromiter((j for x in lists for j in x), np.intp, int(counts.sum()))
        lvl = kf.keypoints.octave[ct]
        good = (lvl >= level[cq] - 1) & (lvl <= level[cq])
        # Reprojection check (chi2 with 3 dof where the keypoint has depth, 2 otherwise).
        e = ((uv[sel][cq] - kf.xy[ct]) ** 2).sum(1)
        ur_pred = uv[sel][cq, 0] - self.bf / np.maximum(z[sel][cq], 1e-9)
        has_r = kf.ur[ct] >= 0
        e = e + np.where(has_r, (ur_pred - kf.ur[ct]) ** 2, 0.0)
        e = e * self.pyr.inv_sigma2[lvl]
        good &= np.where(has_r, e < 7.8, e < 5.99)
        cq, ct = cq[good], ct[good]
        desc = np.stack([cand[s].descriptor for s in sel])
        qi, ti, _ = self.map.matcher.match_candidates(desc, kf.keypoints.descriptors, cq, ct,
                                                      self.map.spec.th_low, 1.0)
        n = 0
        for q, t in zip(qi, ti):
            p = cand[sel[q]]
            if p.bad:
                continue
            existing = kf.points[t]
            if existing is not None and not existing.bad:
                keep, drop = (existing, p) if len(existing.observations) > len(p.observations) else (p, existing)
                self.map.replace_point(drop, keep)
            else:
                p.add_observation(kf, int(t))
                kf.points[t] = p
                keep = p
            if touched is not None:
                touched[keep.id] = keep
            n += 1
        self.n_fused += n
        return n
