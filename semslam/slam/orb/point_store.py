"""Map point storage: every point attribute and every observation lives once, in the arrays
of a ``PointStore``; ``MapPoint`` and ``PointSlots`` are views over its rows.

Why arrays: tracking projects, gathers and counts the whole local map every frame; with the
attributes in arrays that is a few fancy-indexing calls instead of Python loops over
objects. Why views and not copies: a value kept in two places (an object attribute and a
row) drifts apart as soon as one writer forgets the other.
"""

from __future__ import annotations

from collections.abc import Iterable
from types import MappingProxyType
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from semslam.slam.orb.row_kernels import first_seen_unique

Array = NDArray[np.float64]


class Observer(Protocol):
    """What the point store and the batch statistics read of a keyframe observing a point
    (``slam.map.KeyFrame``)."""

    id: int
    ur: NDArray[np.float64]
    xy: NDArray[np.float64]
    keypoints: Any
    bad: bool
    map: Any  # the Map holding the keyframe (None outside one)

    @property
    def center(self) -> Array: ...


class PointStore:
    """Map point attributes in contiguous arrays, one row per point ever created (rows are
    never reused, so a row stays the point's for the whole run).

    Observations: row r is observed by the keyframes ``observers[r, :n_kf_obs[r]]`` (ids,
    in the order they were added, as a dict would keep them: re-observing keeps the place,
    erasing and re-adding goes last) at keypoints ``observer_kp[r, :n_kf_obs[r]]``.
    ``n_obs`` is ORB-SLAM's nObs (RGB-D/stereo observations count twice), kept by the same
    methods.

    Writers: every write happens under the map's lock (tracking: ``n_visible``,
    ``n_found``, new rows; local mapping, loop closing, BA results: positions, normals,
    distance ranges, descriptors, flags, observations). Growth replaces the arrays, so
    nobody keeps a view of them across a lock release."""

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
        self.n_obs = np.zeros(0, np.int32)
        self.bad = np.zeros(0, bool)
        # Observer ids and their keypoints: the first ``n_kf_obs[row]`` entries of a row,
        # widened when one is full. Why arrays: tracking counts the observers of ~500 points
        # every frame; a Counter over dicts hashes every KeyFrame in Python (~0.6 ms a frame).
        self.observers = np.zeros((0, 8), np.int64)
        self.observer_kp = np.zeros((0, 8), np.int64)
        # Every keyframe that ever observed a point (culled ones too: the trajectory keeps
        # them alive anyway, as reference keyframes of the frames).
        self.keyframes_by_id: dict[int, Observer] = {}
        self._grow(capacity)

    _FIELDS = ("pos", "normal", "descriptor", "min_dist", "max_dist", "n_visible", "n_found", "n_kf_obs", "n_obs",
               "bad", "observers", "observer_kp")

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

    # ------------------------------------------------------------------ observations
    def _widen_observers(self) -> None:
        n = self.observers.shape[1]
        for name in ("observers", "observer_kp"):
            old = getattr(self, name)
            wider = np.zeros((old.shape[0], 2 * n), np.int64)
            wider[:, :n] = old
            setattr(self, name, wider)

    def observer_slot(self, row: int, kf: Observer) -> int:
        """Where ``kf`` is among the row's observers, -1 if it does not observe the point
        (a list search: rows hold a few observers, numpy's call costs more)."""
        ids = self.observers[row, :self.n_kf_obs[row]].tolist()
        return ids.index(kf.id) if kf.id in ids else -1

    def observe(self, row: int, kf: Observer, idx: int) -> None:
        """``kf`` observes the point at keypoint ``idx`` (a keyframe observing it already
        keeps its place, with the new keypoint)."""
        k = self.observer_slot(row, kf)
        if k < 0:
            n = int(self.n_kf_obs[row])
            if n == self.observers.shape[1]:
                self._widen_observers()
            self.observers[row, n] = kf.id
            self.observer_kp[row, n] = idx
            self.keyframes_by_id[kf.id] = kf
            self.n_kf_obs[row] += 1
            self.n_obs[row] += 2 if kf.ur[idx] >= 0 else 1
        else:
            self.n_obs[row] += (2 if kf.ur[idx] >= 0 else 1) - (2 if kf.ur[self.observer_kp[row, k]] >= 0 else 1)
            self.observer_kp[row, k] = idx

    def unobserve(self, row: int, kf: Observer) -> int | None:
        """Remove ``kf``'s observation keeping the others' order; its keypoint, or None if
        ``kf`` did not observe the point."""
        k = self.observer_slot(row, kf)
        if k < 0:
            return None
        n = int(self.n_kf_obs[row])
        idx = int(self.observer_kp[row, k])
        for table in (self.observers, self.observer_kp):
            table[row, k:n - 1] = table[row, k + 1:n].copy()
        self.n_kf_obs[row] -= 1
        self.n_obs[row] -= 2 if kf.ur[idx] >= 0 else 1
        return idx

    def clear_observations(self, row: int) -> None:
        self.n_kf_obs[row] = 0
        self.n_obs[row] = 0

    def observations(self, row: int) -> dict[Observer, int]:
        """The row's observations as a new dict (keyframe -> keypoint), in their order."""
        n = int(self.n_kf_obs[row])
        by_id = self.keyframes_by_id
        return dict(zip(map(by_id.__getitem__, self.observers[row, :n].tolist()), self.observer_kp[row, :n].tolist()))

    def first_observer(self, row: int) -> Observer | None:
        return self.keyframes_by_id[int(self.observers[row, 0])] if self.n_kf_obs[row] else None

    def observation_table(self, rows: NDArray[np.intp]) -> tuple[NDArray[np.intp], NDArray[np.int64], NDArray[np.int64]]:
        """Every observation of ``rows`` as flat arrays, points in ``rows`` order and each
        point's observations in their order: (position in ``rows``, keyframe id, keypoint)."""
        if len(rows) == 0:
            return np.zeros(0, np.intp), np.zeros(0, np.int64), np.zeros(0, np.int64)
        n = self.n_kf_obs[rows]
        width = max(int(n.max()), 1)
        ids, kp = self.observers[rows, :width], self.observer_kp[rows, :width]
        held = np.arange(width) < n[:, None]  # row-major: points in order, observers in order
        return np.repeat(np.arange(len(rows), dtype=np.intp), n), ids[held], kp[held]

    def observer_counts(self, rows: NDArray[np.intp]) -> tuple[list[Observer], NDArray[np.int64]]:
        """The keyframes observing any of ``rows`` in first-seen order (points in ``rows``
        order, each point's observers in their order: the order of a ``Counter`` over the
        points' ``observations``) and how many of the points each observes."""
        ids = self.observation_table(rows)[1]
        if ids.size == 0:
            return [], np.zeros(0, np.int64)
        order = first_seen_unique(ids)
        counts = np.bincount(ids)[order]
        by_id = self.keyframes_by_id
        return [by_id[i] for i in order.tolist()], counts


