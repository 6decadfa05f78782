"""The core's contracts and wiring: every backend implements its protocol, the registry
names the key to change, the System owns and closes what it builds, worker waits use a
condition, failures are counted or end the run with one line after writing what exists,
lost frames are left out of the trajectory, and map builders get keyframe snapshots whose
points land on the scene (checked against the renderer's exact geometry).
"""

from __future__ import annotations

import json
import multiprocessing
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from semslam.api import System
from semslam.cli.main import main
from semslam.config import DepthConfig, FeatureConfig, SemanticsConfig, load_config
from semslam.core import protocols, registry
from semslam.core.protocols import FramePacket, KeyframeSnapshot, TrackerInputs
from semslam.core.types import Frame, TrackingState
from semslam.errors import ConfigError, DataError
from semslam.features import create_extractor
from semslam.features.matching import matcher_for
from semslam.geometry.camera import PinholeCamera
from semslam.io.depth import SensorDepth
from semslam.io.sequence import ImageFolderSequence, open_sequence
from semslam.reconstruction.keyframe_cloud import KeyframeCloud
from semslam.slam.orb.keyframe_worker import KeyframeInbox
from semslam.synth import SEQUENCES, Renderer, render_sequence

CAM = PinholeCamera(535.4, 539.2, 320.1, 247.6, width=640, height=480)  # sized: the System is built at once


