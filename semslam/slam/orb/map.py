"""The map: keyframes, map points and the covisibility graph (ORB-SLAM2's Map, KeyFrame,
MapPoint), shared by tracking, local mapping and loop closing under one lock.

Point data (attributes and observations) live in the map's ``PointStore``
(``slam.point_store``); keyframes hold their points as store rows (``PointSlots``).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from semslam.core.protocols import Matcher
from semslam.core.types import DescriptorKind, FeatureSpec, Keypoints
from semslam.features.keypoint_grid import KeypointGrid
from semslam.features.matching import matcher_for
from semslam.geometry.se3 import invert
from semslam.slam.orb.map_batch import compute_distinctive_descriptors, normals_and_depths
from semslam.slam.orb.point_store import MapPoint, PointSlots, PointStore

Array = NDArray[np.float64]


def update_normals_and_depths(points: list[MapPoint], scale_factors: Array) -> None:
    """Mean viewing direction of each point and the distance range it can be matched at
    (ORB-SLAM UpdateNormalAndDepth), for many points at once; computed by
    ``slam.map_batch.normals_and_depths`` and written here (the caller holds the map lock).
    Bad points and points without observations are skipped; the depth range needs the
    reference keyframe among the observations."""
    normals_and_depths(points, scale_factors).write()


def good_point_rows(store: PointStore, kfs: "list[KeyFrame]") -> NDArray[np.intp]:
    """Store rows of the good points the keyframes observe, each once (a map moved or scaled
    as a whole moves these)."""
    rows = np.unique(np.concatenate([k.points.rows for k in kfs] or [np.zeros(0, np.intp)]))
    rows = rows[rows >= 0]
    return rows[~store.bad[rows]]


@dataclass(frozen=True)
class InertialLink:
    """The IMU's motion from an earlier keyframe to this one, ``T_cw(this) ~ T @
    T_cw(previous)``, with isotropic spreads (radians, metres) on the residual of
    ``bundle_adjustment.BAProblem``'s links; local BA holds the two poses to it."""

    previous: "KeyFrame"
    T: Array
    sigma_rotation: float
    sigma_translation: float

    def information(self) -> Array:
        return np.diag([self.sigma_rotation ** -2] * 3 + [self.sigma_translation ** -2] * 3)


