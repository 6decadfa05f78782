"""ORB-SLAM2 local mapping: new keyframe processing, recent point culling, new points by
triangulation, duplicate fusion with neighbours, local bundle adjustment and redundant
keyframe culling. Runs as a thread, or inline when ``slam.sequential`` is set.

Locking (see docs/architecture.md): tracking holds ``map.lock`` for a whole frame, so every
step here reads the map and does its work without the lock, then writes what it found under
the lock in short critical sections (``apply_in_slices`` lets go of the lock every ~1 ms
when there are many small changes) that check again what may have changed meanwhile.
Reading without the lock is safe because the map's structure (observations, keyframes'
point slots, covisibility) has only two writers, this thread and loop closing, and loop
closing pauses this thread (``KeyframeInbox.paused``) around everything it writes; tracking
only adds new keyframes and points (unreachable from here until published), counts
(``n_visible``, ``n_found``) and marks points bad, which every write here checks.  Every
write, to the structure and to the point store (positions, descriptors, normals, depth
ranges), happens under the lock: values are computed first, then stored by rows.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from functools import partial
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from semslam.backend.bundle_adjustment import BAProblem, BAResult
from semslam.backend.worker import BundleAdjustmentRunner
from semslam.config import SystemConfig
from semslam.core.types import ScalePyramid
from semslam.geometry.camera import PinholeCamera
from semslam.slam.orb.depth_prior import DepthPrior
from semslam.slam.orb.frame_builders import is_monocular
from semslam.slam.orb.fusion import PointArrays, PointFusion
from semslam.slam.orb.keyframe_worker import KeyframeInbox, KeyframeSink, KeyframeWorker
from semslam.slam.orb.inertial_links import add_links
from semslam.slam.orb.map import KeyFrame, Map
from semslam.slam.orb.point_store import MapPoint
from semslam.slam.orb.map_batch import (distinctive_descriptors, gather_keypoints, normals_and_depths, observation_table,
                                        point_positions)
from semslam.slam.orb.map_batch import warm_up as warm_up_kernels
from semslam.geometry.projection import project
from semslam.slam.orb.search import node_pairs

if TYPE_CHECKING:
    from semslam.place.vocabulary import Vocabulary

log = logging.getLogger(__name__)


def build_ba_problem(kfs_free: list[KeyFrame], kfs_fixed: list[KeyFrame], points: list[MapPoint],
                     camera: PinholeCamera, pyr: ScalePyramid, bf: float,
                     table: tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.intp], list[KeyFrame]] | None = None,
                     depth_prior: DepthPrior | None = None) -> BAProblem:
    """Arrays of a bundle adjustment over the given keyframes and points (observations of
    the points by keyframes outside both lists are left out); observation ``m`` is point
    ``points[obs_point[m]]`` in keyframe ``(kfs_free + kfs_fixed)[obs_pose[m]]``.
    ``table`` is ``observation_table(points)`` when the caller has it already. With an IMU
    the keyframes' inertial links between them come too (``inertial_links.add_links``)."""
    kfs = kfs_free + kfs_fixed
    if table is None:
        obs_point, obs_pose, kp, _ = observation_table(points, {kf: i for i, kf in enumerate(kfs)})
    else:
        pt_row, kf_row, kp_all, observers = table
        where = {kf: i for i, kf in enumerate(kfs)}
        pose_of = np.array([where.get(kf, -1) for kf in observers], np.intp)
        sel = pose_of[kf_row] >= 0
        obs_point, obs_pose, kp = pt_row[sel], pose_of[kf_row[sel]], kp_all[sel]
    uv, ur, octave = gather_keypoints(kfs, obs_pose, kp)
    if depth_prior is not None:  # monocular: the prior's depths as virtual right coordinates
        bf = depth_prior.virtual_bf()
        ur = depth_prior.virtual_right(uv[:, 0], _prior_depths(kfs, obs_pose, kp), bf)
    problem = BAProblem(
        poses_cw=np.stack([kf.T_cw for kf in kfs]),
        pose_fixed=np.array([False] * len(kfs_free) + [True] * len(kfs_fixed)),
        points_w=point_positions(points),
        obs_pose=obs_pose,
        obs_point=obs_point,
        uv=uv,
        ur=ur,
        inv_sigma2=pyr.inv_sigma2[octave],
        fx=camera.fx, fy=camera.fy, cx=camera.cx, cy=camera.cy, bf=bf,
    )
    add_links(problem, kfs)
    return problem


