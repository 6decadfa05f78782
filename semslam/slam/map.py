"""The map: keyframes, map points and the covisibility graph (ORB-SLAM2's Map, KeyFrame,
MapPoint), shared by tracking, local mapping and loop closing under one lock.

Keyframes and points are small Python objects; arrays are gathered from them where a
stage needs vectorised work (projection of the local map, bundle adjustment).
"""

from __future__ import annotations

import threading
from collections import Counter
from dataclasses import dataclass, field
from itertools import chain
from typing import Any

import numpy as np
from numpy.typing import NDArray

from semslam.core.protocols import Matcher
from semslam.core.types import DescriptorKind, FeatureSpec, Keypoints
from semslam.features.keypoint_grid import KeypointGrid
from semslam.features.matching import matcher_for
from semslam.geometry.se3 import invert
from semslam.slam.row_kernels import first_seen_unique

Array = NDArray[np.float64]


class PointStore:
    """Map point attributes in contiguous arrays, one row per point ever created (rows are
    never reused, so a row stays the point's for the whole run).

    Why: tracking projects, gathers and counts the whole local map every frame; with the
    attributes in arrays that is a few fancy-indexing calls instead of Python loops over
    objects. ``MapPoint`` objects remain the handles for structure (observations,
    reference keyframe); their numeric attributes are properties on these rows.

    Writers: every write happens under the map's lock (tracking: ``n_visible``,
    ``n_found``, new rows; local mapping, loop closing, BA results: positions, normals,
    distance ranges, descriptors, flags). Growth replaces the arrays, so nobody keeps a
    view of them across a lock release."""

    def __init__(self, descriptor_dim: int, descriptor_dtype: Any, capacity: int = 4096) -> None:
        self.size = 0
        self.objects: list[MapPoint] = []
        self._capacity = 0
        self._dim, self._dtype = int(descriptor_dim), np.dtype(descriptor_dtype)
        self.pos = np.zeros((0, 3))
        self.normal = np.zeros((0, 3))
        self.descriptor = np.zeros((0, self._dim), self._dtype)
        self.min_dist = np.zeros(0)
        self.max_dist = np.zeros(0)
        self.n_visible = np.zeros(0, np.int64)
        self.n_found = np.zeros(0, np.int64)
        self.n_kf_obs = np.zeros(0, np.int32)  # keyframes observing the point
        self.n_obs = np.zeros(0, np.int32)  # ORB-SLAM's nObs: RGB-D/stereo observations count twice
        self.bad = np.zeros(0, bool)
        # Ids of the keyframes observing the point, in the order of its ``observations``
        # dict: the first ``n_kf_obs[row]`` entries of the row (widened when one is full).
        # Why: tracking counts the observers of ~500 points every frame; a Counter over the
        # dicts hashes every KeyFrame in Python (~0.6 ms a frame), this is one gather.
        self.observers = np.zeros((0, 8), np.int64)
        # Every keyframe that ever observed a point (culled ones too: the trajectory keeps
        # them alive anyway, as reference keyframes of the frames).
        self.keyframes_by_id: dict[int, KeyFrame] = {}
        self._grow(capacity)

    _FIELDS = ("pos", "normal", "descriptor", "min_dist", "max_dist", "n_visible", "n_found", "n_kf_obs", "n_obs",
               "bad", "observers")

    def _grow(self, capacity: int) -> None:
        for name in self._FIELDS:
            old = getattr(self, name)
            new = np.zeros((capacity, *old.shape[1:]), old.dtype)
            new[:self.size] = old[:self.size]
            setattr(self, name, new)
        self._capacity = capacity

    def allocate(self, point: "MapPoint") -> int:
        """A new row for ``point`` (amortised O(1))."""
        if self.size == self._capacity:
            self._grow(2 * self._capacity)
        row = self.size
        self.size += 1
        self.objects.append(point)
        return row

    def points(self, rows: NDArray[np.intp]) -> list["MapPoint"]:
        objs = self.objects
        return [objs[r] for r in rows.tolist()]

    def add_observer(self, row: int, kf: "KeyFrame") -> None:
        """Append ``kf`` to the row's observers (before ``n_kf_obs`` counts it)."""
        n = int(self.n_kf_obs[row])
        if n == self.observers.shape[1]:
            wider = np.zeros((self.observers.shape[0], 2 * n), np.int64)
            wider[:, :n] = self.observers
            self.observers = wider
        self.observers[row, n] = kf.id
        self.keyframes_by_id[kf.id] = kf

    def remove_observer(self, row: int, kf: "KeyFrame") -> None:
        """Remove ``kf`` from the row's observers keeping the others' order (before
        ``n_kf_obs`` stops counting it)."""
        n = int(self.n_kf_obs[row])
        ids = self.observers[row, :n]
        k = int(np.flatnonzero(ids == kf.id)[0])
        ids[k:n - 1] = ids[k + 1:n].copy()

    def observer_counts(self, rows: NDArray[np.intp]) -> tuple[list["KeyFrame"], NDArray[np.int64]]:
        """The keyframes observing any of ``rows`` in first-seen order (points in ``rows``
        order, each point's observers in the order they were added: the order of a
        ``Counter`` over the points' ``observations``) and how many of the points each
        observes."""
        if len(rows) == 0:
            return [], np.zeros(0, np.int64)
        n = self.n_kf_obs[rows]
        ids = self.observers[rows, :max(int(n.max()), 1)]
        ids = ids[np.arange(ids.shape[1]) < n[:, None]]  # row-major: points in order, observers in order
        if ids.size == 0:
            return [], np.zeros(0, np.int64)
        order = first_seen_unique(ids)
        counts = np.bincount(ids)[order]
        by_id = self.keyframes_by_id
        return [by_id[i] for i in order.tolist()], counts


