"""``semslam.System`` driven as a camera would drive it: a synthetic render read back with
OpenCV (BGR colour, uint16 depth PNGs), fed frame by frame. The references are independent:
``semslam run`` on the same folder (sequential runs are deterministic: the same trajectory
to the last digit), the render's exact ground truth, and evo reading what ``save`` wrote."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest

from semslam import System
from semslam.config import load_config
from semslam.errors import ConfigError, DataError, SemslamError
from semslam.io.association import match_timestamps
from semslam.io.sequence import read_file_list
from tests.conftest import evo_ate, run_cli
from tests.test_interrupt import wait_gone

FRAMES = 40
NO_MAPS = {"slam.sequential": True, "maps.builders": []}


@pytest.fixture(scope="module")
def render(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``semslam synth OUT --sequence static_xyz -n 40``, once for the module."""
    from semslam.cli.main import main

    out = tmp_path_factory.mktemp("api") / "static_xyz"
    assert main(["synth", str(out), "--sequence", "static_xyz", "-n", str(FRAMES), "--quiet"]) == 0
    return out


def camera_frames(seq: Path) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """The render as an RGB-D camera gives it: BGR colour, uint16 depth (5000 per metre)."""
    colour, depth = read_file_list(seq / "rgb.txt"), read_file_list(seq / "depth.txt")
    i_colour, i_depth = match_timestamps([e.timestamp for e in colour], [e.timestamp for e in depth])
    assert len(i_colour) == FRAMES  # every colour image has its depth image (as semslam run pairs them)
    return [(cv2.imread(str(colour[i].path), cv2.IMREAD_COLOR), cv2.imread(str(depth[j].path), cv2.IMREAD_UNCHANGED),
             colour[i].timestamp) for i, j in zip(i_colour, i_depth)]


@pytest.fixture(scope="module")
def frames(render: Path) -> list[tuple[np.ndarray, np.ndarray, float]]:
    return camera_frames(render)


def test_import_semslam_stays_cheap() -> None:
    code = "import sys, semslam; print(sorted(m for m in ('semslam.api', 'cv2', 'numpy') if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=Path(__file__).resolve().parents[1]).stdout
    assert out.strip() == "[]"


@pytest.mark.slow
@pytest.mark.parametrize("preset", ["orb", "default"])
def test_api_run_equals_semslam_run(render: Path, frames: list, tmp_path: Path, preset: str) -> None:
    """Frame by frame through the API = ``semslam run --sequential`` on the folder: the same
    poses, the same ATE; the trajectory, the stats and the map answer at every frame."""
    if preset == "default":
        pytest.importorskip("mediapipe")
    cli = run_cli(render, tmp_path / "cli", "--preset", preset, "--sequential", "--map", "none")
    with System(preset, camera=render / "calib.txt", bgr=True, overrides=NO_MAPS, name=str(render)) as slam:
        posed: list[float] = []
        for i, (bgr, depth, t) in enumerate(frames):
            result = slam.track(bgr, depth, t)
            if result.pose_wc is not None:
                assert result.pose_wc.shape == (4, 4)
                posed.append(t)
            traj = slam.trajectory()  # at any time: one pose per frame tracked so far
            assert np.array_equal(traj.timestamps, posed)
            if i in (5, 25):
                stats = slam.stats()
                assert stats["frames"] == i + 1 and stats["tracked_frames"] == len(posed)
                assert stats["ms_per_frame"]["median"] > 0 and stats["keyframes"] == len(slam.keyframes()) >= 1
                assert slam.map_points().shape == (stats["map_points"], 3)
        result_all = slam.save(tmp_path / "api", groundtruth=render / "groundtruth.txt")
    assert slam.closed
    assert result_all.tracked_frames == cli["tracked_frames"] == FRAMES
    assert result_all.ate_rmse == cli["ate"]["rmse"] < 0.02  # deterministic: equal, not close
    assert abs(result_all.ate_rmse - evo_ate(render / "groundtruth.txt", tmp_path / "api" / "trajectory.txt")) < 1e-9
    assert (tmp_path / "api" / "report.html").is_file()
    assert (tmp_path / "api" / "trajectory.txt").read_text() == (tmp_path / "cli" / "trajectory.txt").read_text()
    api_stats = json.loads((tmp_path / "api" / "stats.json").read_text())
    assert set(api_stats) == set(cli)  # the same fields
    assert api_stats["camera"] == cli["camera"] and api_stats["sequence"] == cli["sequence"]