def _read_only_row(field_name: str) -> property:
    """An array attribute of a MapPoint: a read-only copy of ``PointStore.<field_name>[row]``
    (writes into it raise instead of being lost; assign the attribute to change it)."""
    def get(self: "MapPoint") -> Any:
        value = getattr(self._store, field_name)[self._row].copy()
        value.flags.writeable = False
        return value

    def set_(self: "MapPoint", value: Any) -> None:
        getattr(self._store, field_name)[self._row] = value

    return property(get, set_)


def _scalar_row(field_name: str, kind: type) -> property:
    """A scalar MapPoint attribute stored in ``PointStore.<field_name>[row]``."""
    def get(self: "MapPoint") -> Any:
        return kind(getattr(self._store, field_name)[self._row])

    def set_(self: "MapPoint", value: Any) -> None:
        getattr(self._store, field_name)[self._row] = value

    return property(get, set_)


class MapPoint:
    """A 3D point with the keyframes that observe it (ORB-SLAM2 MapPoint): a handle on row
    ``row`` of its store, which holds its attributes and observations; the reference
    keyframe and the point that replaced it are the object's own."""

    __slots__ = ("id", "_row", "_store", "ref_kf", "first_kf_id", "replaced_by", "__weakref__")

    def __init__(self, pid: int, pos: Array, descriptor: NDArray[Any], ref_kf: Observer,
                 store: PointStore | None = None) -> None:
        if store is None:  # a point outside any map (tests): a store of its own
            store = PointStore(np.asarray(descriptor).size, np.asarray(descriptor).dtype, capacity=1)
        self._store = store
        self._row = store.allocate(self)
        self.id = pid
        self.pos = np.asarray(pos, dtype=np.float64)
        self.descriptor = descriptor
        self.n_visible = 1
        self.n_found = 1
        self.ref_kf = ref_kf
        self.first_kf_id = ref_kf.id
        self.replaced_by: MapPoint | None = None

    pos = _read_only_row("pos")
    normal = _read_only_row("normal")
    descriptor = _read_only_row("descriptor")
    min_dist = _scalar_row("min_dist", float)
    max_dist = _scalar_row("max_dist", float)
    n_visible = _scalar_row("n_visible", int)
    n_found = _scalar_row("n_found", int)
    bad = _scalar_row("bad", bool)

    @property
    def row(self) -> int:
        return self._row

    @property
    def store(self) -> PointStore:
        return self._store

    def __repr__(self) -> str:
        return f"MapPoint({self.id}, obs={self.n_observers})"

    @property
    def observations(self) -> MappingProxyType[Observer, int]:
        """Keyframe -> keypoint index, in the order the observations were added (read from
        the store; change them with ``add_observation`` / ``erase_observation``)."""
        return MappingProxyType(self._store.observations(self._row))

    def keypoint_in(self, kf: Observer) -> int | None:
        """The keypoint of ``kf`` observing the point, None if ``kf`` does not."""
        k = self._store.observer_slot(self._row, kf)
        return None if k < 0 else int(self._store.observer_kp[self._row, k])

    def is_observed_by(self, kf: Observer) -> bool:
        return self._store.observer_slot(self._row, kf) >= 0

    @property
    def n_observers(self) -> int:
        """Keyframes observing the point."""
        return int(self._store.n_kf_obs[self._row])

    @property
    def n_obs(self) -> int:
        """Observation count with RGB-D/stereo observations counted twice (ORB-SLAM's nObs)."""
        return int(self._store.n_obs[self._row])

    @property
    def found_ratio(self) -> float:
        return self.n_found / max(self.n_visible, 1)

    def add_observation(self, kf: Observer, idx: int) -> None:
        self._store.observe(self._row, kf, idx)

    def clear_observations(self) -> None:
        self._store.clear_observations(self._row)

    def erase_observation(self, kf: Observer) -> None:
        """Drop ``kf``'s observation; the first remaining observer becomes the reference if
        ``kf`` was, and a point left with one observation or none goes bad."""
        if self._store.unobserve(self._row, kf) is None:
            return
        left = self.n_observers
        if self.ref_kf is kf and left:
            self.ref_kf = self._store.first_observer(self._row)
        if left <= 1 and kf.map is not None:
            kf.map.set_bad_point(self)


