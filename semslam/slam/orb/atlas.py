"""The multi-map atlas (ORB-SLAM3's Atlas) over one ``Map``.

ORB-SLAM2 stays lost until it relocalises; ORB-SLAM3 starts a new map instead and merges
maps when one sees a place of another. Here every map lives in the one ``Map`` object
(one point store, one lock, one keyframe database, ids unique across maps, as ORB-SLAM3's
keyframe ids are), and a keyframe's ``map_id`` says which map it belongs to. Maps share no
points and no covisibility until they merge, so tracking's local map, local mapping and
loop correction never mix them; what must not run over several maps at once (essential
graph, global BA: each map has its own gauge) asks the atlas for one map's keyframes.

Each map has its own world frame: the camera of its first keyframe (``Map.origins``).
Merging moves the newer map into the older one's frame (``slam/orb/map_merging.py``); the
atlas records which map went into which, and the move of the world for tracking, whose
last frame is still in the old coordinates (tracking takes it under the map lock at the
start of its next frame).

Tracking's side (``AtlasFollower``): when to ask for a new map, mapping its frames into a
merged map's world, and the guess of how the map it left lies in the one it relocalised in.

Threads: tracking starts maps and activates them, loop closing merges them; all of it
under ``map.lock``.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from semslam.backend.sim3 import rigid_part
from semslam.backend.sim3 import sim3_inverse
from semslam.geometry.se3 import invert
from semslam.slam.orb.map import KeyFrame, Map

if TYPE_CHECKING:
    from semslam.slam.orb.frame_state import FrameState

#: The longest gap (seconds) between the last frame tracked in one map and a relocalisation
#: in another over which the motion model still bridges the two (``AtlasFollower.bridge_to``).
BRIDGE_MAX_GAP_S = 0.5


@dataclass(frozen=True)
class MergeHint:
    """Tracking left map ``left`` by relocalising at ``reloc_kf`` of another map."""

    left: int
    reloc_kf: KeyFrame
    bridge: NDArray[np.float64] | None  # S (reloc_kf's world <- left's world), a guess


class Atlas:
    """Which keyframes form which map, which map is active, and the merges so far."""

    def __init__(self, slam_map: Map, new_map_after_s: float) -> None:
        self.map = slam_map
        # <= 0: ORB-SLAM2 (no new maps: tracking stays lost until it relocalises).
        self.new_map_after_s = float(new_map_after_s)
        self.merges: list[tuple[int, int]] = []  # (kept map, map merged into it)
        self._merged_into: dict[int, int] = {}
        self._world_change: NDArray[np.float64] | None = None
        # Tracking left a map by relocalising in another: see ``activate``.
        self._merge_hints: list[MergeHint] = []
        # Every merge check (slam/orb/merge_check.py), for stats.json: rejected ones by reason.
        self.merge_checks: list[dict[str, Any]] = []
        self.merges_rejected: Counter[str] = Counter()

    @property
    def enabled(self) -> bool:
        return self.new_map_after_s > 0

    # ------------------------------------------------------------------ tracking's side
    def new_map_due(self, lost_for_s: float) -> bool:
        """Has relocalisation failed long enough to start a new map?"""
        return self.enabled and lost_for_s >= self.new_map_after_s

    def start_new_map(self) -> int:
        """The id the next keyframe's map gets (``Map.add_keyframe`` stamps it): a new map,
        or the one already started that has no keyframe yet. Caller holds ``map.lock``."""
        new_id = max(len(self.map.origins), 1)
        self.map.active_map = new_id
        return new_id

    def activate(self, reloc_kf: KeyFrame, bridge: NDArray[np.float64] | None = None) -> None:
        """Tracking relocalised at ``reloc_kf`` of another map: new keyframes join that map.
        The map it left was being tracked a moment ago, so its last keyframes are likely near
        ``reloc_kf``: loop closing gets a hint to try that merge directly (``take_merge_hints``),
        because the left map gets no new keyframe that could find the place by itself.
        ``bridge``: tracking's guess of ``S`` (new map's world <- left map's world) from the
        motion model across the gap, if the gap was short. Caller holds the lock."""
        left = self.resolve(self.map.active_map)
        target = self.resolve(reloc_kf.map_id)
        self.map.active_map = target
        if left != target and left < len(self.map.origins):
            self._merge_hints.append(MergeHint(left, reloc_kf, bridge))

    def take_merge_hints(self) -> list[MergeHint]:
        """The hints since the last call, for loop closing. Caller holds ``map.lock``."""
        hints, self._merge_hints = self._merge_hints, []
        return hints

    def take_world_change(self) -> NDArray[np.float64] | None:
        """``S`` (new world <- old world) if the active map was moved by a merge since the last
        call, else None; tracking maps its last frame with it. Caller holds ``map.lock``."""
        S, self._world_change = self._world_change, None
        return S

    # ------------------------------------------------------------------ maps
    @property
    def n_maps(self) -> int:
        """Maps created so far (merged ones included)."""
        return max(len(self.map.origins), 1)

    def resolve(self, map_id: int) -> int:
        """The map ``map_id`` lives in now (after merges)."""
        while map_id in self._merged_into:
            map_id = self._merged_into[map_id]
        return map_id

    def live_maps(self) -> list[int]:
        """Maps not merged into another (the ones with keyframes)."""
        return [i for i in range(len(self.map.origins)) if i not in self._merged_into]

    def keyframes_of(self, map_id: int) -> list[KeyFrame]:
        """The live keyframes of one map, by id (the map's origin first)."""
        return [k for k in self.map.all_keyframes() if k.map_id == map_id]

    def record_merge(self, kept: int, merged: int, S: NDArray[np.float64]) -> None:
        """``merged``'s keyframes now belong to ``kept`` and were moved by ``S`` (kept world
        <- merged world). Caller holds ``map.lock`` and has moved them."""
        self._merged_into[merged] = kept
        self.merges.append((kept, merged))
        if self.map.active_map == merged:
            self.map.active_map = kept
            prev = self._world_change
            self._world_change = S if prev is None else S @ prev

    def merge_checked(self, kf: KeyFrame, cand: KeyFrame, T12: NDArray[np.float64], result: str,
                      coincidences: int = 0, source: str = "bow") -> None:
        """Record one merge check: ``result`` is "merged", "pending" (passed, waiting for more
        keyframes to agree) or why it was refused; ``source``: what found the candidate
        (``LoopClosing._check_merge``; "pending": a later keyframe confirming one). ``T12``:
        kf camera <- cand camera, the transform checked, and ``S`` (kf's map's world <-
        cand's map's world) with the maps' first keyframes' times, so a run's merges can be
        compared with ground truth afterwards."""
        if result not in ("merged", "pending"):
            self.merges_rejected[result] += 1
        S = kf.T_wc @ T12 @ cand.T_cw
        origins = self.map.origins

        def origin_time(map_id: int) -> float | None:
            return origins[map_id].timestamp if map_id < len(origins) else None

        self.merge_checks.append({
            "kf": kf.id, "kf_time": kf.timestamp, "kf_map": kf.map_id, "kf_map_origin_time": origin_time(kf.map_id),
            "cand": cand.id, "cand_time": cand.timestamp, "cand_map": cand.map_id,
            "cand_map_origin_time": origin_time(cand.map_id),
            "result": result, "coincidences": coincidences, "source": source,
            "T12": [round(float(v), 6) for v in np.asarray(T12).reshape(-1)],
            "S": [round(float(v), 6) for v in np.asarray(S).reshape(-1)],
        })

    # ------------------------------------------------------------------ output
    def stats(self, frame_maps: Iterable[int]) -> dict[str, Any]:
        """``maps``, ``merges`` and how many trajectory frames lie in each final map's frame
        (``frame_maps``: the map id of each tracked frame's reference keyframe, in
        trajectory order)."""
        final = [self.resolve(m) for m in frame_maps]
        per_map = Counter(final)
        first = self.resolve(0)
        return {
            "maps": self.n_maps,
            "merges": len(self.merges),
            "maps_unmerged": len(self.live_maps()) if self.map.origins else 1,
            # trajectory.txt holds every tracked frame; frames of a map never merged into the
            # first one are in that map's own frame (its first keyframe's camera).
            "trajectory_frames_by_map": {str(k): v for k, v in sorted(per_map.items())},
            "frames_outside_first_map": sum(v for k, v in per_map.items() if k != first),
            # Which rows of trajectory.txt are in which map's frame: [first row, rows, map].
            "trajectory_map_runs": map_runs(final),
            "merges_rejected": dict(sorted(self.merges_rejected.items())),
            "merge_checks": self.merge_checks,
        }


@dataclass(frozen=True)
class LastTracked:
    """The last frame tracking had (state OK), for bridging a relocalisation into another map."""

    timestamp: float
    T_cw: NDArray[np.float64]
    velocity: NDArray[np.float64] | None
    velocity_dt: float
    map_id: int


class AtlasFollower:
    """Tracking's side of the atlas: how long it has been lost, the last frame it tracked,
    and the world changes merges make under its frames."""

    def __init__(self, atlas: Atlas) -> None:
        self.atlas = atlas
        self.lost_since: float | None = None
        self.last_tracked: LastTracked | None = None

    def new_map_wanted(self, last: "FrameState | None", lost: bool, new_map_pending: bool, timestamp: float) -> bool:
        """Under the map lock before a frame: map the last frame into its map's new world if
        a merge moved it; once relocalisation has failed for ``slam.new_map_after_s``, start
        a new map (True), which the next frame with enough keypoints and depth makes its
        first keyframe (ORB-SLAM3 CreateMapInAtlas). Frames until then stay LOST."""
        self.apply_world_change(last)
        if not lost or new_map_pending:
            self.lost_since = None
            return False
        if self.lost_since is None:
            self.lost_since = last.timestamp if last is not None else timestamp
        if self.atlas.new_map_due(timestamp - self.lost_since):
            self.atlas.start_new_map()
            return True
        return False

    def apply_world_change(self, frame: "FrameState | None") -> None:
        """Map ``frame`` into its map's world if a merge moved that map. A monocular merge's
        ``S`` is a similarity: the frame keeps the rigid part, as the moved keyframes do."""
        S = self.atlas.take_world_change()
        if S is not None and frame is not None and frame.T_cw is not None:
            if abs(np.linalg.det(S[:3, :3]) - 1.0) > 1e-9:
                frame.T_cw = rigid_part(frame.T_cw @ sim3_inverse(S))
            else:
                frame.T_cw = frame.T_cw @ invert(S)

    def tracked(self, timestamp: float, T_cw: NDArray[np.float64], velocity: NDArray[np.float64] | None,
                velocity_dt: float) -> None:
        """A frame tracked in the active map, with the motion model's velocity."""
        self.last_tracked = LastTracked(timestamp, T_cw, velocity, velocity_dt, self.atlas.map.active_map)

    def relocalised(self, kf: KeyFrame, cur: "FrameState") -> None:
        """``cur`` relocalised at ``kf``: if that is another map's, tracking goes on there."""
        if kf.map_id != self.atlas.map.active_map:
            self.atlas.activate(kf, self.bridge_to(cur))

    def bridge_to(self, cur: "FrameState") -> NDArray[np.float64] | None:
        """``S`` (this frame's map world <- the left map's world) if the last frame tracked in
        the left map is at most ``BRIDGE_MAX_GAP_S`` old: that frame carried by the motion
        model to now is this frame in the left map's world. A guess for loop closing, which
        verifies it (``LoopClosing._merge_on_hints``)."""
        last = self.last_tracked
        if (last is None or cur.T_cw is None or last.velocity is None or last.velocity_dt <= 0
                or last.map_id != self.atlas.map.active_map):
            return None
        gap = cur.timestamp - last.timestamp
        if not 0 < gap <= BRIDGE_MAX_GAP_S:
            return None
        T_pred = last.T_cw
        for _ in range(max(1, round(gap / last.velocity_dt))):
            T_pred = last.velocity @ T_pred
        return invert(cur.T_cw) @ T_pred


def map_runs(frame_maps: list[int]) -> list[list[int]]:
    """Runs of consecutive equal map ids: [first index, length, map id] each."""
    runs: list[list[int]] = []
    for i, m in enumerate(frame_maps):
        if runs and runs[-1][2] == m:
            runs[-1][1] += 1
        else:
            runs.append([i, 1, m])
    return runs