def test_close_stops_every_worker(render: Path, frames: list) -> None:
    """Threaded, as live: close() (no outputs asked for) stops the BA worker process and the
    local mapping and loop closing threads."""
    before = set(threading.enumerate())
    kids_before = set(_children(os.getpid()))
    slam = System("orb", camera=render / "calib.txt", bgr=True)
    for bgr, depth, t in frames[:8]:
        slam.track(bgr, depth, t)
    kids = _new_workers(kids_before)
    assert kids, "a threaded run has a BA worker process"
    assert [t for t in set(threading.enumerate()) - before if t.is_alive()], "and threads"
    slam.close()
    slam.close()  # twice is fine
    assert not wait_gone(kids), "a worker process outlived close()"
    assert not [t for t in set(threading.enumerate()) - before if t.is_alive()], "a thread outlived close()"
    assert len(slam.trajectory()) == 8  # still answers


@pytest.mark.slow
def test_save_writes_what_evo_reads(render: Path, frames: list, tmp_path: Path) -> None:
    """Threaded, with a map builder: ``out`` gets the outputs when the ``with`` block ends,
    evo reads them, and no worker process or thread outlives the block."""
    from evo.tools import file_interface

    before = set(threading.enumerate())
    kids_before = set(_children(os.getpid()))
    with System("orb", camera=render / "calib.txt", bgr=True, out=tmp_path / "run",
                overrides={"maps.builders": ["keyframe_cloud"]}) as slam:
        for bgr, depth, t in frames[:30]:
            slam.track(bgr, depth, t)
        kids = _new_workers(kids_before)
        assert len(kids) >= 2, "a BA worker and a maps' worker process"
        slam.save_trajectory(tmp_path / "so_far.txt")
    assert not wait_gone(kids), "a worker process outlived the block"
    assert not [t for t in set(threading.enumerate()) - before if t.is_alive()], "a thread outlived the block"
    assert file_interface.read_tum_trajectory_file(str(tmp_path / "so_far.txt")).num_poses == 30
    out = tmp_path / "run"
    stats = json.loads((out / "stats.json").read_text())
    traj = file_interface.read_tum_trajectory_file(str(out / "trajectory.txt"))
    kfs = file_interface.read_tum_trajectory_file(str(out / "keyframes.txt"))
    assert traj.num_poses == stats["tracked_frames"] == 30 and kfs.num_poses == stats["keyframes"] >= 2
    assert stats["threaded"] is True and Path(stats["paths"]["keyframe_cloud"]).stat().st_size > 1000
    split = stats["tracking_thread_ms"]  # the tracking thread's CPU (and on Linux its waits) per frame
    assert 0.0 < split["cpu"] <= stats["ms_per_frame"]["max"]
    assert all(v >= 0.0 for v in split.values())
    mapping = stats["local_mapping_cpu_ms"]  # local mapping's CPU per step, in total and per keyframe
    steps = {k: v for k, v in mapping.items() if k not in ("total", "per_keyframe")}
    assert mapping["total"] > 0.0 and mapping["total"] == pytest.approx(sum(steps.values()))
    assert mapping["per_keyframe"] <= mapping["total"] and "new_keyframe" in steps
    assert json.loads((out / "config.json").read_text())["maps"]["builders"] == ["keyframe_cloud"]


def _new_workers(before: set[int]) -> list[int]:
    return [p for p in set(_children(os.getpid())) - before if not _is_resource_tracker(p)]


def _children(pid: int) -> list[int]:
    kids = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            if int(stat.read_text().rsplit(")", 1)[1].split()[1]) == pid:
                kids.append(int(stat.parent.name))
        except (OSError, ValueError, IndexError):
            continue
    return kids


def _is_resource_tracker(pid: int) -> bool:
    """multiprocessing's resource tracker lives as long as the test process, by design."""
    try:
        return b"resource_tracker" in Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return True


@pytest.fixture()
def live(render: Path) -> Iterator[System]:
    slam = System("f2kf", camera=render / "calib.txt", bgr=True)
    yield slam
    slam.close()