class PointSlots:
    """A keyframe's or frame's map point per keypoint, held as the points' store rows (-1 =
    none): the point in a slot is the store's object at its row, so rows and objects cannot
    disagree. The store is the first point's; a slots object holds points of one store."""

    __slots__ = ("_rows", "_store")

    def __init__(self, points: Iterable[MapPoint | None] = ()) -> None:
        pts = list(points)
        stores = {p._store for p in pts if p is not None}
        if len(stores) > 1:
            raise ValueError("a slots object holds points of one store")
        self._store: PointStore | None = stores.pop() if stores else None
        self._rows = np.fromiter((-1 if p is None else p._row for p in pts), np.intp, len(pts))

    @property
    def rows(self) -> NDArray[np.intp]:
        """The store row per slot, read-only (change slots by item assignment or ``put``)."""
        rows = self._rows.view()
        rows.flags.writeable = False
        return rows

    @property
    def store(self) -> PointStore | None:
        """The store the points live in (None while no slot was ever set)."""
        return self._store

    def __len__(self) -> int:
        return len(self._rows)

    def __getitem__(self, i: int) -> MapPoint | None:
        r = self._rows[i]
        return None if r < 0 else self._store.objects[r]  # type: ignore[union-attr]

    def __iter__(self) -> Any:
        objs = self._store.objects if self._store is not None else []
        return iter([None if r < 0 else objs[r] for r in self._rows.tolist()])

    def __repr__(self) -> str:
        return f"PointSlots({list(self)!r})"

    def _adopt(self, p: MapPoint) -> None:
        if self._store is None:
            self._store = p._store
        elif p._store is not self._store:
            raise ValueError("a slots object holds points of one store")

    def __setitem__(self, i: int, p: MapPoint | None) -> None:
        if not isinstance(i, (int, np.integer)):
            raise TypeError("PointSlots supports item assignment by index only")
        if p is None:
            self._rows[i] = -1
            return
        self._adopt(p)
        self._rows[i] = p._row

    def put(self, idx: NDArray[np.intp], points: list[MapPoint | None], rows: NDArray[np.intp] | None = None) -> None:
        """``self[idx[k]] = points[k]`` for every k at once (``rows``: the points' store rows,
        when the caller has them; None entries clear slots)."""
        first = next((p for p in points if p is not None), None)
        if first is not None:
            self._adopt(first)
        if rows is None:
            rows = np.fromiter((-1 if p is None else p._row for p in points), np.intp, len(points))
        self._rows[idx] = rows

    def good_rows(self, store: PointStore) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        """Slots holding a point that is not bad (``store``: the points' store) and those
        points' store rows. Safe without the map lock: one snapshot of the rows (a slot
        cleared meanwhile would otherwise read row -1, the newest point's)."""
        rows = self._rows.copy()
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
        rows = self._rows.copy()
        free = rows < 0
        free[~free] = store.bad[rows[~free]]
        return free