def _row_property(field_name: str, kind: type, copy: bool = False) -> property:
    """A MapPoint attribute stored in ``PointStore.<field_name>[row]``."""
    if copy:
        def get(self: "MapPoint") -> Any:
            return getattr(self._store, field_name)[self._row].copy()
    else:
        def get(self: "MapPoint") -> Any:
            return kind(getattr(self._store, field_name)[self._row])

    def set_(self: "MapPoint", value: Any) -> None:
        getattr(self._store, field_name)[self._row] = value

    return property(get, set_)


class MapPoint:
    """A 3D point with the keyframes that observe it (ORB-SLAM2 MapPoint). Numeric
    attributes live in the map's ``PointStore`` (row ``_row``); array attributes are
    returned as copies (assign to change them)."""

    __slots__ = ("id", "_row", "_store", "observations", "ref_kf", "first_kf_id", "replaced_by", "__weakref__")

    def __init__(self, pid: int, pos: Array, descriptor: NDArray[Any], ref_kf: "KeyFrame",
                 store: PointStore | None = None) -> None:
        if store is None:  # a point outside any map (tests): a store of its own
            store = PointStore(np.asarray(descriptor).size, np.asarray(descriptor).dtype, capacity=1)
        self._store = store
        self._row = store.allocate(self)
        self.id = pid
        self.pos = np.asarray(pos, dtype=np.float64)
        self.descriptor = descriptor
        self.observations: dict[KeyFrame, int] = {}
        self.n_visible = 1
        self.n_found = 1
        self.ref_kf = ref_kf
        self.first_kf_id = ref_kf.id
        self.replaced_by: MapPoint | None = None

    pos = _row_property("pos", float, copy=True)
    normal = _row_property("normal", float, copy=True)
    descriptor = _row_property("descriptor", float, copy=True)
    min_dist = _row_property("min_dist", float)
    max_dist = _row_property("max_dist", float)
    n_visible = _row_property("n_visible", int)
    n_found = _row_property("n_found", int)
    bad = _row_property("bad", bool)

    @property
    def row(self) -> int:
        return self._row

    def __repr__(self) -> str:
        return f"MapPoint({self.id}, obs={len(self.observations)})"

    @property
    def n_obs(self) -> int:
        """Observation count with RGB-D/stereo observations counted twice (ORB-SLAM's nObs)."""
        return int(self._store.n_obs[self._row])

    @property
    def found_ratio(self) -> float:
        return self.n_found / max(self.n_visible, 1)

    def add_observation(self, kf: "KeyFrame", idx: int) -> None:
        if kf not in self.observations:
            self._store.add_observer(self._row, kf)
            self._store.n_kf_obs[self._row] += 1
            self._store.n_obs[self._row] += 2 if kf.ur[idx] >= 0 else 1
        else:
            self._store.n_obs[self._row] += (2 if kf.ur[idx] >= 0 else 1) - (2 if kf.ur[self.observations[kf]] >= 0 else 1)
        self.observations[kf] = idx

    def clear_observations(self) -> None:
        self.observations = {}
        self._store.n_kf_obs[self._row] = 0
        self._store.n_obs[self._row] = 0

    def erase_observation(self, kf: "KeyFrame") -> None:
        if kf in self.observations:
            idx = self.observations.pop(kf)
            self._store.remove_observer(self._row, kf)
            self._store.n_kf_obs[self._row] -= 1
            self._store.n_obs[self._row] -= 2 if kf.ur[idx] >= 0 else 1
            if self.ref_kf is kf and self.observations:
                self.ref_kf = next(iter(self.observations))
            if len(self.observations) <= 1 and kf.map is not None:
                kf.map.set_bad_point(self)

    def update_normal_and_depth(self, scale_factors: Array) -> None:
        update_normals_and_depths([self], scale_factors)

    def compute_distinctive_descriptor(self, matcher: Matcher) -> None:
        """The observation descriptor with the least median distance to the others
        (distances by the matcher of the map's descriptor kind); many points at once:
        ``slam.map_batch.compute_distinctive_descriptors``, which this calls."""
        from semslam.slam.map_batch import compute_distinctive_descriptors

        compute_distinctive_descriptors([self], matcher)