def _bad_input_cases(frames: list) -> dict[str, tuple[tuple, str]]:
    bgr, depth, t = frames[0]
    return {
        "float colour": ((bgr.astype(np.float32), depth, t), "expected uint8"),
        "four channels": ((np.dstack([bgr, bgr[:, :, :1]]), depth, t), "expected HxWx3"),
        "not an array": ((bgr.tolist(), depth, t), "expected a numpy array"),
        "depth size": ((bgr, depth[:-2], t), f"depth is {depth.shape[1]}x{depth.shape[0] - 2} but rgb is"),
        "8-bit depth": ((bgr, depth.astype(np.uint8), t), "expected uint16"),
        "negative depth": ((bgr, -np.ones(depth.shape, np.float32), t), "negative values"),
        "no depth": ((bgr, None, t), "no depth: preset 'f2kf' is RGB-D"),
        "nan time": ((bgr, depth, float("nan")), "timestamp is not finite"),
        "image size": ((cv2.resize(bgr, (320, 240)), cv2.resize(depth, (320, 240)), t), "but the camera is 640x480"),
    }


def test_bad_inputs_give_one_line_errors(live: System, frames: list) -> None:
    bgr, depth, t = frames[0]
    live.track(bgr, depth, t)  # the first frame sets the image size
    for name, (args, words) in _bad_input_cases(frames[1:]).items():
        with pytest.raises(DataError) as info:
            live.track(*args)
        msg = str(info.value)
        assert words in msg and "\n" not in msg and msg.startswith("System.track (frame 1"), name
    with pytest.raises(DataError, match="timestamp .* is not after the previous frame's"):
        live.track(bgr, depth, t)
    assert live.track(*frames[1]).pose_wc is not None  # refused frames change nothing
    live.close()
    with pytest.raises(SemslamError, match="the system is closed"):
        live.track(*frames[2])


def test_bad_construction_is_a_config_error(render: Path) -> None:
    with pytest.raises(ConfigError, match="camera is required"):
        System("orb")
    with pytest.raises(ConfigError, match="unknown key 'no_such_key'"):
        System("orb", camera=(525, 525, 319.5, 239.5), overrides={"slam.no_such_key": 1})
    with pytest.raises(ConfigError, match="expected true/false"):
        System("orb", camera=(525, 525, 319.5, 239.5), overrides={"slam.loop_closing": "maybe"})
    with pytest.raises(ConfigError, match="expected 4 numbers"):
        System("orb", camera=(525, 525, 319.5))
    with pytest.raises(DataError, match="not found"):
        System("orb", camera=render / "no_calib.txt")
    with pytest.raises(ConfigError, match="no output folder"):
        System("orb", camera=(525, 525, 319.5, 239.5)).save()
    cfg = load_config("orb")
    cfg.features.n_features = -3  # a SystemConfig set by hand is checked as a preset is
    with pytest.raises(ConfigError, match=r"features.n_features: expected an integer in \[1, "):
        System(cfg, camera=(525, 525, 319.5, 239.5))


def test_rgb_and_bgr_and_metres_are_the_same_frame(render: Path, frames: list, tmp_path: Path) -> None:
    """RGB order with float metres gives exactly what BGR with uint16 TUM depth gives."""
    trajs = []
    for as_camera in (True, False):
        slam = System("f2kf", camera=render / "calib.txt", bgr=as_camera)
        for bgr, depth, t in frames[:8]:
            if as_camera:
                slam.track(bgr, depth, t)
            else:
                slam.track(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), depth.astype(np.float64) / 5000.0, t)
        trajs.append(slam.trajectory())
        slam.close()
    assert len(trajs[0]) == 8 and np.allclose(trajs[0].poses, trajs[1].poses, atol=1e-9)


def test_live_camera_example_runs_on_a_folder(render: Path, tmp_path: Path) -> None:
    import importlib.util

    path = Path(__file__).resolve().parents[1] / "examples" / "live_camera.py"
    spec = importlib.util.spec_from_file_location("live_camera", path)
    assert spec is not None and spec.loader is not None
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    with pytest.raises(SystemExit) as info:
        example.main(["--help"])
    assert info.value.code == 0
    assert example.main(["--folder", str(render), "--preset", "f2kf", "--out", str(tmp_path / "ex"),
                         "--max-frames", "12"]) == 0
    stats = json.loads((tmp_path / "ex" / "stats.json").read_text())
    assert stats["frames"] == stats["tracked_frames"] == 12 and stats["ate"]["rmse"] < 0.02