@pytest.fixture(scope="module")
def static_seq(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return render_sequence(SEQUENCES["static_xyz"].replace(frames=60), tmp_path_factory.mktemp("wiring") / "static")


# ---------------------------------------------------------------- contracts
def test_backends_implement_their_contracts(static_seq: Path) -> None:
    seq = open_sequence(static_seq)
    assert isinstance(seq, protocols.SequenceSource)
    assert isinstance(ImageFolderSequence(static_seq / "rgb"), protocols.SequenceSource)
    assert isinstance(registry.create("depth_source", "sensor", DepthConfig()), protocols.DepthSource)
    assert isinstance(registry.create("map_builder", "keyframe_cloud"), protocols.MapBuilder)
    gt = registry.create("segmenter", "ground_truth", SemanticsConfig(backend="ground_truth"))
    assert isinstance(gt, protocols.Segmenter)
    for name in registry.names("extractor"):
        extractor = create_extractor(FeatureConfig(extractor=name, n_levels=6 if name == "qtree_orb" else 8), (640, 480))
        assert isinstance(extractor, protocols.Extractor) and extractor.spec.n_levels >= 1, name
        matcher = registry.create("matcher", extractor.spec.kind.value)
        assert isinstance(matcher, protocols.Matcher) and type(matcher) is type(matcher_for(extractor.spec)), name
    for preset in ("orb", "f2kf", "ddl"):
        overrides = ["slam.sequential=true"] + (["semantics.backend=ground_truth"] if preset == "ddl" else [])
        system = System(load_config(preset, overrides), seq.camera)
        try:
            assert isinstance(system.tracker, protocols.Tracker)
            if preset == "ddl":
                assert isinstance(system.dynamics, protocols.DynamicStage)
        finally:
            system.close()


def test_registry_errors_name_the_key() -> None:
    with pytest.raises(ConfigError, match=r"tracking\.method: unknown tracker 'nope' \(known: frame_to_keyframe, orb_slam, sdf_slam\)"):
        System(load_config("orb", ["tracking.method=nope"]), CAM)
    with pytest.raises(ConfigError, match=r"maps\.builders: unknown map_builder 'octopus' \(known: cloud, "):
        System(load_config("orb", ["maps.builders=[octopus]"]), CAM)
    with pytest.raises(ConfigError, match=r"sensor: unknown sensor 'lidar' \(known: rgbd, mono, stereo\)"):
        load_config("orb", ["sensor=lidar"])


def test_mono_sensor_runs_the_orb_core_without_depth_and_is_refused_by_f2kf() -> None:
    # orb_slam runs mono frames with no depth at all (two-view initialisation); f2kf needs depth.
    system = System(load_config("orb", ["sensor=mono"]), CAM)
    try:
        assert system.tracker.tracking.mono_init is not None
    finally:
        system.close()
    with pytest.raises(ConfigError, match=r"monocular: tracking\.method=sdf_slam"):
        System(load_config("f2kf", ["sensor=mono"]), CAM)


def test_monocular_folder_and_save_map_are_refused_before_the_run(
        static_seq: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # An image folder without depth: one line, exit 2, not an empty trajectory.
    assert main(["run", str(static_seq / "rgb"), "--out", str(tmp_path / "mono"), "-q", "--preset", "orb"]) == 2
    err = capsys.readouterr().err
    assert "no depth images" in err and "sensor: mono" in err and len(err.strip().splitlines()) == 1
    # --save-map with a tracker that has no map: refused before any frame is tracked (a run
    # would have written its trajectory and stats, even an interrupted one).
    assert main(["run", str(static_seq), "--out", str(tmp_path / "f2kf"), "-q", "--preset", "f2kf",
                 "--save-map", str(tmp_path / "m.npz")]) == 2
    assert "--save-map needs a tracker with a map" in capsys.readouterr().err
    assert not (tmp_path / "f2kf" / "trajectory.txt").exists() and not (tmp_path / "f2kf" / "stats.json").exists()


# ---------------------------------------------------------------- resources
def _live_threads() -> set[str]:
    return {t.name for t in threading.enumerate() if t.is_alive()}


def test_failed_construction_leaves_no_thread_or_process(tmp_path: Path) -> None:
    """A segmenter that cannot be built (missing weights) fails before any BA process or
    worker thread exists; a threaded system's shutdown ends them all."""
    before_threads, before_procs = _live_threads(), len(multiprocessing.active_children())
    with pytest.raises(DataError, match="network weights not found"):
        System(load_config("stdc", ["semantics.backend=stdc", f"semantics.weights={tmp_path / 'none.pt'}"]), CAM)
    assert _live_threads() <= before_threads and len(multiprocessing.active_children()) == before_procs
    system = System(load_config("orb"), CAM)  # threads + BA worker process
    assert len(multiprocessing.active_children()) == before_procs + 1
    system.close()
    system.close()  # idempotent
    assert len(multiprocessing.active_children()) == before_procs
    assert not any(n in ("local-mapping", "loop-closing") for n in _live_threads())


def test_inbox_wait_idle_wakes_on_done_and_times_out() -> None:
    inbox = KeyframeInbox()
    assert inbox.wait_idle(timeout=0.01)
    inbox.put(object())  # type: ignore[arg-type]
    assert inbox.queue_size() == 1 and not inbox.idle()
    assert not inbox.wait_idle(timeout=0.05)  # busy: times out

    def worker() -> None:
        inbox.take()
        time.sleep(0.05)
        inbox.done()

    threading.Thread(target=worker).start()
    assert inbox.wait_idle(timeout=5.0)  # True: idle came before the timeout
    assert inbox.idle()
    inbox.close()
    assert inbox.take() is None


def test_inbox_pause_waits_for_the_keyframe_in_hand_and_holds_the_queue() -> None:
    """ORB-SLAM's RequestStop / Release: the worker finishes what it holds, takes nothing
    while paused, and goes on afterwards."""
    inbox = KeyframeInbox()
    log: list[str] = []
    started = threading.Event()

    def worker() -> None:
        while (item := inbox.take()) is not None:
            log.append(f"start {item}")
            started.set()
            time.sleep(0.05)
            log.append(f"end {item}")
            inbox.done()

    thread = threading.Thread(target=worker)
    thread.start()
    inbox.put("a")  # type: ignore[arg-type]
    assert started.wait(5.0)
    with inbox.paused(timeout=5.0) as ok:
        assert ok and log == ["start a", "end a"]  # waited for "a" to finish
        inbox.put("b")  # type: ignore[arg-type]
        time.sleep(0.1)
        assert log == ["start a", "end a"] and inbox.queue_size() == 1  # not taken while paused
        log.append("paused section")
    assert inbox.wait_idle(timeout=5.0)
    assert log == ["start a", "end a", "paused section", "start b", "end b"]
    with inbox.paused(timeout=0.01) as ok:  # idle worker: immediately
        assert ok
    inbox.close()
    thread.join(5.0)
    assert not thread.is_alive()


# ---------------------------------------------------------------- failures
def test_worker_exception_ends_the_run_with_one_line_after_writing(
        static_seq: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    from semslam.slam.orb.local_mapping import LocalMapping

    def boom(self: LocalMapping, kf: object) -> None:
        raise RuntimeError("injected failure")

    monkeypatch.setattr(LocalMapping, "_local_bundle_adjustment", boom)
    out = tmp_path / "run"
    assert main(["run", str(static_seq), "--out", str(out), "-q", "--preset", "orb", "--no-report"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["error: local-mapping thread failed: RuntimeError: injected failure"]
    stats = json.loads((out / "stats.json").read_text())
    assert "injected failure" in stats["error"] and (out / "trajectory.txt").is_file()
    assert len(multiprocessing.active_children()) == 0


def test_failed_ba_is_counted_not_reported_as_run(monkeypatch: pytest.MonkeyPatch) -> None:
    import gtsam

    from semslam.backend import bundle_adjustment as ba

    rng = np.random.default_rng(0)
    pts = rng.uniform([-1, -1, 3], [1, 1, 5], (30, 3))
    poses = np.stack([np.eye(4), np.eye(4)])
    poses[1, 0, 3] = -0.2
    obs_pose = np.repeat([0, 1], 30)
    obs_point = np.tile(np.arange(30), 2)
    pc = np.einsum("kij,kj->ki", poses[obs_pose, :3, :3], pts[obs_point]) + poses[obs_pose, :3, 3]
    uv = np.c_[500 * pc[:, 0] / pc[:, 2] + 320, 500 * pc[:, 1] / pc[:, 2] + 240]
    problem = ba.BAProblem(poses, np.array([True, False]), pts, obs_pose, obs_point, uv, -np.ones(60), np.ones(60),
                           500.0, 500.0, 320.0, 240.0, 40.0)
    assert ba.bundle_adjust(problem).converged

    class Failing:
        def __init__(self, *args: object) -> None:
            pass

        def optimize(self) -> None:
            raise RuntimeError("Indeterminant linear system")

    monkeypatch.setattr(gtsam, "LevenbergMarquardtOptimizer", Failing)
    result = ba.bundle_adjust(problem, solver="gtsam")
    assert not result.converged
    np.testing.assert_array_equal(result.poses_cw, poses)  # estimate left unchanged

    def no_step(R, t, X, *args):  # the Schur solver found no positive definite damped system
        return R, t, X, 1, False, 0.0, 0.0

    monkeypatch.setattr(ba, "levenberg_marquardt", no_step)
    result = ba.bundle_adjust(problem, solver="schur")
    assert not result.converged
    np.testing.assert_array_equal(result.poses_cw, poses)


# ---------------------------------------------------------------- trajectories and maps
def test_lost_frames_are_left_out_of_the_trajectory(static_seq: Path) -> None:
    seq = open_sequence(static_seq)
    frames = list(seq.frames(0, 40))
    black = [Frame(100 + k, frames[-1].timestamp + 0.01 * (k + 1), np.zeros_like(frames[0].rgb),
                   np.zeros_like(frames[0].depth)) for k in range(5)]
    for preset in ("orb", "f2kf"):
        system = System(load_config(preset, ["slam.sequential=true"]), seq.camera)
        results = [system.track_frame(system.prepare(f)) for f in [*frames, *black]]
        system.close()
        lost = [r for r in results if r.state is TrackingState.LOST]
        assert len(lost) == 5 and all(r.pose_wc is None for r in lost), preset
        traj = system.trajectory()
        assert len(traj) == 40 and traj.timestamps.max() == frames[-1].timestamp, preset


def test_keyframe_cloud_lands_on_the_scene(static_seq: Path, tmp_path: Path) -> None:
    """Every keyframe's depth, placed with its final SLAM pose and moved into the ground
    truth's world, must lie on the rendered surfaces: re-projected into a frame's exact
    (noise-free) depth, the median disagreement is the sensor noise plus millimetres."""
    out = tmp_path / "run"
    assert main(["run", str(static_seq), "--out", str(out), "-q", "--preset", "orb", "--sequential", "--no-report",
                 "--set", "maps.builders=[keyframe_cloud]"]) == 0
    from plyfile import PlyData

    v = PlyData.read(str(out / "map" / "keyframe_cloud.ply"))["vertex"]
    xyz = np.stack([v["x"], v["y"], v["z"]], axis=1).astype(np.float64)
    assert len(xyz) > 10_000
    cfg = SEQUENCES["static_xyz"].replace(frames=60)
    r = Renderer(cfg)
    T_gt0 = r.poses[0]  # SLAM's world is the first camera
    world = xyz @ T_gt0[:3, :3].T + T_gt0[:3, 3]
    k = 30
    T_cw = np.linalg.inv(r.poses[k])
    pc = world @ T_cw[:3, :3].T + T_cw[:3, 3]
    cam = PinholeCamera(*cfg.intrinsics(), width=cfg.width, height=cfg.height)
    front = pc[:, 2] > 0.1
    uv = cam.project(pc[front])
    inside = cam.in_image(uv)
    u, vv = uv[inside].astype(int).T
    exact = r.render(k).z.astype(np.float64)[vv, u]  # exact z-depth of the rendered scene
    z = pc[front][inside, 2]
    ok = np.isfinite(exact)
    visible = z[ok] <= exact[ok] + 0.05  # points hidden behind a nearer surface are not compared
    err = np.abs(z[ok][visible] - exact[ok][visible])
    # The keyframes' own depth noise (Kinect-like, ~1.2 cm median at the 3.4 m of this scene)
    # is the floor; the SLAM poses may add at most a few millimetres on top of it.
    f0 = r.render(0)
    d0, valid0 = f0.depth / 5000.0, (f0.depth > 0) & np.isfinite(f0.z)
    noise = float(np.median(np.abs(d0[valid0] - f0.z[valid0])))
    assert visible.sum() > 5000 and np.median(err) < noise + 0.004, (np.median(err), noise)


def test_keyframe_cloud_leaves_out_dynamic_pixels_and_follows_corrections() -> None:
    cam = PinholeCamera(100.0, 100.0, 15.5, 11.5, width=32, height=24)
    depth = np.full((24, 32), 2.0, np.float32)
    dynamic = np.zeros((24, 32), bool)
    dynamic[:, :16] = True
    rgb = np.zeros((24, 32, 3), np.uint8)
    builder = KeyframeCloud(stride=1)
    builder.add_keyframe(KeyframeSnapshot(7, 0.0, np.eye(4), rgb, depth, dynamic, None, cam))
    xyz, _ = builder.cloud()
    assert len(xyz) == 16 * 24 and (xyz[:, 0] > 0).all() and np.allclose(xyz[:, 2], 2.0)
    moved = np.eye(4)
    moved[:3, 3] = [1.0, 2.0, 3.0]
    builder.correct_poses({7: moved, 99: np.eye(4)})
    xyz2, _ = builder.cloud()
    np.testing.assert_allclose(xyz2, xyz + [1.0, 2.0, 3.0])


def test_the_tracker_takes_its_depth_from_its_source(static_seq: Path) -> None:
    seq = open_sequence(static_seq)
    calls = []

    class CountingDepth(SensorDepth):
        def depth(self, frame: Frame) -> np.ndarray | None:
            calls.append(frame.index)
            return super().depth(frame)

    from semslam.slam.orb.tracker import OrbTracker

    tracker = OrbTracker(load_config("orb", ["slam.sequential=true"]), seq.camera, TrackerInputs(CountingDepth()))
    frames = list(seq.frames(0, 5))
    for f in frames:
        tracker.track(FramePacket(f))
    tracker.shutdown()
    assert calls == [f.index for f in frames]


def test_tracking_marks_its_frames_and_local_mapping_waits_for_the_gap(static_seq: Path) -> None:
    """Map.tracking_idle is clear exactly while tracking works on a frame; a threaded local
    mapping waits for it before a step, at most slam.yield_to_tracking_ms."""
    seq = open_sequence(static_seq)
    system = System(load_config("orb", ["slam.yield_to_tracking_ms=1000"]), seq.camera)
    try:
        tracker = system.tracker
        idle = tracker.map.tracking_idle
        seen: list[bool] = []
        extract = tracker.tracking.extractor.extract

        def spy(*args, **kwargs):  # type: ignore[no-untyped-def]
            seen.append(idle.is_set())
            return extract(*args, **kwargs)

        tracker.tracking.extractor.extract = spy  # type: ignore[method-assign]
        for f in seq.frames(0, 3):
            system.track_frame(system.prepare(f))
        assert seen == [False, False, False] and idle.is_set()
        mapping = tracker.mapper
        idle.clear()
        t0 = time.perf_counter()
        mapping.yield_to_tracking()
        assert time.perf_counter() - t0 >= 0.99  # waited for the frame, up to the bound
        idle.set()
        t0 = time.perf_counter()
        mapping.yield_to_tracking()
        assert time.perf_counter() - t0 < 0.5  # no frame in progress: no wait (else 1 s)
    finally:
        system.close()
    with pytest.raises(ConfigError, match="slam.yield_to_tracking_ms"):
        load_config("orb", ["slam.yield_to_tracking_ms=-1"])


def test_frames_after_initialisation_track_while_local_mapping_lags(static_seq: Path) -> None:
    """On a slow machine local mapping may not have reached the first keyframe (its bag of
    words) when frame 1 is tracked against it: the frame must still track, not be lost."""
    seq = open_sequence(static_seq)
    system = System(load_config("orb"), seq.camera)
    try:
        frames = list(seq.frames(0, 4))
        with system.tracker.mapper.inbox.paused() as ok:  # the first keyframe waits in the queue
            assert ok
            results = [system.track_frame(system.prepare(f)) for f in frames]
        assert [r.state for r in results[1:]] == [TrackingState.OK] * 3
    finally:
        system.close()
