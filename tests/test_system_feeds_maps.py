"""The System is the only caller of the map builders, from what the tracker returns; the
packet a tracker gets cannot be changed on the way (data flows one way)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

import semslam.assembly
from semslam import System
from semslam.config import SystemConfig, load_config
from semslam.core.protocols import FramePacket, KeyframeSnapshot, MapStage, Tracker, TrackerInputs
from semslam.core.trajectory import Trajectory
from semslam.core.types import Frame, KeyframeEvent, TrackingState, TrackResult
from semslam.geometry.camera import PinholeCamera
from semslam.synth import SEQUENCES, Renderer
from tests.conftest import rendered_frames

CAMERA = PinholeCamera(100.0, 100.0, 32.0, 24.0, width=64, height=48)


class RecordingMaps:
    """A ``MapStage`` that records every call it gets."""

    def __init__(self, wants_frames: bool = False) -> None:
        self.wants_frames = wants_frames
        self.calls: list[tuple[str, object]] = []

    def add_keyframe(self, snapshot: KeyframeSnapshot) -> None:
        self.calls.append(("keyframe", snapshot))

    def add_frame(self, snapshot: KeyframeSnapshot) -> None:
        self.calls.append(("frame", snapshot))

    def correct_poses(self, poses_wc: dict[int, np.ndarray]) -> None:
        self.calls.append(("poses", dict(poses_wc)))

    def finish(self, out_dir: Path) -> dict[str, Path]:
        self.calls.append(("finish", out_dir))
        return {}

    def stats(self) -> dict[str, float]:
        return {}

    def close(self) -> None:
        self.calls.append(("close", None))

    def of(self, kind: str) -> list[object]:
        return [arg for name, arg in self.calls if name == kind]


class ScriptedTracker:
    """A ``Tracker`` that makes a keyframe every third frame, moves keyframe 0 at frame 4
    and reports final poses of its own at shutdown; it sees no map builder."""

    has_map = False

    def __init__(self, inputs: TrackerInputs) -> None:
        self.inputs = inputs
        self.keyframes: dict[int, float] = {}
        self.stopped = False

    def prepare(self, frame: Frame) -> None:
        pass

    def track(self, packet: FramePacket) -> TrackResult:
        frame = packet.frame
        pose = np.eye(4)
        pose[0, 3] = frame.index
        event = None
        if frame.index % 3 == 0:
            event = KeyframeEvent(len(self.keyframes), frame.timestamp, pose)
            self.keyframes[event.id] = frame.timestamp
        corrected = {0: np.full((4, 4), 4.0)} if frame.index == 4 else None
        dynamic = np.zeros(frame.shape, bool)
        return TrackResult(frame.timestamp, pose, TrackingState.OK, is_keyframe=event is not None, dynamic=dynamic,
                           keyframe=event, corrected_poses=corrected)

    @property
    def n_keyframes(self) -> int:
        return len(self.keyframes)

    def trajectory(self) -> Trajectory:
        return Trajectory.from_poses([])

    def keyframe_trajectory(self) -> Trajectory:
        return Trajectory.from_poses([])

    def map_points(self) -> np.ndarray:
        return np.zeros((0, 3))

    def stats(self) -> dict[str, object]:
        return {}

    def save_map(self, path: Path) -> None:
        raise AssertionError("not asked for")

    def shutdown(self) -> None:
        self.stopped = True

    def final_keyframe_poses(self) -> dict[int, np.ndarray]:
        assert self.stopped, "the final poses are asked for after the tracker's final optimisation"
        return {k: np.full((4, 4), float(k)) for k in self.keyframes}


def _scripted(monkeypatch: pytest.MonkeyPatch, maps: RecordingMaps) -> None:
    """The System's assembly with the scripted tracker and the recording maps."""
    real_load = semslam.assembly.registry.load

    def load(kind: str, name: str) -> object:
        if kind == "tracker":
            return lambda config, camera, inputs, map_path: ScriptedTracker(inputs)
        return real_load(kind, name)

    monkeypatch.setattr(semslam.assembly.registry, "load", load)
    monkeypatch.setattr(semslam.assembly, "create_map_stage", lambda config: maps)