def _prior_depths(kfs: list[KeyFrame], obs_pose: NDArray[np.intp], kp: NDArray[np.intp]) -> NDArray[np.float32]:
    """Each observation's checked prior depth (0: none)."""
    out = np.zeros(kp.size, np.float32)
    for i, kf in enumerate(kfs):
        if kf.prior_depth is not None:
            sel = obs_pose == i
            out[sel] = kf.prior_depth[kp[sel]]
    return out


def _chunks(items: list[Any], n: int) -> list[list[Any]]:
    return [items[i:i + n] for i in range(0, len(items), n)]


def apply_in_slices(lock: Any, jobs: list[Callable[[], object]], budget_s: float = 1e-3) -> None:
    """Run ``jobs`` in order under ``lock``, letting go of it between jobs once a slice has
    held it for ``budget_s`` (and sleeping a moment, so a thread waiting for it gets it
    before this one takes it again): many small changes that are each consistent on their
    own, without holding tracking up for all of them at once."""
    i = 0
    while i < len(jobs):
        with lock:
            t_end = time.perf_counter() + budget_s
            while i < len(jobs):
                jobs[i]()
                i += 1
                if time.perf_counter() > t_end:
                    break
        if i < len(jobs):
            time.sleep(1e-4)


class LocalMapping(KeyframeWorker):
    """Processes keyframes from tracking; hands them on to loop closing."""

    thread_name = "local-mapping"

    def __init__(self, config: SystemConfig, camera: PinholeCamera, slam_map: Map, vocabulary: "Vocabulary",
                 ba: BundleAdjustmentRunner, fusion: PointFusion, inbox: KeyframeInbox, next_stage: KeyframeSink,
                 depth_prior: DepthPrior | None = None) -> None:
        self.cfg = config.slam
        self.yield_s = config.slam.yield_to_tracking_ms / 1e3
        self.camera = camera
        self.map = slam_map
        self.voc = vocabulary
        self.pyr = slam_map.spec.pyramid  # the pyramid of the map's features
        self.th_depth_m = self.cfg.bf * self.cfg.th_depth / camera.fx
        # No depth at all: ORB-SLAM's monocular thresholds where they differ.
        self.mono = is_monocular(config)
        self.depth_prior = depth_prior
        super().__init__(inbox)
        self.ba = ba
        self.fusion = fusion
        self.next_stage = next_stage
        self.recent_points: list[MapPoint] = []
        warm_up_kernels()  # never compiled inside a critical section
        self.stats: dict[str, Any] = {"local_ba": 0, "local_ba_failed": 0, "local_ba_ms": [], "local_ba_links": 0,
                                      "culled_keyframes": 0, "triangulated": 0, "local_ba_split": [], "steps": {}}

    # ---------------------------------------------------------------- one keyframe
    def process(self, kf: KeyFrame) -> None:
        if kf.bad:
            return
        with self._step("new_keyframe"):
            self._process_new_keyframe(kf)
            if self.depth_prior is not None and kf.predicted_depth is not None:
                self._check_depth_prior(kf)
        with self._step("cull_points"):
            self._cull_points(kf)
        if self.cfg.triangulation:
            with self._step("triangulate"):
                self._create_new_points(kf)
        if not self.inbox.has_pending():
            with self._step("fuse"):
                self._search_in_neighbours(kf)
            if self.cfg.local_ba and len(self.map.keyframes) > 2:
                with self._step("local_ba"):
                    self._local_bundle_adjustment(kf)
            if self.cfg.keyframe_culling:
                with self._step("cull_keyframes"):
                    self._cull_keyframes(kf)
        self.next_stage.insert(kf)

    def _write_statistics(self, points: list[MapPoint], descriptors: bool = True) -> None:
        """Distinctive descriptors (optionally) and normals / depth ranges of ``points``:
        computed without the lock, written to the point store under it."""
        desc = distinctive_descriptors(points, self.map.matcher) if descriptors else None
        normals = normals_and_depths(points, self.pyr.scales)
        if not normals.points and (desc is None or not desc.points):
            return
        with self.map.lock:
            if desc is not None:
                desc.write()
            normals.write()

    def cpu_ms(self) -> dict[str, float]:
        """This thread's CPU milliseconds over the run, per step, in total and per keyframe
        processed: what local mapping takes from the two cores (and, for its Python, from the
        GIL it shares with tracking), steadier from run to run than wall times."""
        steps = {name: float(sum(rec["cpu_ms"])) for name, rec in self.stats["steps"].items()}
        total = sum(steps.values())
        n = len(self.stats["steps"].get("new_keyframe", {}).get("cpu_ms", []))
        return {"total": total, "per_keyframe": total / n if n else 0.0, **steps}

    def yield_to_tracking(self) -> None:
        """In a threaded run, wait (at most ``slam.yield_to_tracking_ms``) until tracking has
        finished its frame before a Python-heavy step: both threads share one GIL, and a
        step started between frames does not stretch the next frame's extraction."""
        if self._thread is not None and self.yield_s > 0:
            self.map.tracking_idle.wait(self.yield_s)

    @contextmanager
    def _step(self, name: str) -> Iterator[None]:
        """Wall and CPU (this thread) milliseconds of one step, in ``stats["steps"]``; each
        step starts between tracked frames when it can (``yield_to_tracking``)."""
        self.yield_to_tracking()
        w0, c0 = time.perf_counter(), time.thread_time()
        try:
            yield
        finally:
            rec = self.stats["steps"].setdefault(name, {"wall_ms": [], "cpu_ms": []})
            rec["wall_ms"].append((time.perf_counter() - w0) * 1e3)
            rec["cpu_ms"].append((time.thread_time() - c0) * 1e3)

    def _process_new_keyframe(self, kf: KeyFrame) -> None:
        """ORB-SLAM ProcessNewKeyFrame: bag of words (without the lock), the keyframe's
        observations added to its points and its connections (under the lock, in slices),
        the points' descriptors and normals (computed without the lock)."""
        bow = featvec = None
        if kf.bow is None:  # reads only the keyframe's own descriptors: no lock
            bow, featvec = self.voc.transform(kf.keypoints.descriptors)
        matched: list[MapPoint] = []

        def set_bow() -> None:
            if bow is not None:
                kf.set_words(bow, featvec)

        def observe(slots: list[tuple[int, MapPoint]]) -> None:
            for i, p in slots:
                if p.bad or kf.points[i] is not p:
                    continue
                if not p.is_observed_by(kf):
                    p.add_observation(kf, i)
                    matched.append(p)
                else:  # created by tracking for this keyframe
                    self.recent_points.append(p)

        slots = [(i, p) for i, p in enumerate(kf.points) if p is not None]
        apply_in_slices(self.map.lock, [set_bow, *(partial(observe, c) for c in _chunks(slots, 64)),
                                        kf.update_connections])
        self._write_statistics(matched)

    def _check_depth_prior(self, kf: KeyFrame) -> None:
        """The keyframe's prior for local BA: its predicted depths where they agree with the
        depths of its map points (slam/orb/depth_prior.py)."""
        assert self.depth_prior is not None and kf.predicted_depth is not None
        with self.map.lock:
            idx = np.flatnonzero(kf.points.rows >= 0)
            pos = self.map.store.pos[kf.points.rows[idx]]
            T = kf.T_cw.copy()
        map_depth = np.zeros(len(kf.predicted_depth))
        map_depth[idx] = pos @ T[2, :3] + T[2, 3]
        kf.prior_depth = self.depth_prior.check_keyframe(map_depth, kf.predicted_depth)

    def _cull_points(self, kf: KeyFrame) -> None:
        """Recent points seen in < 25 % of the frames that should see them, or by < 3
        keyframes two keyframes after creation, are removed (ORB-SLAM MapPointCulling)."""
        keep, cull = [], []
        for p in self.recent_points:
            if p.bad:
                continue
            if p.ref_kf is not None and p.ref_kf.map_id != kf.map_id:
                # An atlas map tracking left (slam/orb/atlas.py): its keyframes stopped coming, so
                # its points cannot be seen again; ageing them by the new map's keyframes
                # culled every point of a map that had one keyframe (nothing left to merge with).
                continue
            age = kf.id - p.first_kf_id
            # Observations count twice where the keyframe has depth (ORB-SLAM's stereo rule),
            # so "<= 3" means: seen by fewer than two RGB-D keyframes.
            if p.found_ratio < 0.25 or (age >= 2 and p.n_obs <= (2 if self.mono else 3)):
                cull.append(p)
                continue
            if age >= 3:
                continue
            keep.append(p)
        self.recent_points = keep
        apply_in_slices(self.map.lock, [partial(self.map.set_bad_point, p) for p in cull])

    # ---------------------------------------------------------------- triangulation
    def _create_new_points(self, kf: KeyFrame) -> None:
        """Triangulate unmatched keypoints with the best covisible keyframes (epipolar-guided);
        the matching and triangulation run without the lock, the new points are added under
        it (in slices, ``apply_in_slices``)."""
        baseline = self.cfg.bf / self.camera.fx
        free1 = kf.free_mask()
        new: list[tuple[KeyFrame, int, int]] = []
        new_pos = []
        # Monocular: 20 neighbours, and a baseline of 1 % of the neighbour's median scene
        # depth instead of the virtual stereo baseline (ORB-SLAM CreateNewMapPoints).
        for nb in kf.best_covisibles(20 if self.mono else 10):
            if not free1.any():
                break
            dist = np.linalg.norm(nb.center - kf.center)
            if self.mono:
                median = self._median_depth(nb)
                if not median > 0 or dist / median < 0.01:
                    continue
            elif dist < baseline:
                continue
            free2 = nb.free_mask()
            i1, i2 = self._epipolar_matches(kf, nb, free1, free2)
            if len(i1) == 0:
                continue
            pts, ok = self._triangulate(kf, nb, i1, i2)
            # Each keypoint of nb is matched at most once (and each of kf once per neighbour).
            for a, b, pw in zip(i1[ok].tolist(), i2[ok].tolist(), pts[ok]):
                if not free1[a] or not free2[b]:
                    continue
                new.append((nb, a, b))
                new_pos.append(pw)
                free1[a] = False
        if not new:
            return
        # The new points' normals and depth ranges (observed by kf, their reference, and nb)
        # and descriptors (of two observations the first, kf's, has the least median).
        pos = np.array(new_pos)
        centers = np.array([nb.center for nb, _, _ in new])
        a_idx = np.array([a for _, a, _ in new], np.intp)
        d1 = pos - kf.center
        dist1 = np.linalg.norm(d1, axis=1)
        d2 = pos - centers
        normal = d1 / np.maximum(dist1, 1e-9)[:, None] + d2 / np.maximum(np.linalg.norm(d2, axis=1), 1e-9)[:, None]
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-9)
        max_d = dist1 * self.pyr.scales[kf.keypoints.octave[a_idx]]
        min_d = max_d / self.pyr.scales[-1]
        desc = kf.keypoints.descriptors[a_idx]  # a copy: one row per new point
        apply_in_slices(self.map.lock, [partial(self._add_triangulated, kf, nb, a, b, pw, n, mx, mn, d)
                                        for (nb, a, b), pw, n, mx, mn, d
                                        in zip(new, pos, normal, max_d.tolist(), min_d.tolist(), desc)])

    def _median_depth(self, kf: KeyFrame) -> float:
        """Median depth of the keyframe's points in its frame (ComputeSceneMedianDepth(2));
        0 without points."""
        rows = kf.points.good_rows(self.map.store)[1]
        if not rows.size:
            return 0.0
        z = self.map.store.pos[rows] @ kf.T_cw[2, :3] + kf.T_cw[2, 3]
        return float(np.median(z))

    def _add_triangulated(self, kf: KeyFrame, nb: KeyFrame, a: int, b: int, pw: NDArray[np.float64],
                          normal: NDArray[np.float64], max_dist: float, min_dist: float,
                          descriptor: NDArray[Any]) -> None:
        """One new point seen by keypoint a of kf and b of nb, if both are still free."""
        old_a, old_b = kf.points[a], nb.points[b]
        if kf.bad or nb.bad or (old_a is not None and not old_a.bad) or (old_b is not None and not old_b.bad):
            return
        p = self.map.new_point(pw, descriptor, kf)
        p.add_observation(kf, a)
        p.add_observation(nb, b)
        p.normal, p.max_dist, p.min_dist = normal, max_dist, min_dist
        kf.points[a] = p
        nb.points[b] = p
        self.recent_points.append(p)
        self.stats["triangulated"] += 1

    def _epipolar_matches(self, kf1: KeyFrame, kf2: KeyFrame, free1: NDArray[np.bool_], free2: NDArray[np.bool_]
                          ) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        ca, cb = node_pairs(kf1.featvec, kf2.featvec, free1, free2)
        if ca.size == 0:
            return ca, cb
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
        """ORB-SLAM SearchInNeighbors: kf's points fused into its neighbours (two levels of
        covisibility), then the neighbours' points into kf.  Each direction is searched
        without the lock for all keyframes at once and applied under it in slices."""
        targets: dict[KeyFrame, None] = {}
        for nb in kf.best_covisibles(10):
            targets.setdefault(nb)
            for nb2 in nb.best_covisibles(5):
                if nb2 is not kf:
                    targets.setdefault(nb2)
        touched: dict[int, MapPoint] = {}
        src = PointArrays.of(kf.valid_points())
        plans = [(t, self.fusion.plan(t, src)) for t in targets]
        apply_in_slices(self.map.lock, [partial(self.fusion.apply, t, matches, touched)
                                        for t, matches in plans if matches])
        cand: dict[int, MapPoint] = {}
        for t in targets:
            for p in t.valid_points():
                cand.setdefault(p.id, p)
        matches = self.fusion.plan(kf, PointArrays.of(list(cand.values())))
        apply_in_slices(self.map.lock, [*(partial(self.fusion.apply, kf, c, touched) for c in _chunks(matches, 32)),
                                        kf.update_connections])
        self._write_statistics([p for p in touched.values() if not p.bad])

    # ---------------------------------------------------------------- local BA
    def _local_bundle_adjustment(self, kf: KeyFrame) -> None:
        """ORB-SLAM LocalBundleAdjustment: kf and its covisible keyframes free, the other
        keyframes that see their points fixed.  The problem is gathered and the normals of
        the result are computed without the lock; poses, outlier observations, positions
        and normals are applied in one critical section, unless a loop correction or global
        BA moved the map meanwhile (``Map.generation``)."""
        t0 = time.perf_counter()
        gen = self.map.generation
        local = [kf] + [k for k in kf.ordered_covis if not k.bad][: self.cfg.local_ba_max_keyframes - 1]
        local_set = set(local)
        pts: dict[int, MapPoint] = {}
        for k in local:
            for p in k.valid_points():
                pts.setdefault(p.id, p)
        points = list(pts.values())
        free = [k for k in local if not k.is_origin]
        if not points or not free:
            return
        # Fixed: the other keyframes that see the local points, the most observations first
        # (ties in first-seen order), from one pass over the observations.
        table = observation_table(points)
        observers = table[3]
        n_seen = np.bincount(table[1], minlength=len(observers))
        outside = [i for i, k in enumerate(observers) if k not in local_set and not k.bad]
        order = sorted(outside, key=lambda i: -n_seen[i])[: self.cfg.local_ba_max_fixed]
        fixed_list = [observers[i] for i in order] + [k for k in local if k.is_origin]
        if self.mono and len(fixed_list) < 2 and len(free) > 1:
            # Without depth one fixed keyframe leaves the map's scale free (the gauge of a
            # monocular BA), and the solver shrank the whole map towards the fixed keyframe
            # (static_xyz, 300 frames: to 1e-5 of its size within 10 keyframes). The oldest
            # free keyframe is fixed too, as ORB-SLAM3 does when fewer than two are fixed
            # (pLowerKf / pSecondLowerKF in Optimizer::LocalBundleAdjustment).
            oldest = min(free, key=lambda k: k.id)
            free = [k for k in free if k is not oldest]
            fixed_list = fixed_list + [oldest]
        if self.mono and not fixed_list:
            return  # ORB-SLAM3 aborts local BA with no fixed keyframe ("0 fixed KF")
        problem = build_ba_problem(free, fixed_list, points, self.camera, self.pyr, self.cfg.bf, table,
                                   self.depth_prior)
        t1 = time.perf_counter()
        result: BAResult = self.ba.run(problem)
        t2 = time.perf_counter()
        if not result.converged:
            self.stats["local_ba_failed"] += 1
        self.stats["local_ba_links"] += int(problem.link_pose.shape[0])
        kfs = free + fixed_list
        outliers = np.flatnonzero(~result.inlier_obs)
        erased: dict[int, set[KeyFrame]] = {}
        for m in outliers.tolist():
            p, k = points[problem.obs_point[m]], kfs[problem.obs_pose[m]]
            if p.is_observed_by(k):
                erased.setdefault(p.id, set()).add(k)
        # Normals and depth ranges of the map as the result will leave it, computed now
        # without the lock, written with the result.
        poses = result.poses_cw[: len(free)]
        centers = dict(zip(free, -np.einsum("kji,kj->ki", poses[:, :3, :3], poses[:, :3, 3])))
        normals = normals_and_depths(points, self.pyr.scales, result.points_w, centers, erased)
        rows = np.fromiter((p.row for p in points), np.intp, len(points))
        store = self.map.store
        t3 = time.perf_counter()
        with self.map.lock:
            if self.map.generation != gen:
                return
            for k, T in zip(free, poses):
                if not k.bad:
                    k.set_pose(T)
            for m in outliers.tolist():
                p, k = points[problem.obs_point[m]], kfs[problem.obs_pose[m]]
                idx = None if p.bad else p.keypoint_in(k)
                if idx is not None:
                    if k.points[idx] is p:
                        k.points[idx] = None
                    p.erase_observation(k)
            alive = ~store.bad[rows]
            store.pos[rows[alive]] = result.points_w[alive]
            normals.write()
        t4 = time.perf_counter()
        self.stats["local_ba"] += int(result.converged)
        self.stats["local_ba_ms"].append((t4 - t0) * 1e3)
        self._record_ba_split(problem, result, t0, t1, t2, t3, t4)

    def _record_ba_split(self, problem: BAProblem, result: BAResult, t0: float, t1: float,
                         t2: float, t3: float, t4: float) -> None:
        """Where one local BA's time went (ms), for ``benchmarks/backend_timing.py``: gathering
        the problem from the map, the solver's own phases, the hand-over to and from the
        runner (IPC when it runs in the worker process: the runner's wall time minus the
        solver's), the normals of the result (without the lock) and applying it (waiting for
        the lock and holding it)."""
        solve = (t2 - t1) * 1e3
        self.stats["local_ba_split"].append({
            "gather": (t1 - t0) * 1e3, "ipc": max(solve - result.time_ms, 0.0), "solve": solve,
            **{k: v for k, v in result.timings.items()}, "normals": (t3 - t2) * 1e3,
            "apply": (t4 - t3) * 1e3, "total": (t4 - t0) * 1e3,
            "keyframes": int(problem.poses_cw.shape[0]),
            "free": int((~np.asarray(problem.pose_fixed)).sum()),
            "points": int(problem.points_w.shape[0]), "observations": int(problem.obs_pose.size)})

    # ---------------------------------------------------------------- keyframe culling
    def _cull_keyframes(self, kf: KeyFrame) -> None:
        """A keyframe whose close points are 90 % seen by >= 3 other keyframes at the same
        or a finer scale is redundant (ORB-SLAM KeyFrameCulling).

        Decided without the lock on one observation table of the candidates' points (a
        per-point histogram of observation levels), updated as each culled keyframe's
        observations go, exactly as the sequential per-point loops decided; the culled
        keyframes are removed under the lock, one per slice."""
        cands = [c for c in kf.ordered_covis if not c.is_origin and not c.bad and c is not kf]
        if not cands:
            return
        # Each candidate's live points by store row, numbered in first-seen order.
        store = self.map.store
        # Slots and rows from one snapshot each: tracking may clear a slot meanwhile (a culled
        # point), and a second read would give row -1, the newest point's, maybe half-made.
        idx_of, rows_of = zip(*(c.points.good_rows(store) for c in cands))
        all_rows = np.concatenate(rows_of)
        if not all_rows.size:
            return
        uniq, first, inverse = np.unique(all_rows, return_index=True, return_inverse=True)
        order = np.argsort(first, kind="stable")  # unique rows in first-seen order
        rank = np.empty_like(order)
        rank[order] = np.arange(order.size)
        local = rank[inverse]
        points = store.points(uniq[order])
        bounds = np.cumsum([0, *(idx.size for idx in idx_of)])
        slots = [(idx, local[a:b]) for idx, a, b in zip(idx_of, bounds[:-1], bounds[1:])]
        n_lv = self.pyr.n_levels
        ob_row, ob_kf, ob_kp, ob_kfs = observation_table(points)
        _, ob_ur, ob_oct = gather_keypoints(ob_kfs, ob_kf, ob_kp)
        n_pts = len(points)
        # at_most[r, l]: observations of point r at level <= l; n_obs: ORB-SLAM's nObs
        # (observations with depth count twice); n_left: observations (bad when <= 1).
        at_most = np.zeros((n_pts, n_lv), np.intp)
        np.add.at(at_most, (ob_row, np.minimum(ob_oct, n_lv - 1)), 1)
        np.cumsum(at_most, axis=1, out=at_most)
        n_obs = np.bincount(ob_row, weights=np.where(ob_ur >= 0, 2, 1), minlength=n_pts)
        n_left = np.bincount(ob_row, minlength=n_pts)
        gone = np.zeros(n_pts, bool)
        levels = np.arange(n_lv)
        culled = []
        for c, (idx, rows) in zip(cands, slots):
            alive = ~gone[rows]
            depth = c.depth[idx]
            # Monocular: every point counts (ORB-SLAM tests depth only with a depth sensor).
            close = alive if self.mono else alive & (depth > 0) & (depth <= self.th_depth_m)
            n_points = int(close.sum())
            if not n_points:
                continue
            r = rows[close]
            level = c.keypoints.octave[idx[close]]
            # observations by other keyframes at level <= level + 1 (its own is one of them)
            others = at_most[r, np.minimum(level + 1, n_lv - 1)] - 1
            redundant = int(((n_obs[r] > 3) & (others >= 3)).sum())
            if redundant <= 0.9 * n_points:
                continue
            culled.append(c)
            if c.not_erase:  # set_bad_keyframe only marks it: its observations stay
                continue
            r = rows[alive]
            own = c.keypoints.octave[idx[alive]]
            at_most[r] -= levels[None, :] >= own[:, None]
            n_obs[r] -= np.where(c.ur[idx[alive]] >= 0, 2, 1)
            n_left[r] -= 1
            gone[r[n_left[r] <= 1]] = True
        apply_in_slices(self.map.lock, [partial(self.map.set_bad_keyframe, c) for c in culled])
        self.stats["culled_keyframes"] += len(culled)
