"""The maps' worker: the same maps in a worker process as inline, in the order the SLAM
system issued keyframes and corrections; a failing builder stops the run with a clear error;
``semslam map`` rebuilds a finished run's maps from its final keyframe poses."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from plyfile import PlyData

from semslam.config import MapsConfig
from semslam.core.protocols import KeyframeSnapshot
from semslam.core.types import LabelMap
from semslam.errors import ConfigError, WorkerFailed
from semslam.geometry.camera import PinholeCamera
from semslam.reconstruction.mapping_worker import MappingWorker
from tests.conftest import run_cli

CAM = PinholeCamera(50.0, 50.0, 15.5, 11.5, width=32, height=24)


def _snapshots(n: int) -> list[KeyframeSnapshot]:
    rng = np.random.default_rng(1)
    out = []
    for k in range(n):
        T = np.eye(4)
        T[:3, 3] = [0.1 * k, 0.0, 0.0]
        depth = rng.uniform(1.0, 3.0, (24, 32)).astype(np.float32)
        rgb = rng.integers(0, 255, (24, 32, 3), dtype=np.uint8)
        out.append(KeyframeSnapshot(k, float(k), T, rgb, depth, None, None, CAM))
    return out


def _xyz(path: Path) -> np.ndarray:
    v = PlyData.read(str(path))["vertex"]
    return np.stack([v["x"], v["y"], v["z"]], axis=1)


def _cfg() -> MapsConfig:
    cfg = MapsConfig(builders=["keyframe_cloud"])
    cfg.inpainting.enabled = False
    return cfg


@pytest.mark.parametrize("threaded", [False, True])
def test_worker_builds_the_maps_with_corrections_applied_in_order(tmp_path: Path, threaded: bool) -> None:
    worker = MappingWorker(["keyframe_cloud"], _cfg(), threaded=threaded)
    try:
        snaps = _snapshots(3)
        for s in snaps[:2]:
            worker.add_keyframe(s)
        moved = np.eye(4)
        moved[:3, 3] = [0.0, 0.0, 5.0]
        worker.correct_poses({0: moved})  # after keyframes 0 and 1, before 2
        worker.add_keyframe(snaps[2])
        paths = worker.finish(tmp_path)
    finally:
        worker.close()
    xyz = _xyz(paths["keyframe_cloud"])
    # keyframe_cloud keeps a stride-4 grid: 8 x 6 pixels per keyframe, all valid.
    per_kf = 8 * 6
    assert len(xyz) == 3 * per_kf
    z0 = xyz[:per_kf, 2]
    assert z0.min() > 5.0  # keyframe 0 moved 5 m along z by the correction
    stats = worker.stats()
    assert stats["map_keyframes"] == 3 and stats["map_queue_max"] >= (1 if threaded else 0)


def test_worker_refuses_an_unknown_map_before_any_frame() -> None:
    with pytest.raises(ConfigError, match="maps.builders"):
        MappingWorker(["octopus"], _cfg(), threaded=False)


def test_a_failing_builder_surfaces_as_worker_failed(tmp_path: Path) -> None:
    worker = MappingWorker(["keyframe_cloud"], _cfg(), threaded=True)
    try:
        bad = _snapshots(1)[0]
        bad.depth = np.ones((48, 64), np.float32)  # larger than its image: the builder raises in the worker
        worker.add_keyframe(bad)
        with pytest.raises(WorkerFailed, match="mapping worker failed"):
            worker.finish(tmp_path)
    finally:
        worker.close()


@pytest.mark.slow
def test_semslam_map_rebuilds_the_run_maps(static_render: Path, tmp_path: Path) -> None:
    """Offline from keyframes.txt, the same cloud as the live (sequential) run wrote."""
    from semslam.cli.main import main

    out = tmp_path / "run"
    run_cli(static_render, out, "--preset", "orb", "--sequential", "--no-report", "--max-frames", "40",
            "--map", "keyframe_cloud", "--set", "maps.inpainting.enabled=false")
    live = _xyz(out / "map" / "keyframe_cloud.ply")
    assert main(["map", str(out), "--out", str(tmp_path / "offline"), "--quiet"]) == 0
    offline = _xyz(tmp_path / "offline" / "keyframe_cloud.ply")
    # keyframes.txt holds the final poses with 9 decimals: the same points to ~1e-6 m.
    assert live.shape == offline.shape and len(live) > 1000
    np.testing.assert_allclose(offline, live, atol=1e-4)


def test_semslam_map_names_what_is_missing(tmp_path: Path) -> None:
    from semslam.cli.main import main

    assert main(["map", str(tmp_path), "--quiet"]) == 2


@pytest.mark.parametrize("mask_dynamic", [True, False])
def test_dynamic_pixels_stay_out_of_the_maps_unless_told(tmp_path: Path, mask_dynamic: bool) -> None:
    cfg = _cfg()
    cfg.mask_dynamic = mask_dynamic
    snap = _snapshots(1)[0]
    snap.dynamic = np.zeros((24, 32), bool)
    snap.dynamic[:, :16] = True  # the left half: a person
    worker = MappingWorker(["keyframe_cloud"], cfg, threaded=False)
    try:
        worker.add_keyframe(snap)
        n = len(_xyz(worker.finish(tmp_path)["keyframe_cloud"]))
    finally:
        worker.close()
    assert n == (4 * 6 if mask_dynamic else 8 * 6)


class Boom:
    """A map builder that fails on its second keyframe."""

    def __init__(self, cfg: MapsConfig) -> None:
        self.n = 0

    def add_keyframe(self, snapshot: KeyframeSnapshot) -> None:
        self.n += 1
        if self.n == 2:
            raise RuntimeError("disk full")

    def correct_poses(self, poses_wc: dict) -> None: ...

    def finish(self, out_dir: Path) -> dict[str, Path]:
        return {}

    def close(self) -> None: ...


@pytest.mark.slow
def test_a_failed_map_still_leaves_the_trajectory_and_stats(static_render: Path, tmp_path: Path,
                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    import json

    from semslam.cli.main import main
    from semslam.core import registry

    monkeypatch.setitem(registry.PLUGINS["map_builder"], "boom", "tests.test_mapping_worker:Boom")
    out = tmp_path / "run"
    rc = main(["run", str(static_render), "--out", str(out), "--quiet", "--no-report", "--preset", "orb",
               "--sequential", "--max-frames", "30", "--map", "boom"])
    assert rc == 2  # one line, no traceback
    stats = json.loads((out / "stats.json").read_text())
    assert "disk full" in stats["error"] and stats["tracked_frames"] == 30
    assert (out / "trajectory.txt").read_text().count("\n") >= 30


class HalfPerson:
    """A segmenter that sees a person in the left half of every image."""

    name = "half_person"
    names = {0: "background", 15: "person"}

    def __init__(self, cfg: object) -> None: ...

    def segment(self, rgb: np.ndarray, frame: object = None) -> LabelMap:
        labels = np.zeros(rgb.shape[:2], np.uint8)
        labels[:, : rgb.shape[1] // 2] = 15
        return LabelMap(labels, dict(self.names))

    def close(self) -> None: ...


def test_keyframes_tracking_did_not_segment_are_segmented_for_the_maps(tmp_path: Path,
                                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    from semslam.config import SemanticsConfig
    from semslam.core import registry

    monkeypatch.setitem(registry.PLUGINS["segmenter"], "half_person", "tests.test_mapping_worker:HalfPerson")
    worker = MappingWorker(["keyframe_cloud"], _cfg(), threaded=False,
                           semantics=SemanticsConfig(backend="half_person"))
    try:
        warped, own = _snapshots(2)
        warped.dynamic = np.zeros((24, 32), bool)  # its mask came warped: no labels of its own
        own.labels = LabelMap(np.zeros((24, 32), np.uint8), {0: "background"})  # segmented: nobody there
        worker.add_keyframe(warped)
        worker.add_keyframe(own)
        n = len(_xyz(worker.finish(tmp_path)["keyframe_cloud"]))
        assert worker.stats()["map_segmented_keyframes"] == 1
    finally:
        worker.close()
    assert n == 4 * 6 + 8 * 6  # the left half of the first keyframe left out, all of the second kept


def test_a_dead_worker_process_does_not_stop_tracking(tmp_path: Path) -> None:
    """The maps' process killed mid-run: later keyframes are dropped, finish says why."""
    import os
    import signal

    worker = MappingWorker(["keyframe_cloud"], _cfg(), threaded=True)
    try:
        snaps = _snapshots(3)
        worker.add_keyframe(snaps[0])
        pool = worker._pool
        assert pool is not None
        pid = pool.submit(os.getpid).result()
        os.kill(pid, signal.SIGKILL)
        for s in snaps[1:]:
            worker.add_keyframe(s)  # must not raise
        with pytest.raises(WorkerFailed, match="mapping worker failed"):
            worker.finish(tmp_path)
    finally:
        worker.close()