def _frames(n: int) -> list[Frame]:
    rng = np.random.default_rng(0)
    return [Frame(i, 0.1 * i, rng.integers(0, 255, (48, 64, 3), np.uint8), np.full((48, 64), 2.0, np.float32))
            for i in range(n)]


def test_the_maps_get_what_the_results_announce_and_the_final_poses(monkeypatch: pytest.MonkeyPatch) -> None:
    maps = RecordingMaps()
    _scripted(monkeypatch, maps)
    system = System("orb", CAMERA, overrides={"slam.sequential": True})
    assert isinstance(system.tracker, Tracker) and isinstance(maps, MapStage)
    assert not hasattr(system.tracker.inputs, "map_builders")  # trackers never see the builders
    frames = _frames(8)
    results = [system.track_frame(system.prepare(f)) for f in frames]
    announced = [r.keyframe for r in results if r.keyframe is not None]
    fed = maps.of("keyframe")
    assert [s.keyframe_id for s in fed] == [e.id for e in announced] == [0, 1, 2]
    for snap, event in zip(fed, announced):
        assert isinstance(snap, KeyframeSnapshot)
        assert snap.T_wc is event.T_wc and snap.timestamp == event.timestamp
        assert snap.rgb is frames[int(round(event.timestamp * 10))].rgb  # no copy of the image
        assert snap.depth is not None and snap.dynamic is not None
    assert maps.of("frame") == []  # the maps did not ask for every frame
    assert len(maps.of("poses")) == 1 and list(maps.of("poses")[0]) == [0]  # frame 4's correction
    system.close()
    final = maps.of("poses")[-1]
    assert sorted(final) == [0, 1, 2] and all((final[k] == k).all() for k in final)
    assert [name for name, _ in maps.calls[-2:]] == ["poses", "close"]
    system.close()  # twice: nothing more reaches the maps
    assert [name for name, _ in maps.calls[-2:]] == ["poses", "close"]


def test_maps_that_want_every_frame_get_the_tracked_frames_between_keyframes(monkeypatch: pytest.MonkeyPatch) -> None:
    maps = RecordingMaps(wants_frames=True)
    _scripted(monkeypatch, maps)
    with System("orb", CAMERA, overrides={"slam.sequential": True}) as system:
        for f in _frames(5):
            system.track_frame(system.prepare(f))
    assert [s.keyframe_id for s in maps.of("keyframe")] == [0, 1]
    assert [s.timestamp for s in maps.of("frame")] == [0.1, 0.2, 0.4]
    assert all(s.keyframe_id == -1 for s in maps.of("frame"))


def test_a_packet_cannot_be_changed() -> None:
    packet = FramePacket(_frames(1)[0], sharpness=3.0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        packet.sharpness = 1.0  # type: ignore[misc]
    with pytest.raises(dataclasses.FrozenInstanceError):
        packet.dynamic = np.zeros((48, 64), bool)  # type: ignore[attr-defined]


@pytest.mark.slow
def test_orb_keyframes_reach_the_maps_once_with_their_final_poses(monkeypatch: pytest.MonkeyPatch) -> None:
    """The ORB tracker on a render: every keyframe it announces reaches the maps once, and
    the final poses are the tracker's after its final optimisation."""
    cfg = SEQUENCES["static_xyz"].replace(frames=30)
    renderer = Renderer(cfg)
    maps = RecordingMaps()
    monkeypatch.setattr(semslam.assembly, "create_map_stage", lambda config: maps)
    config: SystemConfig = load_config("orb", ["slam.sequential=true"])
    system = System(config, PinholeCamera(*cfg.intrinsics()))
    announced = [r.keyframe.id for f in rendered_frames(renderer, range(30))
                 if (r := system.track_frame(system.prepare(f))).keyframe is not None]
    system.close()
    assert len(announced) >= 2
    assert [s.keyframe_id for s in maps.of("keyframe")] == announced
    final = maps.of("poses")[-1]
    expected = system.tracker.final_keyframe_poses()
    assert sorted(final) == sorted(announced) and all(np.array_equal(final[k], expected[k]) for k in final)
