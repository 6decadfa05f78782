"""ORB-SLAM loop closing: bag-of-words candidates with covisibility-group consistency,
a similarity RANSAC on matched map points, verification by projection, loop correction
(pose propagation + point fusion), essential-graph optimisation and global BA.

RGB-D fixes the scale, so ORB-SLAM's Sim3 becomes SE(3) there. A monocular map
(``frame_builders.is_monocular``) drifts in scale, so its loops are Sim(3) as in ORB-SLAM:
7-DoF RANSAC refined by ``optimize_similarity`` (Sim3Solver + Optimizer::OptimizeSim3),
the correction propagated as similarities (CorrectLoop's g2oCorrectedSiw) and the essential
graph solved in Sim(3) (``pose_graph.optimize_sim3_pose_graph``); keyframes keep the rigid
part of their similarity and points move with the full similarity. Merges of monocular atlas
maps likewise (ORB-SLAM3 MergeLocal with a Sim3): found with the 7-DoF RANSAC, checked by
reprojection and the keyframes' own points' depths (merge_check.py's monocular mode), the
newer map moved by the similarity.
"""

from __future__ import annotations

import logging
import time
from functools import partial
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
from numpy.typing import NDArray

from semslam.backend.pose_graph import PoseGraphFailed
from semslam.backend.sim3 import optimize_similarity, ransac_similarity, rigid_part, sim3_inverse, sim3_parts
from semslam.backend.worker import BundleAdjustmentRunner
from semslam.config import SystemConfig
from semslam.geometry.camera import PinholeCamera
from semslam.geometry.se3 import invert
from semslam.slam.orb.frame_builders import is_monocular
from semslam.slam.orb.fusion import PointArrays, PointFusion, adopt_matched_points
from semslam.slam.orb.keyframe_worker import KeyframeInbox, KeyframeWorker
from semslam.slam.orb.local_mapping import apply_in_slices, build_ba_problem
from semslam.slam.orb.loop_consistency import Candidate, LoopConsistency
from semslam.slam.orb.atlas import MergeHint
from semslam.slam.orb.merge_check import COVISIBLES, MIN_PROJECTED, PENDING_MISSES, MergeVerifier, PendingMerge, enough
from semslam.slam.orb.map import KeyFrame, Map
from semslam.slam.orb.map_alignment import rescale_frame_records
from semslam.slam.orb.point_store import MapPoint
from semslam.slam.orb.map_batch import normals_and_depths
from semslam.geometry.projection import project
from semslam.slam.orb.search import search_by_bow, search_by_projection

if TYPE_CHECKING:
    from semslam.place.database import KeyframeDatabase
    from semslam.slam.orb.map_merging import MapMerger, MergeResult

#: New keyframes of the map tracking relocalised in on which a merge hint is tried (``_merge_on_hints``).
HINT_KEYFRAMES = 5
#: Matches a monocular loop's Sim(3) must keep after OptimizeSim3 (ORB-SLAM ComputeSim3: 20).
MIN_SIM3_INLIERS = 20

log = logging.getLogger(__name__)


class _Matches(NamedTuple):
    """BoW matches of two keyframes' map points (``ransac_similarity``'s arguments in order)."""

    x1: NDArray[np.float64]  # points in kf's camera frame
    x2: NDArray[np.float64]  # the same in cand's camera frame
    uv1: NDArray[np.float64]
    uv2: NDArray[np.float64]
    inv_s2_1: NDArray[np.float64]
    inv_s2_2: NDArray[np.float64]


def _point_positions(kf: KeyFrame) -> NDArray[np.float64]:
    """World positions of kf's map points, one row per keypoint, NaN where it has none."""
    pos = np.full((len(kf.points), 3), np.nan)
    for i, p in enumerate(kf.points):
        if p is not None and not p.bad:
            pos[i] = p.pos
    return pos


def _neighbourhood_points(kf: KeyFrame) -> list[MapPoint]:
    """The valid map points of kf and its covisible keyframes, each once, in first-seen order."""
    points: dict[int, MapPoint] = {}
    for k in [kf, *kf.covisibles_with_weight(0)]:
        for p in k.valid_points():
            points.setdefault(p.id, p)
    return list(points.values())


