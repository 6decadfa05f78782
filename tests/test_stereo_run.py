"""Stereo end to end: renders in the TUM-like, EuRoC and KITTI layouts through ``semslam run``
(the sensor from the input), the Python API's ``track(left, right, t)``, and the clear
errors. Poses are checked against the renders' exact ground truth with evo."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from semslam.errors import ConfigError, DataError
from tests.conftest import evo_ate, run_cli

B = 0.11  # the held-out rig's baseline (metres)


@pytest.fixture(scope="module")
def walking_stereo(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two people walking, 640x480, a right camera 0.11 m along x: TUM-like (rgb/, depth/,
    rgb_right/, camera.yaml)."""
    from semslam.synth import SEQUENCES, render_sequence

    cfg = SEQUENCES["walking_xyz"].replace(frames=60, stereo_baseline=B)
    return render_sequence(cfg, tmp_path_factory.mktemp("stereo_run") / "walking_xyz")


@pytest.fixture(scope="module")
def small_layouts(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """One static 320x240 stereo path written in the EuRoC and the KITTI layout."""
    from semslam.synth import SEQUENCES, render_sequence

    cfg = SEQUENCES["static_xyz"].replace(frames=40, stereo_baseline=B, width=320, height=240)
    root = tmp_path_factory.mktemp("stereo_layouts")
    return {fmt: render_sequence(cfg, root / fmt, layout_format=fmt) for fmt in ("euroc", "kitti")}


def test_default_runs_a_stereo_render_with_its_dynamic_front_end(walking_stereo: Path, tmp_path: Path) -> None:
    """``--sensor stereo`` on a folder that also has depth: the pair is used (bf from
    camera.yaml), the semantic stage and the multi-view check see people, the octree map is
    built from the pair's dense depth, and the poses hold against the ground truth."""
    out = tmp_path / "default"
    stats = run_cli(walking_stereo, out, "--preset", "default", "--sensor", "stereo", "--map", "octree")
    config = json.loads((out / "config.json").read_text())
    assert config["sensor"] == "stereo"
    fx = float(next(ln.split(":")[1] for ln in (walking_stereo / "camera.yaml").read_text().splitlines()
                    if ln.startswith("Camera1.fx")))
    assert config["slam"]["bf"] == pytest.approx(fx * B, rel=1e-6)  # camera.yaml's fx times the baseline
    assert stats["tracked_frames"] == 60 and stats["ate_alignment"] == "se3"
    assert stats["dynamic_ratio_mean"] > 0.02  # people masked in the left images
    assert (out / "map" / "octree.ot").is_file() or any((out / "map").glob("octree*"))
    ate = evo_ate(walking_stereo / "groundtruth.txt", out / "trajectory.txt")
    assert ate == pytest.approx(stats["ate"]["rmse"], rel=1e-6)
    assert ate < 0.02
    # `semslam map` rebuilds the maps afterwards from the pair's depth too
    from semslam.cli.main import main

    assert main(["map", str(out), "--out", str(tmp_path / "again"), "--map", "cloud", "--quiet"]) == 0
    assert any((tmp_path / "again").glob("*.ply"))


def test_orb_stereo_matches_rgbd_on_the_same_path(walking_stereo: Path, tmp_path: Path) -> None:
    """`orb` with the pair against `orb` with the render's depth: the same order of error
    (stereo depth is noisier, so a margin)."""
    stereo = run_cli(walking_stereo, tmp_path / "s", "--preset", "orb", "--sensor", "stereo", "--sequential")
    rgbd = run_cli(walking_stereo, tmp_path / "r", "--preset", "orb", "--sequential")
    assert stereo["tracked_frames"] == rgbd["tracked_frames"] == 60
    assert stereo["ate"]["rmse"] < max(3 * rgbd["ate"]["rmse"], 0.01)


@pytest.mark.parametrize("preset", ["stdc", "ddl"])
def test_paper_presets_run_stereo(walking_stereo: Path, preset: str, tmp_path: Path) -> None:
    """STDC-SLAM's and DDL-SLAM's presets on the pair: people masked, poses held (`ddl`'s
    inpainted octree from the pair's depth)."""
    stats = run_cli(walking_stereo, tmp_path / preset, "--preset", preset, "--sensor", "stereo", "--sequential",
                    "--max-frames", "30", "--no-report")
    assert stats["tracked_frames"] == 30 and stats["dynamic_ratio_mean"] > 0.02
    assert stats["ate"]["rmse"] < 0.02
    if preset == "ddl":
        assert "octree" in stats["paths"]


@pytest.mark.parametrize("layout", ["euroc", "kitti"])
def test_layouts_open_as_stereo_and_track(small_layouts: dict[str, Path], layout: str, tmp_path: Path) -> None:
    """An RGB-D preset on an EuRoC or KITTI folder runs as stereo (no flag); the ground truth
    is the camera's (EuRoC: body pose times T_BS; KITTI: poses.txt with times.txt)."""
    from semslam.io.sequence import open_sequence

    seq = open_sequence(small_layouts[layout])
    assert seq.calibration.baseline == pytest.approx(B, rel=1e-6) and not seq.has_depth
    stats = run_cli(small_layouts[layout], tmp_path / layout, "--preset", "orb", "--sequential")
    assert json.loads((tmp_path / layout / "config.json").read_text())["sensor"] == "stereo"
    assert stats["tracked_frames"] == 40
    assert seq.groundtruth_path is not None
    ate = evo_ate(seq.groundtruth_path, tmp_path / layout / "trajectory.txt")
    # 320x240 halves the disparities: such renders measured 1.6-2.6 cm with the pair against
    # 0.7-1.3 cm with their depth (640x480: 0.4-0.6 cm, docs/results/stereo.md)
    assert ate == pytest.approx(stats["ate"]["rmse"], rel=1e-6) and ate < 0.03


def test_api_tracks_left_right_pairs(walking_stereo: Path) -> None:
    """``System(preset, camera, sensor="stereo", baseline=B)`` and ``track(left, right, t)``
    give the poses ``semslam run`` gives, within the ground truth's tolerance."""
    from semslam import System
    from semslam.eval.metrics import ate
    from semslam.io.stereo_sequence import open_stereo_sequence
    from semslam.io.trajectory import read_tum

    seq = open_stereo_sequence(walking_stereo)
    cam = seq.calibration.camera
    with System("default", (cam.fx, cam.fy, cam.cx, cam.cy), sensor="stereo", baseline=B,
                overrides={"slam.sequential": True}) as slam:
        for frame in list(seq)[:40]:
            result = slam.track(frame.rgb, frame.right, frame.timestamp)
        assert result.pose_wc is not None
        traj = slam.trajectory()
    assert len(traj) == 40
    assert ate(read_tum(walking_stereo / "groundtruth.txt"), traj, align="se3").rmse < 0.02


def test_stereo_errors(tum_folder: Path, tmp_path: Path) -> None:
    from semslam import System
    from semslam.cli.main import main

    with pytest.raises(ConfigError, match="baseline"):
        System("orb", (500.0, 500.0, 160.0, 120.0), sensor="stereo")
    with pytest.raises(ConfigError, match="binary descriptors"):
        System("orb", (500.0, 500.0, 160.0, 120.0), sensor="stereo", baseline=B,
               overrides={"features.extractor": "sift", "slam.loop_closing": False}, image_size=(320, 240))
    with pytest.raises(ConfigError, match="depth comes from the pair"):
        System("sdf_paper", (500.0, 500.0, 160.0, 120.0), sensor="stereo", baseline=B, image_size=(320, 240))
    with pytest.raises(ConfigError, match="sdf_slam is monocular"):
        System("orb", (500.0, 500.0, 160.0, 120.0), sensor="stereo", baseline=B, image_size=(320, 240),
               overrides={"tracking.method": "sdf_slam"})
    with System("orb", (500.0, 500.0, 160.0, 120.0), sensor="stereo", baseline=B) as slam:
        with pytest.raises(DataError, match="no right image"):
            slam.track(np.zeros((240, 320, 3), np.uint8), None, 0.0)
        with pytest.raises(DataError, match="right image is 160x120"):
            slam.track(np.zeros((240, 320, 3), np.uint8), np.zeros((120, 160, 3), np.uint8), 0.1)
    # sensor stereo on a folder without right images: one line naming the folder
    assert main(["run", str(tum_folder), "--out", str(tmp_path / "x"), "--quiet", "--sensor", "stereo"]) != 0
    with pytest.raises(DataError, match="not a stereo sequence"):
        from semslam.io.sequence import open_sequence

        open_sequence(tum_folder, kind="stereo")


def _write_bag(seq_dir: Path, bag: Path) -> Path:
    """The EuRoC render as a ROS 1 bag: mono8 images on /cam0 and /cam1, rectified
    CameraInfos (P's Tx = -fx * baseline), the camera's ground truth on /tf."""
    import cv2
    from rosbags.rosbag1 import Writer

    from semslam.geometry.se3 import pose_to_tum
    from semslam.io.sequence import open_sequence
    from tests.test_rosbag_stereo import M, STORE, _header

    seq = open_sequence(seq_dir)
    cam, gt = seq.calibration.camera, seq.groundtruth()
    k = np.array([[cam.fx, 0, cam.cx], [0, cam.fy, cam.cy], [0, 0, 1.0]])
    with Writer(bag) as w:
        conns = [w.add_connection(f"/cam{i}/image_raw", "sensor_msgs/msg/Image", typestore=STORE) for i in (0, 1)]
        for frame in seq:
            for i, (conn, rgb) in enumerate(zip(conns, (frame.rgb, frame.right))):
                grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
                msg = M["sensor_msgs/msg/Image"](header=_header(frame.timestamp, f"cam{i}", frame.index),
                                                 height=grey.shape[0], width=grey.shape[1], encoding="mono8",
                                                 is_bigendian=0, step=grey.shape[1], data=grey.reshape(-1))
                w.write(conn, int(round(frame.timestamp * 1e9)), STORE.serialize_ros1(msg, "sensor_msgs/msg/Image"))
        roi = M["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
        for i in (0, 1):
            p = np.hstack([k, np.zeros((3, 1))])
            p[0, 3] = -cam.fx * seq.calibration.baseline * i
            info = M["sensor_msgs/msg/CameraInfo"](
                header=_header(float(seq.timestamps[0]), f"cam{i}"), height=cam.height, width=cam.width,
                distortion_model="plumb_bob", D=np.zeros(5), K=k.reshape(-1), R=np.eye(3).reshape(-1),
                P=p.reshape(-1), binning_x=0, binning_y=0, roi=roi)
            c = w.add_connection(f"/cam{i}/camera_info", "sensor_msgs/msg/CameraInfo", typestore=STORE)
            w.write(c, int(seq.timestamps[0] * 1e9), STORE.serialize_ros1(info, "sensor_msgs/msg/CameraInfo"))
        c = w.add_connection("/tf", "tf2_msgs/msg/TFMessage", typestore=STORE)
        for t, pose in zip(gt.timestamps, gt.poses):
            x, y, z, qx, qy, qz, qw = pose_to_tum(pose[None])[0]
            tr = M["geometry_msgs/msg/Transform"](translation=M["geometry_msgs/msg/Vector3"](x=x, y=y, z=z),
                                                  rotation=M["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw))
            msg = M["tf2_msgs/msg/TFMessage"](transforms=[M["geometry_msgs/msg/TransformStamped"](
                header=_header(float(t), "/world"), child_frame_id="/cam0", transform=tr)])
            w.write(c, int(round(float(t) * 1e9)), STORE.serialize_ros1(msg, "tf2_msgs/msg/TFMessage"))
    return bag


def test_stereo_bag_runs(small_layouts: dict[str, Path], tmp_path: Path) -> None:
    """A ROS 1 bag with two image topics runs as stereo through ``semslam run`` (the
    calibration from its CameraInfos, the ground truth from /tf)."""
    bag = _write_bag(small_layouts["euroc"], tmp_path / "stereo.bag")
    stats = run_cli(bag, tmp_path / "bag", "--preset", "orb", "--sequential")
    assert json.loads((tmp_path / "bag" / "config.json").read_text())["sensor"] == "stereo"
    assert stats["tracked_frames"] == 40 and stats["ate"]["rmse"] < 0.03  # 320x240, as above


def test_calibration_options(walking_stereo: Path, tmp_path: Path) -> None:
    """``--camera`` + ``--baseline`` and ``--settings`` give the pair's bf; a baseline for a
    sequence read as RGB-D is refused in one line."""
    from semslam.cli.main import main

    cam = "535.4,539.2,320.1,247.6"
    for name, flags, bf in (("values", ["--camera", cam, "--baseline", "0.2"], 535.4 * 0.2),
                            ("settings", ["--settings", str(walking_stereo / "camera.yaml")], 535.4 * B)):
        run_cli(walking_stereo, tmp_path / name, "--preset", "orb", "--sensor", "stereo", "--max-frames", "3",
                "--sequential", "--no-report", *flags)
        assert json.loads((tmp_path / name / "config.json").read_text())["slam"]["bf"] == pytest.approx(bf)
    assert main(["run", str(walking_stereo), "--out", str(tmp_path / "x"), "--quiet", "--baseline", "0.1"]) == 2