@dataclass(eq=False)
class KeyFrame:
    """A frame kept in the map, with its features and their map points."""

    id: int
    frame_index: int
    timestamp: float
    T_cw: Array
    keypoints: Keypoints
    xy: Array  # undistorted keypoint positions
    depth: NDArray[np.float32]
    ur: NDArray[np.float64]
    points: PointSlots  # built from a list of MapPoint | None
    map: "Map | None" = None
    bow: Any = None  # place.vocabulary.BowVector, set by local mapping
    featvec: dict[int, Any] = field(default_factory=dict)
    covis: dict["KeyFrame", int] = field(default_factory=dict)
    ordered_covis: list["KeyFrame"] = field(default_factory=list)
    parent: "KeyFrame | None" = None
    children: set["KeyFrame"] = field(default_factory=set)
    loop_edges: set["KeyFrame"] = field(default_factory=set)
    bad: bool = False
    not_erase: bool = False
    to_be_erased: bool = False
    T_cw_before_gba: Array | None = None
    T_cp: Array | None = None  # pose relative to the parent, kept when the keyframe is culled
    # The atlas map this keyframe belongs to (slam/orb/atlas.py; 0 without a new map) and whether
    # it is that map's first keyframe: the root of its spanning tree, never culled, fixed in
    # local BA (ORB-SLAM3's GetInitKFid; ORB-SLAM2 tests id 0).
    map_id: int = 0
    origin: bool = False
    # Monocular with a depth network as a prior (slam/orb/depth_prior.py): its depth per
    # keypoint as predicted, and the prior local BA uses once local mapping has checked it
    # (0: none); None without one.
    predicted_depth: NDArray[np.float32] | None = None
    prior_depth: NDArray[np.float32] | None = None
    # With an IMU: its motion from the keyframe made before this one (None: none measured).
    inertial_link: InertialLink | None = None
    _tree: Any = None
    _grid: KeypointGrid | None = None
    _center: Array = field(default_factory=lambda: np.zeros(3), repr=False)

    def __hash__(self) -> int:
        return self.id

    def __repr__(self) -> str:
        return f"KeyFrame({self.id}, frame={self.frame_index})"

    @property
    def T_wc(self) -> Array:
        return invert(self.T_cw)

    @property
    def is_origin(self) -> bool:
        """The first keyframe of its map (keyframe 0, or the origin of a later atlas map)."""
        return self.id == 0 or self.origin

    def __post_init__(self) -> None:
        self.set_pose(self.T_cw)
        if not isinstance(self.points, PointSlots):
            self.points = PointSlots(self.points)

    @property
    def center(self) -> Array:
        return self._center

    def set_pose(self, T_cw: Array) -> None:
        self.T_cw = np.asarray(T_cw, dtype=np.float64).copy()
        self._center = -self.T_cw[:3, :3].T @ self.T_cw[:3, 3]

    def set_words(self, bow: Any, featvec: dict[int, Any]) -> None:
        """The keyframe's bag of words, set once: tracking, local mapping and the place
        indexer may each compute it first; later sets keep it. ``featvec`` goes first, as
        readers check ``bow``."""
        if self.bow is None:
            self.featvec = featvec
            self.bow = bow

    def point_store(self) -> PointStore | None:
        """Where this keyframe's points live: its map's store (or, for a keyframe outside a
        map, its points'); None without points."""
        if self.map is not None:
            return self.map.store
        return self.points.store

    def tracked_points(self, min_obs: int = 1) -> int:
        """Points with at least ``min_obs`` observations (ORB-SLAM TrackedMapPoints)."""
        rows = self.points.rows
        rows = rows[rows >= 0]
        if len(rows) == 0:
            return 0
        store = self.point_store()
        return int((~store.bad[rows] & (store.n_obs[rows] >= min_obs)).sum())

    def _good_rows(self) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        """The slots with a good point and the points' store rows (one snapshot)."""
        store = self.point_store()
        if store is None:
            return np.zeros(0, np.intp), np.zeros(0, np.intp)
        return self.points.good_rows(store)

    def valid_indices(self) -> NDArray[np.intp]:
        """Keypoints with a good map point."""
        return self._good_rows()[0]

    def valid_points(self) -> list[MapPoint]:
        """The good points, in slot order (one snapshot of the slots: local mapping reads
        without the map lock)."""
        store = self.point_store()
        return [] if store is None else store.points(self._good_rows()[1])

    def free_mask(self) -> NDArray[np.bool_]:
        """Keypoints without a map point, or with a bad one (as ``valid_indices`` reads them)."""
        store = self.point_store()
        return np.ones(len(self.points), bool) if store is None else self.points.free(store)

    def best_covisibles(self, n: int) -> list["KeyFrame"]:
        return [kf for kf in self.ordered_covis[:n] if not kf.bad]

    def covisibles_with_weight(self, w: int) -> list["KeyFrame"]:
        return [kf for kf in self.ordered_covis if self.covis.get(kf, 0) >= w and not kf.bad]

    def update_connections(self) -> None:
        """Covisibility weights = shared map points; spanning-tree parent = best covisible."""
        store = self.point_store()
        if store is None:
            return
        observers, shared = store.observer_counts(self._good_rows()[1])  # first-seen order, as a Counter
        counts = {kf: n for kf, n in zip(observers, shared.tolist()) if kf is not self and not kf.bad}
        if not counts:
            return
        best = max(counts, key=lambda k: counts[k])
        strong = {kf: w for kf, w in counts.items() if w >= 15} or {best: counts[best]}
        for kf, w in strong.items():
            kf.add_connection(self, w)
        self.covis = strong
        self.ordered_covis = sorted(strong, key=lambda k: -strong[k])
        if self.parent is None and not self.is_origin:
            self.parent = self.ordered_covis[0]
            self.parent.children.add(self)

    def add_connection(self, kf: "KeyFrame", weight: int) -> None:
        self.covis[kf] = weight
        self.ordered_covis = sorted(self.covis, key=lambda k: -self.covis[k])

    def erase_connection(self, kf: "KeyFrame") -> None:
        if kf in self.covis:
            del self.covis[kf]
            self.ordered_covis = [k for k in self.ordered_covis if k is not kf]

    def tree(self) -> Any:
        """KD-tree over keypoint positions for radius searches (built once)."""
        if self._tree is None:
            from scipy.spatial import cKDTree

            self._tree = cKDTree(self.xy)
        return self._tree

    def grid(self, width: float, height: float) -> KeypointGrid:
        """The keypoints in ORB-SLAM's 64 x 48 grid over the image, for compiled radius
        queries (built once; ``xy`` does not change once a frame is a keyframe)."""
        if self._grid is None:
            self._grid = KeypointGrid(self.xy, self.keypoints.octave, width, height)
        return self._grid


