"""ORB-SLAM2 local mapping: new keyframe processing, recent point culling, new points by
triangulation, duplicate fusion with neighbours, local bundle adjustment (GTSAM) and
redundant keyframe culling. Runs as a thread, or inline when ``slam.sequential`` is set.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from semslam.backend.bundle_adjustment import BAProblem, BAResult
from semslam.backend.worker import BundleAdjustmentRunner
from semslam.config import SystemConfig
from semslam.core.types import ScalePyramid
from semslam.geometry.camera import PinholeCamera
from semslam.slam.fusion import PointFusion
from semslam.slam.keyframe_worker import KeyframeInbox, KeyframeSink, KeyframeWorker
from semslam.slam.map import KeyFrame, Map, MapPoint, update_normals_and_depths
from semslam.slam.search import project

if TYPE_CHECKING:
    from semslam.place.vocabulary import Vocabulary

log = logging.getLogger(__name__)


def build_ba_problem(kfs_free: list[KeyFrame], kfs_fixed: list[KeyFrame], points: list[MapPoint],
                     camera: PinholeCamera, pyr: ScalePyramid, bf: float
                     ) -> tuple[BAProblem, list[tuple[MapPoint, KeyFrame]]]:
    """Arrays of a bundle adjustment over the given keyframes and points (observations of
    the points by keyframes outside both lists are left out)."""
    kfs = kfs_free + kfs_fixed
    kf_index = {kf: i for i, kf in enumerate(kfs)}
    obs_pose, obs_point, uv, ur, inv_s2 = [], [], [], [], []
    obs_ref: list[tuple[MapPoint, KeyFrame]] = []
    for j, p in enumerate(points):
        for kf, idx in p.observations.items():
            k = kf_index.get(kf)
            if k is None:
                continue
            obs_pose.append(k)
            obs_point.append(j)
            uv.append(kf.xy[idx])
            ur.append(kf.ur[idx])
            inv_s2.append(pyr.inv_sigma2[kf.keypoints.octave[idx]])
            obs_ref.append((p, kf))
    problem = BAProblem(
        poses_cw=np.stack([kf.T_cw for kf in kfs]),
        pose_fixed=np.array([False] * len(kfs_free) + [True] * len(kfs_fixed)),
        points_w=np.array([p.pos for p in points]).reshape(-1, 3),
        obs_pose=np.asarray(obs_pose, np.intp),
        obs_point=np.asarray(obs_point, np.intp),
        uv=np.asarray(uv, np.float64).reshape(-1, 2),
        ur=np.asarray(ur, np.float64),
        inv_sigma2=np.asarray(inv_s2, np.float64),
        fx=camera.fx, fy=camera.fy, cx=camera.cx, cy=camera.cy, bf=bf,
    )
    return problem, obs_ref


class LocalMapping(KeyframeWorker):
    """Processes keyframes from tracking; hands them on to loop closing."""

    thread_name = "local-mapping"

    def __init__(self, config: SystemConfig, camera: PinholeCamera, slam_map: Map, vocabulary: "Vocabulary",
                 ba: BundleAdjustmentRunner, fusion: PointFusion, inbox: KeyframeInbox, next_stage: KeyframeSink) -> None:
        self.cfg = config.slam
        self.camera = camera
        self.map = slam_map
        self.voc = vocabulary
        self.pyr = slam_map.spec.pyramid  # the pyramid of the map's features
        self.th_depth_m = self.cfg.bf * self.cfg.th_depth / camera.fx
        super().__init__(inbox)
        self.ba = ba
        self.fusion = fusion
        self.next_stage = next_stage
        self.recent_points: list[MapPoint] = []
        self.stats: dict[str, Any] = {"local_ba": 0, "local_ba_failed": 0, "local_ba_ms": [], "culled_keyframes": 0, "triangulated": 0,
                      "local_ba_split": [], "steps": {}}

    # ---------------------------------------------------------------- one keyframe
    def process(self, kf: KeyFrame) -> None:
        with self.map.lock:
            if kf.bad:
                return
            with self._step("new_keyframe"):
                self._process_new_keyframe(kf)
            with self._step("cull_points"):
                self._cull_points(kf)
            if self.cfg.triangulation:
                with self._step("triangulate"):
                    self._create_new_points(kf)
        if not self.inbox.has_pending():
            with self.map.lock, self._step("fuse"):
                self._search_in_neighbours(kf)
            if self.cfg.local_ba and len(self.map.keyframes) > 2:
                with self._step("local_ba"):
                    self._local_bundle_adjustment(kf)
            if self.cfg.keyframe_culling:
                with self.map.lock, self._step("cull_keyframes"):
                    self._cull_keyframes(kf)
        self.next_stage.insert(kf)

    @contextmanager
    def _step(self, name: str) -> Iterator[None]:
        """Wall and CPU (this thread) milliseconds of one step, in ``stats["steps"]``."""
        w0, c0 = time.perf_counter(), time.thread_time()
        try:
            yield
        finally:
            rec = self.stats["steps"].setdefault(name, {"wall_ms": [], "cpu_ms": []})
            rec["wall_ms"].append((time.perf_counter() - w0) * 1e3)
            rec["cpu_ms"].append((time.thread_time() - c0) * 1e3)

    def _process_new_keyframe(self, kf: KeyFrame) -> None:
        if kf.bow is None:
            kf.bow, kf.featvec = self.voc.transform(kf.keypoints.descriptors)
        matched = []
        for i, p in enumerate(kf.points):
            if p is None or p.bad:
                continue
            if kf not in p.observations:
                p.add_observation(kf, i)
                p.compute_distinctive_descriptor(self.map.matcher)
                matched.append(p)
            else:  # created by tracking for this keyframe
                self.recent_points.append(p)
        update_normals_and_depths(matched, self.pyr.scales)
        kf.update_connections()

    def _cull_points(self, kf: KeyFrame) -> None:
        """Recent points seen in < 25 % of the frames that should see them, or by < 3
        keyframes two keyframes after creation, are removed (ORB-SLAM MapPointCulling)."""
        keep = []
        for p in self.recent_points:
            if p.bad:
                continue
            age = kf.id - p.first_kf_id
            # Observations count twice where the keyframe has depth (ORB-SLAM's stereo rule),
            # so "<= 3" means: seen by fewer than two RGB-D keyframes.
            if p.found_ratio < 0.25 or (age >= 2 and p.n_obs <= 3):
                self.map.set_bad_point(p)
                continue
            if age >= 3:
                continue
            keep.append(p)
        self.recent_points = keep

    # ---------------------------------------------------------------- triangulation
    def _create_new_points(self, kf: KeyFrame) -> None:
        """Triangulate unmatched keypoints with the best covisible keyframes (epipolar-guided)."""
        baseline = self.cfg.bf / self.camera.fx
        free1 = np.array([p is None or p.bad for p in kf.points], bool)
        for nb in kf.best_covisibles(10):
            if not free1.any():
                break
            if np.linalg.norm(nb.center - kf.center) < baseline:
                continue
            free2 = np.array([p is None or p.bad for p in nb.points], bool)
            i1, i2 = self._epipolar_matches(kf, nb, free1, free2)
            if len(i1) == 0:
                continue
            pts, ok = self._triangulate(kf, nb, i1, i2)
            for a, b, pw in zip(i1[ok], i2[ok], pts[ok]):
                if not free1[a] or not (nb.points[b] is None or nb.points[b].bad):
                    continue
                p = self.map.new_point(pw, kf.keypoints.descriptors[a].copy(), kf)
                p.add_observation(kf, int(a))
                p.add_observation(nb, int(b))
                kf.points[a] = p
                nb.points[b] = p
                p.compute_distinctive_descriptor(self.map.matcher)
                p.update_normal_and_depth(self.pyr.scales)
                self.recent_points.append(p)
                free1[a] = False
                self.stats["triangulated"] += 1

    def _epipolar_matches(self, kf1: KeyFrame, kf2: KeyFrame, free1: NDArray[np.bool_], free2: NDArray[np.bool_]
                          ) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        qa, qb = [], []
        for node, ia in kf1.featvec.items():
            ib = kf2.featvec.get(node)
            if ib is None or len(ib) == 0:
                continue
            a = np.asarray(ia, np.intp)
            b = np.asarray(ib, np.intp)
            a, b = a[free1[a]], b[free2[b]]
            if len(a) and len(b):
                qa.append(np.repeat(a, len(b)))
                qb.append(np.tile(b, len(a)))
        if not qa:
            return np.zeros(0, np.intp), np.zeros(0, np.intp)
        ca, cb = np.concatenate(qa), np.concatenate(qb)
        # Fundamental matrix F12 with x1^T F12 x2 = 0 (pixels, undistorted).
        T12 = kf1.T_cw @ kf2.T_wc
        R12, t12 = T12[:3, :3], T12[:3, 3]
        tx = np.array([[0, -t12[2], t12[1]], [t12[2], 0, -t12[0]], [-t12[1], t12[0], 0]])
        Kinv = np.linalg.inv(self.camera.K)
        F12 = Kinv.T @ tx @ R12 @ Kinv
        x1 = np.c_[kf1.xy[ca], np.ones(len(ca))]
        x2 = np.c_[kf2.xy[cb], np.ones(len(cb))]
        line = x1 @ F12  # epipolar lines in image 2
        num = np.einsum("ij,ij->i", line, x2)
        den = line[:, 0] ** 2 + line[:, 1] ** 2
        dsqr = num**2 / np.maximum(den, 1e-12)
        sigma2 = 1.0 / self.pyr.inv_sigma2[kf2.keypoints.octave[cb]]
        # Also skip keypoints too close to the epipole (no parallax).
        ok = dsqr < 3.84 * sigma2
        qi, ti, _ = self.map.matcher.match_candidates(kf1.keypoints.descriptors,
                                                      kf2.keypoints.descriptors, ca[ok], cb[ok],
                                                      self.map.spec.th_low, 0.6)
        return qi, ti

    def _triangulate(self, kf1: KeyFrame, kf2: KeyFrame, i1: NDArray[np.intp], i2: NDArray[np.intp]
                     ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
        K = self.camera.K
        P1 = K @ kf1.T_cw[:3]
        P2 = K @ kf2.T_cw[:3]
        u1, u2 = kf1.xy[i1], kf2.xy[i2]
        A = np.stack([u1[:, :1] * P1[2] - P1[0], u1[:, 1:2] * P1[2] - P1[1],
                      u2[:, :1] * P2[2] - P2[0], u2[:, 1:2] * P2[2] - P2[1]], axis=1)
        _, _, vt = np.linalg.svd(A)
        X = vt[:, -1]
        w = X[:, 3:4]
        good = np.abs(w[:, 0]) > 1e-12
        pts = X[:, :3] / np.where(good[:, None], w, 1.0)
        # Parallax: rays must not be (near) parallel.
        r1 = pts - kf1.center
        r2 = pts - kf2.center
        cosp = np.einsum("ij,ij->i", r1, r2) / np.maximum(np.linalg.norm(r1, axis=1) * np.linalg.norm(r2, axis=1), 1e-12)
        ok = good & (cosp < 0.9998)
        fx, fy, cx, cy = self.camera.fx, self.camera.fy, self.camera.cx, self.camera.cy
        for kf, idx, uv in ((kf1, i1, u1), (kf2, i2, u2)):
            proj, z = project(kf.T_cw, pts, fx, fy, cx, cy)
            err2 = ((proj - uv) ** 2).sum(1) * self.pyr.inv_sigma2[kf.keypoints.octave[idx]]
            ok &= (z > 0) & (err2 < 5.991)
        d1 = np.linalg.norm(r1, axis=1)
        d2 = np.linalg.norm(r2, axis=1)
        ratio_dist = d2 / np.maximum(d1, 1e-12)
        ratio_oct = self.pyr.scales[kf1.keypoints.octave[i1]] / self.pyr.scales[kf2.keypoints.octave[i2]]
        factor = 1.5 * self.pyr.scale_factor
        ok &= (ratio_dist * factor >= ratio_oct) & (ratio_dist <= ratio_oct * factor)
        return pts, ok

    # ---------------------------------------------------------------- fusion
    def _search_in_neighbours(self, kf: KeyFrame) -> None:
        targets: dict[KeyFrame, None] = {}
        for nb in kf.best_covisibles(10):
            targets.setdefault(nb)
            for nb2 in nb.best_covisibles(5):
                if nb2 is not kf:
                    targets.setdefault(nb2)
        pts = kf.valid_points()
        touched: dict[int, MapPoint] = {}
        for t in targets:
            self.fusion.fuse(t, pts, touched=touched)
        cand: dict[int, MapPoint] = {}
        for t in targets:
            for p in t.valid_points():
                cand.setdefault(p.id, p)
        self.fusion.fuse(kf, list(cand.values()), touched=touched)
        changed = [p for p in touched.values() if not p.bad]
        for p in changed:
            p.compute_distinctive_descriptor(self.map.matcher)
        update_normals_and_depths(changed, self.pyr.scales)
        kf.update_connections()

    # ---------------------------------------------------------------- local BA
    def _local_bundle_adjustment(self, kf: KeyFrame) -> None:
        t0 = time.perf_counter()
        with self.map.lock:
            local = [kf] + [k for k in kf.ordered_covis if not k.bad][: self.cfg.local_ba_max_keyframes - 1]
            local_set = set(local)
            pts: dict[int, MapPoint] = {}
            for k in local:
                for p in k.valid_points():
                    pts.setdefault(p.id, p)
            points = list(pts.values())
            fixed: dict[KeyFrame, int] = {}
            for p in points:
                for k in p.observations:
                    if k not in local_set and not k.bad:
                        fixed[k] = fixed.get(k, 0) + 1
            free = [k for k in local if k.id != 0]
            fixed_list = sorted(fixed, key=lambda k: -fixed[k])[: self.cfg.local_ba_max_fixed] + [k for k in local if k.id == 0]
            if not points or not free:
                return
            problem, obs_ref = build_ba_problem(free, fixed_list, points, self.camera, self.pyr, self.cfg.bf)
            gen = self.map.generation
        t1 = time.perf_counter()
        result: BAResult = self.ba.run(problem)
        t2 = time.perf_counter()
        if not result.converged:
            self.stats["local_ba_failed"] += 1
        with self.map.lock:
            if self.map.generation != gen:
                return
            for k, T in zip(free, result.poses_cw[: len(free)]):
                if not k.bad:
                    k.set_pose(T)
            for (p, k), inlier in zip(obs_ref, result.inlier_obs):
                if not inlier and not p.bad and k in p.observations:
                    idx = p.observations[k]
                    if k.points[idx] is p:
                        k.points[idx] = None
                    p.erase_observation(k)
            for p, pos in zip(points, result.points_w):
                if not p.bad:
                    p.pos = pos
            update_normals_and_depths([p for p in points if not p.bad], self.pyr.scales)
        t3 = time.perf_counter()
        self.stats["local_ba"] += int(result.converged)
        self.stats["local_ba_ms"].append((t3 - t0) * 1e3)
        self._record_ba_split(problem, result, t0, t1, t2, t3)

    def _record_ba_split(self, problem: BAProblem, result: BAResult, t0: float, t1: float,
                         t2: float, t3: float) -> None:
        """Where one local BA's time went (ms), for ``benchmarks/backend_timing.py``: gathering
        the problem from the map, the solver's own phases, the hand-over to and from the
        runner (IPC to the worker process: the runner's wall time minus the solver's) and
        applying the result to the map."""
        solve = (t2 - t1) * 1e3
        self.stats["local_ba_split"].append({
            "gather": (t1 - t0) * 1e3, "ipc": max(solve - result.time_ms, 0.0), "solve": solve,
            **{k: v for k, v in result.timings.items()}, "apply": (t3 - t2) * 1e3,
            "total": (t3 - t0) * 1e3, "keyframes": int(problem.poses_cw.shape[0]),
            "free": int((~np.asarray(problem.pose_fixed)).sum()),
            "points": int(problem.points_w.shape[0]), "observations": int(problem.obs_pose.size)})

    # ---------------------------------------------------------------- keyframe culling
    def _cull_keyframes(self, kf: KeyFrame) -> None:
        """A keyframe whose close points are 90 % seen by >= 3 other keyframes at the same
        or a finer scale is redundant (ORB-SLAM KeyFrameCulling)."""
        for cand in kf.ordered_covis:
            if cand.id == 0 or cand.bad or cand is kf:
                continue
            n_points = redundant = 0
            for i, p in enumerate(cand.points):
                if p is None or p.bad:
                    continue
                if cand.depth[i] > self.th_depth_m or cand.depth[i] <= 0:
                    continue
                n_points += 1
                if p.n_obs > 3:
                    level = cand.keypoints.octave[i]
                    n_obs = 0
                    for other, j in p.observations.items():
                        if other is cand:
                            continue
                        if other.keypoints.octave[j] <= level + 1:
                            n_obs += 1
                            if n_obs >= 3:
                                break
                    if n_obs >= 3:
                        redundant += 1
            if n_points and redundant > 0.9 * n_points:
                self.map.set_bad_keyframe(cand)
                self.stats["culled_keyframes"] += 1