def update_normals_and_depths(points: list[MapPoint], scale_factors: Array) -> None:
    """Mean viewing direction of each point and the distance range it can be matched at
    (ORB-SLAM UpdateNormalAndDepth), for many points at once; computed by
    ``slam.map_batch.normals_and_depths`` and written here (the caller holds the map lock).
    Bad points and points without observations are skipped; the depth range needs the
    reference keyframe among the observations."""
    from semslam.slam.map_batch import normals_and_depths

    update = normals_and_depths(points, scale_factors)
    if update.points:
        store = update.points[0]._store
        shared = all(p._store is store for p in update.points)
        update.write(store if shared else None)


class PointSlots(list):  # type: ignore[type-arg]
    """A keyframe's map point per keypoint (``MapPoint | None``), a list that also keeps
    the points' store rows in ``rows`` (-1 = none), so the local map is gathered with
    array operations. Only item assignment is supported as a change."""

    def __init__(self, points: Any = ()) -> None:
        super().__init__(points)
        self.rows = np.fromiter((-1 if p is None else p._row for p in self), np.intp, len(self))

    def __setitem__(self, i: Any, p: Any) -> None:
        if not isinstance(i, (int, np.integer)):
            raise TypeError("PointSlots supports item assignment by index only")
        super().__setitem__(i, p)
        self.rows[i] = -1 if p is None else p._row

    def put(self, idx: NDArray[np.intp], points: list[Any], rows: NDArray[np.intp] | None = None) -> None:
        """``self[idx[k]] = points[k]`` for every k at once (``rows``: the points' store rows,
        when the caller has them; None entries clear slots)."""
        setitem = super().__setitem__
        for i, p in zip(idx.tolist(), points):
            setitem(i, p)
        if rows is None:
            rows = np.fromiter((-1 if p is None else p._row for p in points), np.intp, len(points))
        self.rows[idx] = rows

    def good_rows(self, store: PointStore) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        """Slots holding a point that is not bad (``store``: the points' store) and those
        points' store rows. Safe without the map lock: one snapshot of the rows (a slot
        cleared meanwhile would otherwise read row -1, the newest point's)."""
        rows = self.rows.copy()
        has = rows >= 0
        has[has] = ~store.bad[rows[has]]
        idx = np.flatnonzero(has)
        return idx, rows[idx]

    def good(self, store: PointStore) -> NDArray[np.intp]:
        """The slots of ``good_rows``."""
        return self.good_rows(store)[0]

    def free(self, store: PointStore) -> NDArray[np.bool_]:
        """Slots without a point, or with a bad one (``store``: the points' store); one
        snapshot of the rows, as ``good``."""
        rows = self.rows.copy()
        free = rows < 0
        free[~free] = store.bad[rows[~free]]
        return free

    def _unsupported(self, *args: Any, **kwargs: Any) -> None:
        raise TypeError("a keyframe's point slots have a fixed length")

    append = extend = insert = pop = remove = clear = __delitem__ = __iadd__ = _unsupported  # type: ignore[assignment]


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
    points: list[MapPoint | None]
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
    # The atlas map this keyframe belongs to (slam/atlas.py; 0 without a new map) and whether
    # it is that map's first keyframe: the root of its spanning tree, never culled, fixed in
    # local BA (ORB-SLAM3's GetInitKFid; ORB-SLAM2 tests id 0).
    map_id: int = 0
    origin: bool = False
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
        map, its first point's); None without points."""
        if self.map is not None:
            return self.map.store
        return next((p._store for p in self.points if p is not None), None)

    def tracked_points(self, min_obs: int = 1) -> int:
        """Points with at least ``min_obs`` observations (ORB-SLAM TrackedMapPoints)."""
        rows = self.points.rows
        rows = rows[rows >= 0]
        if len(rows) == 0:
            return 0
        store = self.point_store()
        return int((~store.bad[rows] & (store.n_obs[rows] >= min_obs)).sum())

    def valid_indices(self) -> NDArray[np.intp]:
        """Keypoints with a good map point (in a map: by the store's flags, no property per
        point; outside one, as tests build them, point by point)."""
        if self.map is None:
            return np.array([i for i, p in enumerate(self.points) if p is not None and not p.bad], np.intp)
        return self.points.good(self.map.store)

    def valid_points(self) -> list[MapPoint]:
        """The good points, in slot order. Local mapping reads without the map lock, and
        tracking may clear a slot (a point culled) between the rows and the list: skipped."""
        pts = self.points
        return [p for p in map(pts.__getitem__, self.valid_indices().tolist()) if p is not None]

    def free_mask(self) -> NDArray[np.bool_]:
        """Keypoints without a map point, or with a bad one (as ``valid_indices`` reads them)."""
        if self.map is None:
            return np.array([p is None or p.bad for p in self.points], bool)
        return self.points.free(self.map.store)

    def best_covisibles(self, n: int) -> list["KeyFrame"]:
        return [kf for kf in self.ordered_covis[:n] if not kf.bad]

    def covisibles_with_weight(self, w: int) -> list["KeyFrame"]:
        return [kf for kf in self.ordered_covis if self.covis.get(kf, 0) >= w and not kf.bad]

    def update_connections(self) -> None:
        """Covisibility weights = shared map points; spanning-tree parent = best covisible."""
        every = Counter(chain.from_iterable(p.observations for p in self.valid_points()))  # C loop, first-seen order
        counts = {kf: n for kf, n in every.items() if kf is not self and not kf.bad}
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
        # The atlas map new keyframes join (slam/atlas.py changes it; 0 with one map).
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
            if kf in new.observations:
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
            new.compute_distinctive_descriptor(self.matcher)

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