class Map:
    """All keyframes and points; ``lock`` guards structural changes across threads.

    ``spec`` says what the keyframes' descriptors are (a map holds one kind) and the pyramid
    their levels refer to; ``matcher`` compares those descriptors."""

    def __init__(self, spec: FeatureSpec) -> None:
        self.spec = spec
        self.matcher: Matcher = matcher_for(spec)
        self.keyframes: dict[int, KeyFrame] = {}
        self.points: dict[int, MapPoint] = {}
        self.store = PointStore(spec.dim, np.uint8 if spec.kind is DescriptorKind.BINARY else np.float32)
        self.lock = threading.RLock()
        # Clear while tracking works on a frame: background threads start their Python-heavy
        # steps in the gaps (they share one GIL with tracking, see LocalMapping.yield_to_tracking).
        self.tracking_idle = threading.Event()
        self.tracking_idle.set()
        self._next_kf = 0
        self._next_pt = 0
        self.origins: list[KeyFrame] = []  # the first keyframe of each atlas map, by map id
        # The atlas map new keyframes join (slam/orb/atlas.py changes it; 0 with one map).
        self.active_map = 0
        self.n_loops = 0
        # Bumped by loop correction and global BA: a local BA computed on older poses is dropped.
        self.generation = 0

    def new_kf_id(self) -> int:
        self._next_kf += 1
        return self._next_kf - 1

    def new_point(self, pos: Array, descriptor: NDArray[Any], ref_kf: KeyFrame) -> MapPoint:
        p = MapPoint(self._next_pt, pos, descriptor, ref_kf, self.store)
        self._next_pt += 1
        self.points[p.id] = p
        return p

    def add_keyframe(self, kf: KeyFrame) -> None:
        kf.map = self
        kf.map_id = self.active_map
        self.keyframes[kf.id] = kf
        if len(self.origins) <= kf.map_id:  # the first keyframe of a new map
            self.origins.append(kf)
            kf.origin = True

    def set_bad_point(self, p: MapPoint) -> None:
        """Remove a point and its observations (ORB-SLAM MapPoint::SetBadFlag)."""
        if p.bad:
            return
        p.bad = True
        for kf, idx in list(p.observations.items()):
            if idx < len(kf.points) and kf.points[idx] is p:
                kf.points[idx] = None
        p.clear_observations()
        self.points.pop(p.id, None)

    def replace_point(self, old: MapPoint, new: MapPoint, descriptor: bool = True) -> None:
        """Fuse ``old`` into ``new`` (duplicates found by projection or loop fusion).
        ``descriptor=False`` leaves ``new``'s distinctive descriptor to the caller, who
        computes it once for many replaced points (``slam.map_batch``)."""
        if old is new or old.bad or new.bad:
            return
        for kf, idx in list(old.observations.items()):
            if new.is_observed_by(kf):
                if kf.points[idx] is old:
                    kf.points[idx] = None
            else:
                kf.points[idx] = new
                new.add_observation(kf, idx)
        new.n_found += old.n_found
        new.n_visible += old.n_visible
        old.clear_observations()
        old.bad = True
        old.replaced_by = new
        self.points.pop(old.id, None)
        if descriptor:
            compute_distinctive_descriptors([new], self.matcher)

    def set_bad_keyframe(self, kf: KeyFrame) -> None:
        """Remove a redundant keyframe, re-parenting its children (ORB-SLAM KeyFrame::SetBadFlag)."""
        if kf.is_origin or kf.not_erase:
            kf.to_be_erased = True
            return
        for other in list(kf.covis):
            other.erase_connection(kf)
        for i, p in enumerate(kf.points):
            if p is not None:
                kf.points[i] = None
                p.erase_observation(kf)
        kf.covis, kf.ordered_covis = {}, []
        # Re-parent children to the covisible keyframe they share most with.
        parent = kf.parent
        if parent is not None:
            kf.T_cp = kf.T_cw @ parent.T_wc
        for child in list(kf.children):
            candidates = [c for c in child.ordered_covis if c is not kf and not c.bad]
            new_parent = candidates[0] if candidates else parent
            child.parent = new_parent
            if new_parent is not None:
                new_parent.children.add(child)
        if parent is not None:
            parent.children.discard(kf)
        kf.children = set()
        kf.bad = True
        # Keep the relative pose to the parent for the trajectory of frames that referenced kf.
        self.keyframes.pop(kf.id, None)

    def all_keyframes(self) -> list[KeyFrame]:
        return sorted(self.keyframes.values(), key=lambda k: k.id)