class LoopClosing(KeyframeWorker):
    """Detects and corrects loops; runs global BA after each correction."""

    thread_name = "loop-closing"

    def __init__(self, config: SystemConfig, camera: PinholeCamera, slam_map: Map, database: "KeyframeDatabase",
                 ba: BundleAdjustmentRunner, fusion: PointFusion, inbox: KeyframeInbox, mapping: KeyframeInbox,
                 merger: "MapMerger | None" = None) -> None:
        super().__init__(inbox)
        self.cfg = config.slam
        # Monocular: loops are similarities (scale drift); RGB-D / stereo: rigid.
        self.mono = is_monocular(config)
        self.camera = camera
        self.map = slam_map
        self.db = database
        self.ba = ba
        self.fusion = fusion
        # Local mapping's inbox: a loop is corrected only once local mapping is idle.
        self.mapping = mapping
        self.pyr = slam_map.spec.pyramid  # the pyramid of the map's features
        self.rng = np.random.default_rng(config.seed)
        self.last_loop_kf_id = 0
        self.consistency = LoopConsistency(config.slam.loop_consistency)
        # Atlas (ORB-SLAM3): the same place recognition across maps finds merges, and each
        # candidate must pass slam/orb/merge_check.py (spread, depth, agreement of COINCIDENCES
        # keyframes) before maps are welded: a wrong merge offsets a whole map for good.
        self.merger = merger
        self.verifier = MergeVerifier(camera, config.slam.bf, self.pyr.inv_sigma2, self._match_at, self.mono)
        self._hints: list[tuple[MergeHint, int]] = []  # (hint, keyframes it is still tried on)
        # Tracking's (timestamp, reference keyframe, T_c_ref) list (tracker.py wires it): a
        # monocular loop's scale correction rescales the frames recorded relative to keyframes.
        self.frame_records: list[tuple[float, KeyFrame, NDArray[np.float64]]] | None = None
        self._pending: list[PendingMerge] = []  # transforms waiting for more keyframes to agree
        self.loops: list[tuple[int, int]] = []
        self.stats = {"loops": 0, "loops_dropped": 0, "global_ba": 0, "global_ba_failed": 0, "pose_graph_failed": 0,
                      "global_ba_ms": [], "pose_graph_ms": [], "merges": 0}

    def _write_normals(self, points: list[MapPoint]) -> None:
        """Normals and depth ranges of ``points``: computed without the lock, written to the
        point store under it."""
        update = normals_and_depths(points, self.pyr.scales)
        if update.points:
            with self.map.lock:
                update.write()

    # ---------------------------------------------------------------- per keyframe
    def process(self, kf: KeyFrame) -> None:
        if kf.bad:
            return
        if self._confirm_pending(kf) or self._merge_on_hints(kf):
            self.db.add(kf.id, kf.bow)
            return
        found = self._detect_loop(kf)
        merged = found is None and self.merger is not None and self.merger.mergeable() and self._detect_merge(kf)
        self.db.add(kf.id, kf.bow)
        if merged or found is None:
            return
        cand, T12, matched = found
        self._correct_loop(kf, cand, T12, matched)

    def _detect_loop(self, kf: KeyFrame) -> tuple[KeyFrame, NDArray[np.float64], dict[int, MapPoint]] | None:
        """ORB-SLAM2 DetectLoop + ComputeSim3. The map lock is taken only for reads; the
        database query and the consistency bookkeeping run without it, so tracking is
        never held up by detection."""
        from semslam.place.database import detect_loop_candidates

        if kf.id < self.last_loop_kf_id + self.cfg.loop_min_keyframes or len(self.map.keyframes) < self.cfg.loop_min_keyframes:
            return None
        covis_ids, min_score = self._query_bounds(kf)
        cand_ids = detect_loop_candidates(self.db, kf.id, kf.bow, covis_ids, min_score, self._best_covisibles)
        cand_ids = self._in_map(cand_ids, kf.map_id, same=True)  # other maps: merges, not loops
        log.debug("kf %d: min_score %.3f, loop candidates %s", kf.id, min_score, cand_ids)
        candidates = self._candidate_groups(cand_ids)
        accepted = self.consistency.update([c for c, _ in candidates])
        log.debug("kf %d: consistent candidates %s", kf.id, accepted)
        by_id = {c.kf_id: k for c, k in candidates}
        for cid in accepted:
            res = self._compute_transform(kf, by_id[cid])
            if res is not None:
                return res
        return None

    def _in_map(self, kf_ids: list[int], map_id: int, same: bool) -> list[int]:
        """The ids whose keyframe is (``same``) or is not in atlas map ``map_id``."""
        with self.map.lock:
            kfs = self.map.keyframes
            return [i for i in kf_ids if i in kfs and (kfs[i].map_id == map_id) == same]

    def _detect_merge(self, kf: KeyFrame) -> bool:
        """ORB-SLAM3 DetectCommonRegionsFromBoW for merges: the loop query, keeping the
        candidates of other maps (the 3 best groups, as its DetectNBestCandidates), the same
        SE(3) RANSAC (monocular: Sim(3)) and verification as a loop, then ``_check_merge``;
        True if merged."""
        from semslam.place.database import detect_loop_candidates

        covis_ids, min_score = self._query_bounds(kf)
        if self.mono:
            # No minimum score, as ORB-SLAM3's DetectNBestCandidates: a young monocular map's
            # covisibles are its initial pair, views so alike that no keyframe of another map
            # reaches their score (threaded blackout renders: 1 of 6 merged). The Sim(3) and
            # the merge checks stay as strict.
            min_score = 0.0
        cand_ids = detect_loop_candidates(self.db, kf.id, kf.bow, covis_ids, min_score, self._best_covisibles)
        cand_ids = self._in_map(cand_ids, kf.map_id, same=False)
        log.debug("kf %d: merge candidates %s", kf.id, cand_ids)
        assert self.merger is not None
        with self.map.lock:
            candidates = [self.map.keyframes[i] for i in cand_ids[:3] if i in self.map.keyframes]
        for cand in candidates:
            res = self._compute_transform(kf, cand)
            outcome = self._check_merge(kf, *res) if res is not None else None
            if outcome is not None:
                return outcome == "merged"
        return False

    def _merge_on_hints(self, kf: KeyFrame) -> bool:
        """Tracking left a map for another by relocalising (``Atlas.activate``): try to merge
        the left map's last keyframes with keyframes of the map tracking went on in: the
        relocalisation keyframe and its covisibles, then each new keyframe there for the next
        ``HINT_KEYFRAMES`` (the camera usually keeps moving back towards the left map's last
        view). Each pair gets the same SE(3) RANSAC and verification as a merge found by BoW,
        or, where BoW finds too little, the motion model's bridge across the gap verified by
        projection; then the same checks as any merge (``_check_merge``). The bridge is only
        a place to look: a constant-velocity guess across a gap can be far off, and matching
        by projection near a wrong pose on a repeated texture can agree with it, so it is
        welded only if it passes them all.

        Why: the left map gets no new keyframe, so nothing of it would query the database
        again; in threaded runs tracking often loses a young map (its local mapping still
        behind) on the way back to an old place and relocalises there, leaving the young
        map's frames in their own world for good. A frame tracked in one map and, a moment
        later, relocalised in another says where to look."""
        if self.merger is None:
            return False
        atlas = self.merger.atlas
        with self.map.lock:
            self._hints += [(h, HINT_KEYFRAMES) for h in atlas.take_merge_hints()]
            attempts: list[tuple[list[KeyFrame], list[KeyFrame], NDArray[np.float64] | None]] = []
            kept: list[tuple[MergeHint, int]] = []
            for hint, tries in self._hints:
                left, there = atlas.resolve(hint.left), atlas.resolve(hint.reloc_kf.map_id)
                if left == there:
                    continue  # merged meanwhile
                if atlas.resolve(kf.map_id) != there:
                    kept.append((hint, tries))  # a keyframe from before the relocalisation
                    continue
                recent = [k for k in atlas.keyframes_of(left) if not k.bad][-3:][::-1]
                first = tries == HINT_KEYFRAMES
                near = [kf, hint.reloc_kf, *hint.reloc_kf.best_covisibles(4)] if first else [kf]
                # The bridge is rigid: it has no scale to give a monocular map.
                attempts.append((recent, [k for k in dict.fromkeys(near) if not k.bad],
                                 None if self.mono else hint.bridge))
                if tries > 1:
                    kept.append((hint, tries - 1))
            self._hints = kept
        for recent, near, bridge in attempts:
            for cand in near:
                for left_kf in recent:
                    res, source = self._compute_transform(left_kf, cand), "hint"
                    if res is None and bridge is not None:
                        # left_kf in cand's world by the motion model's bridge, checked as a loop is.
                        with self.map.lock:
                            T12 = left_kf.T_cw @ invert(bridge) @ invert(cand.T_cw)
                        res, source = self._verify_by_projection(left_kf, cand, T12), "bridge"
                    outcome = self._check_merge(left_kf, *res, source=source) if res is not None else None
                    if outcome is not None:  # merged, or pending for later keyframes to confirm
                        log.debug("merge hint: kf %d (left map) vs %d: %s", left_kf.id, cand.id, outcome)
                        self._hints = []
                        return outcome == "merged"
        return False

    # ---------------------------------------------------------------- merge checks
    def _match_at(self, kf: KeyFrame, cand: KeyFrame, T12: NDArray[np.float64]) -> dict[int, MapPoint] | None:
        """cand's neighbourhood projected into kf at ``T12`` (kf <- cand): the matches, or
        None if fewer than a confirming keyframe needs (the merge checker's matcher; the
        checker counts the inliers of its refit against the bars again)."""
        res = self._verify_by_projection(kf, cand, T12, min_matches=MIN_PROJECTED)
        return None if res is None else res[2]

    def _check_merge(self, kf: KeyFrame, cand: KeyFrame, T12: NDArray[np.float64], matched: dict[int, MapPoint],
                     source: str = "bow") -> str | None:
        """Check a candidate merge (``T12``: kf <- cand) and merge the maps if it passes and
        enough keyframes agree (``merge_check.enough``): "merged"; one that passes with
        fewer waits in ``_pending`` for later keyframes: "pending"; None if it failed.
        ``source``: what found the candidate ("bow", "hint": the relocalisation hint's
        RANSAC, "bridge": its motion-model bridge), recorded in stats.json's merge_checks."""
        assert self.merger is not None
        with self.map.lock:
            covis = [k for k in kf.best_covisibles(COVISIBLES) if not k.bad and k.map_id == kf.map_id]
            cand_covis = [k for k in cand.best_covisibles(COVISIBLES) if not k.bad and k.map_id == cand.map_id]
        v = self.verifier.verify(kf, cand, T12, matched, covis, cand_covis)
        atlas = self.merger.atlas
        if not v.ok:
            atlas.merge_checked(kf, cand, T12, str(v.reason), source=source)
            return None
        assert v.S is not None and v.T12 is not None and v.points is not None
        same = [p for p in self._pending if {p.kf.map_id, p.cand.map_id} == {kf.map_id, cand.map_id}]
        p = next((p for p in same if p.kf.map_id == kf.map_id and p.agrees(v.S)), None)
        agree = v.confirmers | (p.confirmers if p is not None else set())  # a transform found again
        later = p is not None and (p.later or kf.id not in {i for _, i in p.confirmers})
        self._pending = [q for q in self._pending if q not in same]  # this check supersedes them
        if not enough(agree, later):
            atlas.merge_checked(kf, cand, v.T12, "pending", len(agree), source)
            self._pending.append(PendingMerge(kf, cand, v.S, v.points, agree, later, mono=self.mono))
            return "pending"
        atlas.merge_checked(kf, cand, v.T12, "merged", len(agree), source)
        self._merge_maps(kf, cand, v.T12, v.matched)
        return "merged"

    def _confirm_pending(self, kf: KeyFrame) -> bool:
        """A new keyframe of either map of a pending transform tries to confirm it (ORB-SLAM3
        DetectAndReffineSim3FromLastKF); enough confirmations merge the maps, ``PENDING_MISSES``
        failures in a row drop it. True if the maps were merged."""
        if self.merger is None or not self._pending:
            return False
        atlas = self.merger.atlas
        keep: list[PendingMerge] = []
        for n, p in enumerate(self._pending):
            with self.map.lock:
                a, b, here = (atlas.resolve(p.kf.map_id), atlas.resolve(p.cand.map_id), atlas.resolve(kf.map_id))
                gone = p.kf.bad or p.cand.bad
            if a == b or gone:
                continue
            if here not in (a, b):
                keep.append(p)
                continue
            other, S = (p.cand, p.S) if here == a else (p.kf, self.verifier.inverse(p.S))
            fit = self.verifier.confirm(kf, other, S)
            if fit is None:
                p.misses += 1
                if p.misses < PENDING_MISSES:
                    keep.append(p)
                else:
                    atlas.merge_checked(p.kf, p.cand, p.kf.T_cw @ p.S @ p.cand.T_wc, "not_confirmed", p.coincidences, "pending")
                continue
            p.confirmers.add((kf.map_id, kf.id))
            p.later = True
            p.misses = 0
            T12 = self.verifier.relative(fit, other, S)
            if not p.enough:
                atlas.merge_checked(kf, other, T12, "pending", p.coincidences, "pending")
                keep.append(p)
                continue
            atlas.merge_checked(kf, other, T12, "merged", p.coincidences, "pending")
            self._pending = keep + self._pending[n + 1:]  # those of these two maps are dropped later
            self._merge_maps(kf, other, T12, fit.matched)
            return True
        self._pending = keep
        return False

    def _culled_meanwhile(self, kf: KeyFrame, cand: KeyFrame, what: str) -> bool:
        """Whether local mapping culled one of the pair while the loop or merge was being
        detected (ORB-SLAM2 protects them from DetectLoop on; here they are protected from
        the correction on; call with local mapping paused). Then nothing anchors the
        correction: it is dropped and counted, and the place is found again from a later
        keyframe."""
        with self.map.lock:
            gone = cand if cand.bad else kf if kf.bad else None
        if gone is None:
            return False
        log.info("%s %d <-> %d dropped: keyframe %d was culled during detection", what, kf.id, cand.id, gone.id)
        self.stats["loops_dropped"] += 1
        return True

    def _merge_maps(self, kf: KeyFrame, cand: KeyFrame, T12: NDArray[np.float64], matched: dict[int, MapPoint]) -> None:
        """Merge kf's map with cand's (``slam/orb/map_merging.py``) with local mapping paused, then
        the essential graph and global BA over the merged map, as after a loop."""
        assert self.merger is not None
        t0 = time.perf_counter()
        if not self.mapping.wait_idle(timeout=60.0):
            log.warning("local mapping still busy after 60 s; merging maps anyway")
        with self.mapping.paused():
            if self._culled_meanwhile(kf, cand, "merge"):
                return
            records = self.frame_records
            rescale = (partial(rescale_frame_records, records) if self.mono and records is not None else None)
            res = self.merger.merge(kf, cand, T12, matched, mono=self.mono, rescale=rescale)
            if self.mono:
                self._after_similarity_merge(res)
            # The merged map moved as a whole: measurements are its poses now (nothing "old").
            self._optimize_essential_graph(res.anchor, {}, {}, res.new_links)
        self.consistency.reset()
        self.last_loop_kf_id = kf.id
        self.stats["merges"] += 1
        self.stats["pose_graph_ms"].append((time.perf_counter() - t0) * 1e3)
        if self.cfg.global_ba:
            self.global_bundle_adjustment(res.kept)

    def _after_similarity_merge(self, res: "MergeResult") -> None:
        """A monocular merge scaled the moved map by ``res.scale`` (the frames recorded relative
        to its keyframes were rescaled with the move, ``rescale_frame_records``): the points'
        normals and scale-invariance distances are recomputed, as after a Sim(3) loop."""
        with self.map.lock:
            points = [p for k in self.map.all_keyframes() if k.id in res.moved_ids for p in k.valid_points()]
        self._write_normals(list({p.id: p for p in points}.values()))

    def _query_bounds(self, kf: KeyFrame) -> tuple[set[int], float]:
        """The keyframes a loop must not be (kf's covisibles) and the lowest BoW score among
        them, which a loop candidate must reach (ORB-SLAM2's minScore)."""
        from semslam.place.vocabulary import l1_score

        with self.map.lock:
            covis = kf.covisibles_with_weight(0)
        min_score = min((l1_score(kf.bow, c.bow) for c in covis if c.bow is not None), default=0.0)
        return {c.id for c in covis}, min_score

    def _best_covisibles(self, kf_id: int, n: int) -> list[int]:
        """The database query's view of the covisibility graph, read under the lock."""
        with self.map.lock:
            other = self.map.keyframes.get(kf_id)
            return [] if other is None else [c.id for c in other.best_covisibles(n)]

    def _candidate_groups(self, cand_ids: list[int]) -> list[tuple[Candidate, KeyFrame]]:
        """Each candidate still in the map with its covisibility group (read under the lock)."""
        with self.map.lock:
            found = [self.map.keyframes[i] for i in cand_ids if i in self.map.keyframes]
            return [(Candidate.of(c.id, (k.id for k in c.covisibles_with_weight(0))), c) for c in found]

    def _bow_matches(self, kf: KeyFrame, cand: KeyFrame) -> _Matches | None:
        """BoW matches between the map points of kf and cand, in each one's camera frame,
        with their keypoints and levels' inverse sigma^2; None under 20 (ORB-SLAM ComputeSim3)."""
        with self.map.lock:
            pos1, T1 = _point_positions(kf), kf.T_cw.copy()
            pos2, T2 = _point_positions(cand), cand.T_cw.copy()
        valid1, valid2 = ~np.isnan(pos1[:, 0]), ~np.isnan(pos2[:, 0])
        i1, i2 = search_by_bow(kf.featvec, kf.keypoints.descriptors, cand.featvec, cand.keypoints.descriptors,
                               valid1, valid2, self.map.matcher, self.map.spec.th_low, ratio=0.75)
        if len(i1) < 20:
            log.debug("kf %d vs %d: %d BoW matches", kf.id, cand.id, len(i1))
            return None
        x1 = pos1[i1] @ T1[:3, :3].T + T1[:3, 3]
        x2 = pos2[i2] @ T2[:3, :3].T + T2[:3, 3]
        return _Matches(x1, x2, kf.xy[i1], cand.xy[i2], self.pyr.inv_sigma2[kf.keypoints.octave[i1]],
                        self.pyr.inv_sigma2[cand.keypoints.octave[i2]])

    def _compute_transform(self, kf: KeyFrame, cand: KeyFrame
                           ) -> tuple[KeyFrame, NDArray[np.float64], dict[int, MapPoint]] | None:
        """kf <- cand from BoW matches, verified by projecting cand's neighbourhood into kf.
        RGB-D: an SE(3) RANSAC. Monocular: ORB-SLAM ComputeSim3, a 7-DoF RANSAC (Sim3Solver)
        refined on the reprojection errors of all matches (OptimizeSim3, which also drops the
        outliers; at least ``MIN_SIM3_INLIERS`` must stay), the scale in the rotation block
        (ORB-SLAM also searches more matches with the Sim(3) before OptimizeSim3,
        SearchBySim3: not done here)."""
        m = self._bow_matches(kf, cand)
        if m is None:
            return None
        T12, inl = ransac_similarity(*m, self.camera, self.rng, with_scale=self.mono)
        if T12 is None:
            log.debug("kf %d vs %d: %s RANSAC failed (%d matches, best %d inliers)", kf.id, cand.id,
                      "Sim3" if self.mono else "SE3", len(m.x1), int(inl.sum()))
            return None
        n_inliers = int(inl.sum())
        if self.mono:
            fit = optimize_similarity(T12, *m, self.camera, fix_scale=False)
            if fit.n_inliers < MIN_SIM3_INLIERS:
                log.debug("kf %d vs %d: %d inliers after OptimizeSim3", kf.id, cand.id, fit.n_inliers)
                return None
            T12, n_inliers = fit.S12, fit.n_inliers
        return self._verify_by_projection(kf, cand, T12, n_inliers)

    def _inverse(self, S: NDArray[np.float64]) -> NDArray[np.float64]:
        """The inverse of a keyframe transform: a similarity's in a monocular map, else a
        rigid pose's (``invert``, as the RGB-D path always computed it)."""
        return sim3_inverse(S) if self.mono else invert(S)

    def _pose_of(self, S_cw: NDArray[np.float64]) -> NDArray[np.float64]:
        """The camera pose a keyframe keeps of a corrected ``S_cw``: its rigid part in a
        monocular map (``rigid_part``); RGB-D corrections are rigid already."""
        return rigid_part(S_cw) if self.mono else S_cw

    def _verify_by_projection(self, kf: KeyFrame, cand: KeyFrame, T12: NDArray[np.float64], n_inliers: int = 0,
                              min_matches: int | None = None
                              ) -> tuple[KeyFrame, NDArray[np.float64], dict[int, MapPoint]] | None:
        """Project cand's neighbourhood into kf with ``T12`` (kf <- cand); enough matches
        (with ``n_inliers`` already found; ``slam.loop_min_matches`` unless ``min_matches``)
        confirm it. Returns kf keypoint -> cand-side point."""
        with self.map.lock:
            T_cw_corr = T12 @ cand.T_cw
            pts = _neighbourhood_points(cand)
            if not pts:  # e.g. a keyframe whose points were all culled or fused away
                return None
            pos = np.array([p.pos for p in pts])
            max_dist = np.array([p.max_dist for p in pts])
            descriptors = [p.descriptor for p in pts]
        uv, z = project(T_cw_corr, pos, self.camera.fx, self.camera.fy, self.camera.cx, self.camera.cy)
        inside = (z > 0) & self.camera.in_image(uv)
        sel = np.nonzero(inside)[0]
        if len(sel) == 0:
            return None
        dist = np.linalg.norm(pos[sel] - self._inverse(T_cw_corr)[:3, 3], axis=1)  # in cand's world
        max_d = max_dist[sel]
        level = self.pyr.predict_level(max_d, dist)
        qi, ti = search_by_projection(uv[sel], 10.0 * self.pyr.scales[level], level - 1, level + 1,
                                      np.stack([descriptors[s] for s in sel]), kf.xy, kf.keypoints.octave,
                                      kf.keypoints.descriptors, np.ones(len(kf.points), bool),
                                      kf.tree(), self.map.matcher, self.map.spec.th_high, 0.9)
        n_matched = n_inliers + len(qi)
        log.debug("kf %d vs %d: %d SE3 inliers, %d projected matches", kf.id, cand.id, n_inliers, len(qi))
        need = self.cfg.loop_min_matches if min_matches is None else min_matches
        if len(qi) < need and n_matched < need:
            return None
        return cand, T12, {int(t): pts[sel[q]] for q, t in zip(qi, ti)}

    # ---------------------------------------------------------------- correction
    def _correct_loop(self, kf: KeyFrame, cand: KeyFrame, T12: NDArray[np.float64], matched: dict[int, MapPoint]) -> None:
        """ORB-SLAM CorrectLoop with local mapping paused (RequestStop): the map's structure
        then has no other writer, so everything is read and computed without the lock and
        written in short critical sections; the essential graph is solved in the BA worker
        process (GTSAM holds the GIL)."""
        t0 = time.perf_counter()
        if not self.mapping.wait_idle(timeout=60.0):
            log.warning("local mapping still busy after 60 s; correcting the loop anyway")
        with self.mapping.paused() as stopped:
            if not stopped:
                log.warning("local mapping did not pause within 60 s; correcting the loop anyway")
            if self._culled_meanwhile(kf, cand, "loop"):
                return
            self._correct_loop_paused(kf, cand, T12, matched)
        self.loops.append((kf.id, cand.id))
        self.stats["loops"] += 1
        self.stats["pose_graph_ms"].append((time.perf_counter() - t0) * 1e3)
        log.info("loop closed: keyframe %d <-> %d", kf.id, cand.id)
        if self.cfg.global_ba:
            self.global_bundle_adjustment(kf.map_id)

    def _correct_loop_paused(self, kf: KeyFrame, cand: KeyFrame, T12: NDArray[np.float64],
                             matched: dict[int, MapPoint]) -> None:
        with self.map.lock:
            self.map.generation += 1
            kf.update_connections()
            all_kfs = self.map.all_keyframes()
        connected = [kf, *kf.covisibles_with_weight(0)]
        T_wc_old = kf.T_wc
        T_cw_corr = T12 @ cand.T_cw
        old = {k: k.T_cw.copy() for k in all_kfs}
        corrected = {kf: T_cw_corr}
        for k in connected[1:]:
            corrected[k] = (k.T_cw @ T_wc_old) @ T_cw_corr
        # Points of the connected keyframes move with the first of them that sees them.
        moved: dict[int, MapPoint] = {}
        new_pos, new_ref = [], []
        for k in connected:
            pts = [p for p in k.valid_points() if p.id not in moved]
            if not pts:
                continue
            delta = self._inverse(corrected[k]) @ old[k]  # Sim(3): the points scale with the loop
            new_pos.append(np.array([p.pos for p in pts]) @ delta[:3, :3].T + delta[:3, 3])
            for p in pts:
                moved[p.id] = p
                new_ref.append(k if p.ref_kf not in corrected else p.ref_kf)
        points = list(moved.values())
        positions = np.concatenate(new_pos) if new_pos else np.zeros((0, 3))
        rows = np.fromiter((p.row for p in points), np.intp, len(points))
        with self.map.lock:
            self.map.store.pos[rows] = positions
            for p, r in zip(points, new_ref):
                p.ref_kf = r
            for k in connected:
                k.set_pose(self._pose_of(corrected[k]))
        self._write_normals(points)
        # Fuse: the loop's points replace the current keyframe's duplicates, then are
        # searched in every connected keyframe (planned without the lock).
        with self.map.lock:
            adopt_matched_points(self.map, kf, matched)
        loop_pts = list({p.id: p for k in [cand, *cand.covisibles_with_weight(0)] for p in k.valid_points()}.values())
        src = PointArrays.of(loop_pts)
        plans = [(k, self.fusion.plan(k, src, th=4.0)) for k in connected]
        apply_in_slices(self.map.lock, [partial(self.fusion.apply, k, m) for k, m in plans if m])
        before = {k: set(k.covis) for k in connected}
        apply_in_slices(self.map.lock, [k.update_connections for k in connected])
        new_links = {k: set(k.covis) - before[k] - set(connected) for k in connected}
        with self.map.lock:
            kf.loop_edges.add(cand)
            cand.loop_edges.add(kf)
            cand.not_erase = True
            kf.not_erase = True
        self._optimize_essential_graph(cand, old, corrected, new_links)
        with self.map.lock:
            self.map.n_loops += 1
        self.last_loop_kf_id = kf.id

    def _optimize_essential_graph(self, loop_kf: KeyFrame, old: dict[KeyFrame, NDArray[np.float64]],
                                  corrected: dict[KeyFrame, NDArray[np.float64]],
                                  new_links: dict[KeyFrame, set[KeyFrame]]) -> None:
        """Pose graph over spanning tree, loop and strong covisibility edges (weight >= 100),
        with measurements from the poses before correction, new loop links from after it.
        Built without the lock (local mapping is paused), solved in the BA worker process;
        the poses and the points moved with their reference keyframes are written in one
        critical section."""
        with self.map.lock:  # one atlas map: the others have gauges of their own
            kfs = [k for k in self.map.all_keyframes() if k.map_id == loop_kf.map_id]
        index = {k: i for i, k in enumerate(kfs)}
        # Reference (measurement) poses: non-corrected ones where a correction happened.
        ref_wc = {k: invert(old.get(k, k.T_cw)) for k in kfs}
        init_wc = np.stack([self._inverse(corrected.get(k, k.T_cw)) for k in kfs])
        edges, meas = [], []
        seen: set[tuple[int, int]] = set()

        def add(a: KeyFrame, b: KeyFrame, T_ab: NDArray[np.float64]) -> None:
            i, j = index.get(a), index.get(b)
            if i is None or j is None or i == j:
                return
            key = (min(i, j), max(i, j))
            if key in seen:
                return
            seen.add(key)
            edges.append((i, j))
            meas.append(T_ab)

        for k, links in new_links.items():
            for other in links:
                Twk, Twl = self._inverse(corrected.get(k, k.T_cw)), self._inverse(corrected.get(other, other.T_cw))
                add(k, other, self._inverse(Twk) @ Twl)
        for k in kfs:
            if k.parent is not None and not k.parent.bad:
                add(k, k.parent, invert(ref_wc[k]) @ ref_wc[k.parent])
            for other in k.loop_edges:
                if other is loop_kf and k in corrected:  # the new loop edge: measured after correction
                    add(k, other, corrected[k] @ invert(other.T_cw))
                else:
                    add(k, other, invert(ref_wc[k]) @ ref_wc[other])
            for other in k.covisibles_with_weight(100):
                add(k, other, invert(ref_wc[k]) @ ref_wc[other])
        if not edges:
            return
        weights = np.ones(len(edges))
        fixed = [index[loop_kf]] + ([index[kfs[0]]] if kfs[0] is not loop_kf else [])
        # Monocular: Sim(3) nodes, so the loop's scale correction spreads along the graph
        # (ORB-SLAM OptimizeEssentialGraph with bFixScale false).
        solve = self.ba.run_sim3_pose_graph if self.mono else self.ba.run_pose_graph
        try:
            poses_wc = solve(init_wc, np.asarray(edges, np.intp), np.stack(meas), weights, fixed)
        except PoseGraphFailed as exc:  # keep the loop-corrected poses rather than stop loop closing
            log.warning("essential graph optimisation failed (%s); loop-corrected poses kept", exc)
            self.stats["pose_graph_failed"] += 1
            poses_wc = init_wc
        # Move each point with its reference keyframe (from its pre-graph pose).
        pts: list[MapPoint] = []
        new_pos = []
        for k, T_wc_new in zip(kfs, poses_wc):
            own = [p for p in k.valid_points() if p.ref_kf is k]
            if own:
                delta = T_wc_new @ self._inverse(init_wc[index[k]])
                new_pos.append(np.array([p.pos for p in own]) @ delta[:3, :3].T + delta[:3, 3])
                pts.extend(own)
        positions = np.concatenate(new_pos) if new_pos else np.zeros((0, 3))
        rows = np.fromiter((p.row for p in pts), np.intp, len(pts))
        with self.map.lock:
            self.map.store.pos[rows] = positions
            for k, T_wc_new in zip(kfs, poses_wc):
                k.set_pose(self._pose_of(self._inverse(T_wc_new)))
            if self.mono and self.frame_records is not None:
                # S_wc starts from each keyframe's rigid pose before the loop (scale 1, or the
                # loop's correction): its scale is how much the map around it grew.
                grown = {k: sim3_parts(S)[2] for k, S in zip(kfs, poses_wc)}
                n = rescale_frame_records(self.frame_records, grown)
                log.info("Sim(3) loop: keyframe scales %.3f..%.3f, %d frame records rescaled",
                         min(grown.values()), max(grown.values()), n)
            all_points = list(self.map.points.values())
        self._write_normals(all_points)

    def global_bundle_adjustment(self, map_id: int | None = None) -> None:
        """Full BA over all keyframes and points (first keyframe fixed), solved without the
        lock while local mapping goes on (the Schur solver releases the GIL); the problem is
        gathered and the result applied with local mapping paused, the result written in
        one critical section.  Keyframes and points added while it ran are moved with their
        parent / reference keyframe. ``map_id``: only that atlas map (its origin fixed)."""
        t0 = time.perf_counter()
        with self.mapping.paused():
            with self.map.lock:
                gen = self.map.generation
                kfs = [k for k in self.map.all_keyframes() if map_id is None or k.map_id == map_id]
                candidates = list(self.map.points.values())
            if len(kfs) < 2:
                return
            points = [p for p in candidates if not p.bad and p.n_observers
                      and (map_id is None or p.store.first_observer(p.row).map_id == map_id)]
            rows = np.fromiter((p.row for p in points), np.intp, len(points))
            # Monocular: the two oldest keyframes fixed, not just the origin: with one, the
            # map's free scale drifted in the BA (room_loop render: the map shrank to 0.57 of
            # itself, and every frame recorded relative to a keyframe was off by that), as
            # local mapping found for its BA (ORB-SLAM3's pSecondLowerKF there).
            n_fixed = 2 if self.mono else 1
            free, fixed = kfs[n_fixed:], kfs[:n_fixed]
            problem = build_ba_problem(free, fixed, points, self.camera, self.pyr, self.cfg.bf)
            before = {k: k.T_cw.copy() for k in kfs}
        result = self.ba.run(problem, iterations=(10, 0), remove_outliers=False)  # ORB-SLAM GBA: 10 iterations
        if not result.converged:
            self.stats["global_ba_failed"] += 1
        with self.mapping.paused():
            with self.map.lock:
                if self.map.generation != gen:
                    log.info("global BA discarded: map corrected meanwhile")
                    return
                self.map.generation += 1
                after = {k: T for k, T in zip(free, result.poses_cw[: len(free)])}
                for k in fixed:
                    after[k] = k.T_cw
                store = self.map.store
                alive = ~store.bad[rows]
                store.pos[rows[alive]] = result.points_w[alive]
                # Keyframes created during BA: follow their parent's correction.
                for k in self.map.all_keyframes():
                    if k in after:
                        k.set_pose(after[k])
                        continue
                    par = k.parent
                    while par is not None and par not in after:
                        par = par.parent
                    if par is not None:
                        delta = invert(after[par]) @ before[par]  # T_w_new <- T_w_old for the parent
                        k.set_pose(k.T_cw @ invert(delta))
                # Points created during BA: follow their reference keyframe.
                in_ba = {p.id for p in points}
                for p in list(self.map.points.values()):
                    if p.id not in in_ba and not p.bad and p.ref_kf in before and p.ref_kf in after:
                        delta = invert(after[p.ref_kf]) @ before[p.ref_kf]
                        p.pos = delta[:3, :3] @ p.pos + delta[:3, 3]
                all_points = list(self.map.points.values())
            self._write_normals(all_points)
        self.stats["global_ba"] += int(result.converged)
        self.stats["global_ba_ms"].append((time.perf_counter() - t0) * 1e3)
