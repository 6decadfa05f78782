"""ROS 1 bags as a sequence (io/rosbag_sequence.py).

The test writes bags with rosbags' own writer and ROS 1 serialisation from a short synthetic
render, in TUM's layout (``/camera/rgb/image_color``, ``/camera/depth/image`` 32FC1,
``/camera/rgb/camera_info``, ``/tf`` as ``tf/tfMessage`` with ``/world`` -> ``/kinect`` ->
optical frame), and checks what comes back against the folder reader and the render's
ground truth.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from rosbags.rosbag1 import Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from semslam.cli.main import main
from semslam.errors import DataError
from semslam.geometry.se3 import invert, make_pose, pose_to_tum, quat_to_rot
from semslam.io.images import read_depth, read_rgb
from semslam.io.rosbag_sequence import RosbagSequence
from semslam.io.sequence import open_sequence, read_file_list
from semslam.io.trajectory import read_tum

N_FRAMES = 24
OPTICAL = "/openni_rgb_optical_frame"
# /kinect -> optical frame: ROS's optical rotation (z forward) and an offset, as a static tf.
T_KINECT_OPTICAL = make_pose(quat_to_rot([-0.5, 0.5, -0.5, 0.5]), [0.02, -0.045, 0.01])


@pytest.fixture(scope="module")
def render(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from semslam.synth import SEQUENCES, render_sequence

    return render_sequence(SEQUENCES["static_xyz"].replace(frames=N_FRAMES), tmp_path_factory.mktemp("bag") / "render")


def _typestore() -> Any:
    store = get_typestore(Stores.ROS1_NOETIC)
    # TUM's bags carry tf's old message type; it is not in the Noetic store.
    store.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf/msg/tfMessage"))
    return store


def _ns(t: float) -> int:
    return int(round(t * 1e9))


def write_bag(render: Path, bag: Path, n: int = N_FRAMES, colour: str = "rgb8", depth: str = "32FC1",
              camera: tuple[float, ...] | None = None, with_depth: bool = True, with_tf: bool = True) -> Path:
    """The render as a TUM-style ROS 1 bag; record times lag the header stamps by 7 ms."""
    ts = _typestore()
    t_mod = ts.types
    Header, Time = t_mod["std_msgs/msg/Header"], t_mod["builtin_interfaces/msg/Time"]
    Image, Compressed = t_mod["sensor_msgs/msg/Image"], t_mod["sensor_msgs/msg/CompressedImage"]

    def header(t: float, frame: str, seq: int = 0) -> Any:
        ns = _ns(t)
        return Header(seq=seq, stamp=Time(sec=ns // 10**9, nanosec=ns % 10**9), frame_id=frame)

    rgb_list = read_file_list(render / "rgb.txt")[:n]
    depth_list = read_file_list(render / "depth.txt")[:n]
    cam = camera or tuple(float(v) for v in (render / "calib.txt").read_text().split())
    fx, fy, cx, cy, *dist = (*cam, 0.0, 0.0, 0.0, 0.0, 0.0)[:9] if len(cam) == 4 else cam
    lag = 7_000_000
    with Writer(bag) as w:
        rgb_type = "sensor_msgs/msg/CompressedImage" if colour == "png" else "sensor_msgs/msg/Image"
        c_rgb = w.add_connection("/camera/rgb/image_color", rgb_type, typestore=ts)
        c_info = w.add_connection("/camera/rgb/camera_info", "sensor_msgs/msg/CameraInfo", typestore=ts)
        c_depth = w.add_connection("/camera/depth/image", "sensor_msgs/msg/Image", typestore=ts) if with_depth else None
        c_tf = w.add_connection("/tf", "tf/msg/tfMessage", typestore=ts) if with_tf else None
        for k, e in enumerate(rgb_list):
            rgb = read_rgb(e.path)
            h, wd = rgb.shape[:2]
            if colour == "png":
                msg = Compressed(header=header(e.timestamp, OPTICAL, k), format="png",
                                 data=np.frombuffer(cv2.imencode(".png", rgb[..., ::-1])[1].tobytes(), np.uint8))
            else:
                pixels = rgb if colour == "rgb8" else rgb[..., ::-1]
                msg = Image(header=header(e.timestamp, OPTICAL, k), height=h, width=wd, encoding=colour,
                            is_bigendian=0, step=wd * 3, data=np.ascontiguousarray(pixels).reshape(-1))
            w.write(c_rgb, _ns(e.timestamp) + lag, ts.serialize_ros1(msg, rgb_type))
            if k == 0:
                info = t_mod["sensor_msgs/msg/CameraInfo"](
                    header=header(e.timestamp, OPTICAL), height=h, width=wd, distortion_model="plumb_bob",
                    D=np.array(dist, dtype=np.float64), K=np.array([fx, 0, cx, 0, fy, cy, 0, 0, 1.0]),
                    R=np.eye(3).reshape(-1), P=np.zeros(12), binning_x=0, binning_y=0,
                    roi=t_mod["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0,
                                                                  do_rectify=False))
                w.write(c_info, _ns(e.timestamp) + lag, ts.serialize_ros1(info, "sensor_msgs/msg/CameraInfo"))
        for k, e in enumerate(depth_list if c_depth is not None else []):
            metres = read_depth(e.path, 5000.0)
            h, wd = metres.shape
            if depth == "32FC1":
                data, step = metres.astype("<f4").view(np.uint8).reshape(-1), wd * 4
            else:  # 16UC1 millimetres (REP 118)
                data, step = np.round(metres * 1000).astype("<u2").view(np.uint8).reshape(-1), wd * 2
            msg = Image(header=header(e.timestamp, OPTICAL, k), height=h, width=wd, encoding=depth, is_bigendian=0,
                        step=step, data=data)
            w.write(c_depth, _ns(e.timestamp) + lag, ts.serialize_ros1(msg, "sensor_msgs/msg/Image"))
        if c_tf is not None:
            gt = read_tum(render / "groundtruth.txt")
            tf_msgs = t_mod["tf/msg/tfMessage"], t_mod["geometry_msgs/msg/TransformStamped"]
            for k, (t, pose) in enumerate(zip(gt.timestamps, gt.poses)):
                edges = [("/world", "/kinect", pose @ invert(T_KINECT_OPTICAL))]
                if k % 10 == 0:  # the static part, republished now and then as TUM's bags do
                    edges.append(("/kinect", OPTICAL, T_KINECT_OPTICAL))
                msg = tf_msgs[0](transforms=[tf_msgs[1](header=header(t, parent), child_frame_id=child,
                                                        transform=_transform(t_mod, T))
                                             for parent, child, T in edges])
                w.write(c_tf, _ns(t) + lag, ts.serialize_ros1(msg, "tf/msg/tfMessage"))
    return bag


def _transform(t_mod: Any, pose: np.ndarray) -> Any:
    x, y, z, qx, qy, qz, qw = pose_to_tum(pose[None])[0]
    return t_mod["geometry_msgs/msg/Transform"](translation=t_mod["geometry_msgs/msg/Vector3"](x=x, y=y, z=z),
                                                rotation=t_mod["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw))


def test_round_trip_frames_intrinsics_and_ground_truth(render: Path, tmp_path: Path) -> None:
    """Frames, depth, K and D, and the tf chain's poses come back as written."""
    cam = (530.5, 531.25, 318.75, 241.5, 0.11, -0.23, 0.0012, -0.0021, 0.05)
    seq = open_sequence(write_bag(render, tmp_path / "walk.bag", n=8, camera=cam))
    assert isinstance(seq, RosbagSequence) and seq.has_depth
    folder = open_sequence(render)
    assert len(seq) == 8
    for a, b in zip(seq, folder.frames(0, 8)):
        assert a.timestamp == pytest.approx(b.timestamp, abs=1e-6)  # header stamps, not the lagging record times
        assert np.array_equal(a.rgb, b.rgb) and a.depth is not None and b.depth is not None
        assert np.array_equal(a.depth, b.depth)
    c = seq.camera
    assert (c.fx, c.fy, c.cx, c.cy, *c.dist) == cam and (c.width, c.height) == (640, 480)

    gt = read_tum(render / "groundtruth.txt")
    assert seq.groundtruth is not None and np.allclose(seq.groundtruth.timestamps, gt.timestamps, atol=1e-6)
    assert np.allclose(seq.groundtruth.poses, gt.poses, atol=1e-9)  # /world -> /kinect -> optical composed
    assert seq.groundtruth_path is not None
    assert np.allclose(read_tum(seq.groundtruth_path).poses, gt.poses, atol=1e-8)


