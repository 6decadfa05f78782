"""Merging two atlas maps that saw the same place (ORB-SLAM3 LoopClosing::MergeLocal, RGB-D).

Loop closing finds the place (bag-of-words candidates in another map, SE(3) RANSAC and
verification by projection, as for a loop), slam/orb/merge_check.py verifies it (spread,
depths, several keyframes agreeing) and loop closing hands the result here; afterwards it runs the essential graph and global BA over the
merged map, as after a loop.

RGB-D observes scale, so the merge is one rigid SE(3). Monocular maps each have their own
scale, so their merge is a similarity, as ORB-SLAM3's MergeLocal solves a Sim3 for them: the
moved map's points move with the full similarity, its keyframes keep the rigid part
(``rigid_part``, as a Sim(3) loop correction does) and loop closing rescales the frames
recorded relative to them and runs the essential graph in Sim(3). Deviation from ORB-SLAM3: the whole newer map is moved by that transform
at once, in one critical section, instead of the welding window first and the rest after a
welding BA; the window is then welded (duplicate points fused, as loop closing does) and
global BA spreads the residual over both maps. The older map keeps its frame, so the first
map's frame stays the trajectory's frame.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial

import numpy as np
from numpy.typing import NDArray

from semslam.backend.sim3 import rigid_part, sim3_inverse, sim3_parts
from semslam.geometry.camera import PinholeCamera
from semslam.geometry.se3 import invert
from semslam.slam.orb.atlas import Atlas
from semslam.slam.orb.fusion import PointArrays, PointFusion, adopt_matched_points
from semslam.slam.orb.local_mapping import apply_in_slices
from semslam.slam.orb.map import KeyFrame, Map, good_point_rows
from semslam.slam.orb.point_store import MapPoint

log = logging.getLogger(__name__)


@dataclass
class MergeResult:
    """What loop closing needs for the essential graph after a merge."""

    kept: int  # the map that kept its frame (the older one)
    merged: int  # the map moved into it
    anchor: KeyFrame  # the keyframe of the kept map at the weld (fixed in the essential graph)
    new_links: dict[KeyFrame, set[KeyFrame]]  # covisibility links across the weld
    scale: float = 1.0  # the similarity's scale (kept map's units per moved map's unit)
    moved_ids: frozenset[int] = frozenset()  # the moved map's keyframes (ids)


def merge_transform(kf: KeyFrame, cand: KeyFrame, T12: NDArray[np.float64], move_kf_map: bool) -> NDArray[np.float64]:
    """``S`` (kept world <- moved world) from ``T12`` (kf camera <- cand camera).

    Moving kf's map: kf's pose in cand's world is ``T12 @ cand.T_cw``, so a point ``p`` of
    kf's world is ``inv(T12 @ cand.T_cw) @ kf.T_cw @ p`` there. Moving cand's map: the
    same with the roles swapped (``inv(T12)``)."""
    if move_kf_map:
        return invert(T12 @ cand.T_cw) @ kf.T_cw
    return invert(invert(T12) @ kf.T_cw) @ cand.T_cw


def merge_similarity(kf: KeyFrame, cand: KeyFrame, S12: NDArray[np.float64], move_kf_map: bool) -> NDArray[np.float64]:
    """Monocular ``merge_transform``: ``S12`` (kf camera <- cand camera) is a similarity, so
    is ``S`` (kept world <- moved world)."""
    if move_kf_map:
        return sim3_inverse(S12 @ cand.T_cw) @ kf.T_cw
    return sim3_inverse(sim3_inverse(S12) @ kf.T_cw) @ cand.T_cw


def _path_to_root(kf: KeyFrame) -> list[KeyFrame]:
    """kf and its ancestors up to its tree's root (stopping at a repeat, should the parent
    links ever form a cycle)."""
    path: list[KeyFrame] = []
    seen: set[int] = set()
    node: KeyFrame | None = kf
    while node is not None and id(node) not in seen:
        seen.add(id(node))
        path.append(node)
        node = node.parent
    return path


def _reroot(child_kf: KeyFrame, new_parent: KeyFrame) -> None:
    """Hang ``child_kf``'s spanning tree under ``new_parent``: the parent links from
    child_kf up to its map's root are reversed (ORB-SLAM3 MergeLocal), so the merged map
    has one tree and the old root becomes an ordinary keyframe. If the two are already in
    one tree (a parent link across the maps), nothing changes: reversing the path would
    close a cycle (a threaded default run on a held-out room_path render hung here)."""
    path = _path_to_root(child_kf)
    if not set(path).isdisjoint(_path_to_root(new_parent)):
        log.warning("keyframes %d and %d already share a spanning tree; not re-rooted", child_kf.id, new_parent.id)
        return
    old_parent = child_kf.parent
    if old_parent is not None:
        old_parent.children.discard(child_kf)
    child_kf.parent = new_parent
    new_parent.children.add(child_kf)
    for below, node in zip(path, path[1:]):
        up = node.parent
        if up is not None:
            up.children.discard(node)
        node.children.discard(below)
        node.parent = below
        below.children.add(node)


def _window(kf: KeyFrame, n: int = 15) -> list[KeyFrame]:
    """kf and its best covisibles (ORB-SLAM3's welding window, numTemporalKFs = 15)."""
    return [kf, *kf.best_covisibles(n - 1)]


class MapMerger:
    """Moves one atlas map into another's frame and welds them; counts merges."""

    def __init__(self, slam_map: Map, atlas: Atlas, fusion: PointFusion, camera: PinholeCamera, bf: float) -> None:
        self.map = slam_map
        self.atlas = atlas
        self.fusion = fusion
        self.camera = camera
        self.bf = bf

    def mergeable(self) -> bool:
        """More than one map to merge (place recognition across maps is worth a query)."""
        return self.atlas.enabled and len(self.atlas.live_maps()) > 1

    def merge(self, kf: KeyFrame, cand: KeyFrame, T12: NDArray[np.float64],
              matched: dict[int, MapPoint], mono: bool = False,
              rescale: Callable[[dict[KeyFrame, float]], object] | None = None) -> MergeResult:
        """Merge kf's map and cand's map (verified by loop closing and slam/orb/merge_check.py:
        ``T12`` kf <- cand, and ``matched`` kf keypoint -> cand-side point). Local mapping is
        paused by the caller. ``mono``: ``T12`` is a similarity (monocular maps); ``rescale``
        gets the moved keyframes' scale in the same critical section as the move, so that
        tracking's records relative to them change units together with them."""
        move_kf_map = kf.map_id > cand.map_id  # the newer map moves into the older one's frame
        kept, moved = (cand.map_id, kf.map_id) if move_kf_map else (kf.map_id, cand.map_id)
        S = merge_similarity(kf, cand, T12, move_kf_map) if mono else merge_transform(kf, cand, T12, move_kf_map)
        R, t = S[:3, :3], S[:3, 3]  # a similarity's R holds its scale: points scale with it
        scale = sim3_parts(S)[2] if mono else 1.0
        R_normal = R / scale if mono else R
        S_inv = sim3_inverse(S) if mono else invert(S)
        with self.map.lock:
            self.map.generation += 1  # a local BA computed before the move is discarded
            kfs = self.atlas.keyframes_of(moved)
            store = self.map.store
            rows = good_point_rows(store, kfs)
            store.pos[rows] = store.pos[rows] @ R.T + t
            store.normal[rows] = store.normal[rows] @ R_normal.T
            for k in kfs:
                k.set_pose(rigid_part(k.T_cw @ S_inv) if mono else k.T_cw @ S_inv)
                k.map_id = kept
            if rescale is not None:
                rescale({k: scale for k in kfs})
            root = self.map.origins[moved]
            mover, anchor = (kf, cand) if move_kf_map else (cand, kf)
            _reroot(mover, anchor)
            root.origin = False
            self.atlas.record_merge(kept, moved, S)
        log.info("maps merged: map %d into map %d at keyframes %d <-> %d (scale %.3f)", moved, kept, kf.id,
                 cand.id, scale)
        return MergeResult(kept, moved, anchor, self._weld(kf, cand, matched), scale, frozenset(k.id for k in kfs))

    def _weld(self, kf: KeyFrame, cand: KeyFrame, matched: dict[int, MapPoint]) -> dict[KeyFrame, set[KeyFrame]]:
        """Fuse the duplicated points of the two windows, as loop closing fuses a loop's
        points: the verified matches first, then cand's window projected into kf's window;
        returns the covisibility links that appeared across the weld."""
        with self.map.lock:
            adopt_matched_points(self.map, kf, matched)
            here, there = _window(kf), _window(cand)
            src_pts = list({p.id: p for k in there for p in k.valid_points()}.values())
        src = PointArrays.of(src_pts)
        plans = [(k, self.fusion.plan(k, src, th=4.0)) for k in here]
        apply_in_slices(self.map.lock, [partial(self.fusion.apply, k, m) for k, m in plans if m])
        before = {k: set(k.covis) for k in here + there}
        apply_in_slices(self.map.lock, [k.update_connections for k in here + there])
        with self.map.lock:
            kf.loop_edges.add(cand)
            cand.loop_edges.add(kf)
            kf.not_erase = cand.not_erase = True
        # The maps shared nothing before, so every new link crosses the weld.
        return {k: set(k.covis) - before[k] for k in here + there}