@pytest.mark.parametrize("colour, depth", [("bgr8", "16UC1"), ("png", "32FC1")])
def test_other_encodings(render: Path, tmp_path: Path, colour: str, depth: str) -> None:
    """bgr8 and CompressedImage colour, 16UC1 millimetre depth."""
    seq = RosbagSequence(write_bag(render, tmp_path / "x.bag", n=4, colour=colour, depth=depth))
    for a, b in zip(seq, open_sequence(render).frames(0, 4)):
        assert np.array_equal(a.rgb, b.rgb)
        tol = 0.0005 if depth == "16UC1" else 0.0
        assert a.depth is not None and b.depth is not None and np.abs(a.depth - b.depth).max() <= tol


def test_missing_topic_is_one_line(render: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bag = write_bag(render, tmp_path / "nodepth.bag", n=3, with_depth=False, with_tf=False)
    with pytest.raises(DataError, match=r"nodepth.bag: no depth image topic /camera/depth/image in the bag \(nor "
                                        r"/camera/depth_registered/image, .*; its image topics: /camera/rgb/image_color\)"):
        RosbagSequence(bag)
    assert main(["run", str(bag), "--out", str(tmp_path / "out"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "nodepth.bag: no depth image topic /camera/depth/image" in err
    mono = open_sequence(bag, kind="mono")  # colour only is enough for a monocular run
    assert len(mono) == 3 and not mono.has_depth and mono.groundtruth_path is None
    assert next(iter(mono)).depth is None

    (tmp_path / "junk.bag").write_bytes(b"#ROSBAG V2.0\nnot really")
    with pytest.raises(DataError, match="junk.bag: not a readable ROS 1 bag"):
        open_sequence(tmp_path / "junk.bag")


def test_run_on_bag_equals_run_on_folder(render: Path, tmp_path: Path) -> None:
    """`semslam run x.bag` tracks the same frames as the folder and gets the same ATE."""
    bag = write_bag(render, tmp_path / "static.bag")
    stats = {}
    for name, seq in (("folder", render), ("bag", bag)):
        out = tmp_path / name
        assert main(["run", str(seq), "--out", str(out), "--quiet", "--preset", "orb", "--sequential",
                     "--no-report"]) == 0
        stats[name] = json.loads((out / "stats.json").read_text())
    assert stats["bag"]["frames"] == stats["folder"]["frames"] == N_FRAMES
    assert stats["bag"]["camera"]["source"].startswith("camera_info in static.bag")
    assert stats["bag"]["tracked_frames"] == stats["folder"]["tracked_frames"]
    assert stats["bag"]["ate"]["rmse"] == pytest.approx(stats["folder"]["ate"]["rmse"], abs=1e-5)
    assert stats["folder"]["ate"]["rmse"] < 0.05
