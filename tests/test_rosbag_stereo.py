"""Stereo ROS 1 bags (io/rosbag_stereo.py).

Tiny bags written with rosbags' own writer: a textured pair 160x120 whose right image is
the left shifted by a known disparity, on EuRoC's (or other) topic names, with or without
CameraInfo. Checks pairs, stamps, decoding, the calibration taken from CameraInfo against
the values written (and, for an unrectified pair, against ``cv2.stereoRectify``'s own
model), /tf ground truth and the errors.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from rosbags.rosbag1 import Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from semslam.errors import ConfigError, DataError
from semslam.geometry.camera import PinholeCamera
from semslam.geometry.se3 import make_pose, pose_to_tum
from semslam.io.rosbag_stereo import StereoRosbagSequence, bag_has_stereo, open_stereo_rosbag
from semslam.io.stereo_calibration import stereo_from_values

W, H, N, DISP = 160, 120, 6, 8
FX, FY, CX, CY, BASELINE = 100.0, 101.0, 79.5, 59.5, 0.11
T0 = 1403636579.763555584  # an EuRoC-like stamp: pairing must survive nanosecond-scale epochs
EUROC = ("/cam0/image_raw", "/cam1/image_raw")
STORE = get_typestore(Stores.ROS1_NOETIC)
STORE.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage"))
M = STORE.types


def texture(k: int, channels: int) -> np.ndarray:
    """A smooth random texture, different per frame, ``W + DISP`` wide."""
    rng = np.random.default_rng(k)
    tex = rng.integers(0, 256, (H, W + DISP, channels)).astype(np.float32)
    return np.clip(cv2.GaussianBlur(tex, (5, 5), 1.0).reshape(H, W + DISP, channels), 0, 255).astype(np.uint8)


def pair(k: int, channels: int) -> tuple[np.ndarray, np.ndarray]:
    """Left and right images (H, W, C): ``right[y, x] = left[y, x + DISP]`` (disparity DISP)."""
    tex = texture(k, channels)
    return tex[:, DISP:DISP + W], tex[:, :W]


def _header(t: float, frame: str, seq: int = 0) -> Any:
    ns = int(round(t * 1e9))
    return M["std_msgs/msg/Header"](seq=seq, stamp=M["builtin_interfaces/msg/Time"](sec=ns // 10**9,
                                                                                   nanosec=ns % 10**9),
                                    frame_id=frame)


def camera_info(t: float, k: np.ndarray, d: np.ndarray, r: np.ndarray, p: np.ndarray) -> Any:
    roi = M["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    return M["sensor_msgs/msg/CameraInfo"](header=_header(t, "cam"), height=H, width=W, distortion_model="plumb_bob",
                                           D=np.asarray(d, np.float64), K=np.asarray(k, np.float64).reshape(-1),
                                           R=np.asarray(r, np.float64).reshape(-1),
                                           P=np.asarray(p, np.float64).reshape(-1), binning_x=0, binning_y=0, roi=roi)


def rectified_infos(t: float) -> tuple[Any, Any]:
    k = np.array([[FX, 0, CX], [0, FY, CY], [0, 0, 1.0]])
    p_left = np.hstack([k, np.zeros((3, 1))])
    p_right = p_left.copy()
    p_right[0, 3] = -FX * BASELINE
    return camera_info(t, k, np.zeros(5), np.eye(3), p_left), camera_info(t, k, np.zeros(5), np.eye(3), p_right)


def write_stereo_bag(bag: Path, topics: tuple[str, str] = EUROC, encoding: str = "mono8", n: int = N,
                     infos: tuple[Any, Any] | None | str = "rectified", right_lag: float = 0.001,
                     drop_right: tuple[int, ...] = (), with_right: bool = True,
                     tf: list[np.ndarray] | None = None) -> Path:
    """``n`` pairs 20 Hz apart; the right stamps lag by ``right_lag`` s; ``infos`` on
    ``<ns>/camera_info`` ("rectified": the pair's own rectified values)."""
    image = M["sensor_msgs/msg/Image"]
    channels = 1 if encoding == "mono8" else 3
    with Writer(bag) as w:
        conns = [w.add_connection(t, "sensor_msgs/msg/Image", typestore=STORE)
                 for t in (topics if with_right else topics[:1])]
        for k in range(n):
            t = T0 + 0.05 * k
            for side, (conn, img) in enumerate(zip(conns, pair(k, channels))):
                if side == 1 and k in drop_right:
                    continue
                stamp = t + (right_lag if side else 0.0)
                pixels = img[..., ::-1] if encoding == "bgr8" else img  # stored BGR, read back as RGB
                msg = image(header=_header(stamp, "cam0" if side == 0 else "cam1", k), height=H, width=W,
                            encoding=encoding, is_bigendian=0, step=W * channels,
                            data=np.ascontiguousarray(pixels).reshape(-1))
                w.write(conn, int(round(stamp * 1e9)), STORE.serialize_ros1(msg, "sensor_msgs/msg/Image"))
        if infos is not None:
            msgs = rectified_infos(T0) if infos == "rectified" else infos
            for topic, msg in zip(topics, msgs):
                c = w.add_connection(topic.rsplit("/", 1)[0] + "/camera_info", "sensor_msgs/msg/CameraInfo",
                                     typestore=STORE)
                w.write(c, int(T0 * 1e9), STORE.serialize_ros1(msg, "sensor_msgs/msg/CameraInfo"))
        if tf is not None:
            c = w.add_connection("/tf", "tf2_msgs/msg/TFMessage", typestore=STORE)
            for k, pose in enumerate(tf):
                t = T0 + 0.01 * k
                x, y, z, qx, qy, qz, qw = pose_to_tum(pose[None])[0]
                tr = M["geometry_msgs/msg/Transform"](translation=M["geometry_msgs/msg/Vector3"](x=x, y=y, z=z),
                                                      rotation=M["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz,
                                                                                                 w=qw))
                msg = M["tf2_msgs/msg/TFMessage"](transforms=[M["geometry_msgs/msg/TransformStamped"](
                    header=_header(t, "/world"), child_frame_id="/cam0", transform=tr)])
                w.write(c, int(round(t * 1e9)), STORE.serialize_ros1(msg, "tf2_msgs/msg/TFMessage"))
    return bag


def tf_poses(n: int = 30) -> list[np.ndarray]:
    return [make_pose(cv2.Rodrigues(np.array([0.0, 0.02 * k, 0.01 * k]))[0], [0.03 * k, 0.0, 0.01 * k])
            for k in range(n)]


@pytest.fixture(scope="module")
def euroc_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_stereo_bag(tmp_path_factory.mktemp("stereo_bag") / "MH_01_easy.bag", tf=tf_poses())


def test_rectified_mono_pair_from_camera_info(euroc_bag: Path) -> None:
    """mono8 pairs come back grey-expanded, paired and unmodified; K and Tx give the calibration."""
    assert bag_has_stereo(euroc_bag)
    seq = open_stereo_rosbag(euroc_bag)
    assert isinstance(seq, StereoRosbagSequence) and not seq.has_depth and len(seq) == N
    assert np.allclose(seq.timestamps, T0 + 0.05 * np.arange(N), atol=1e-6)  # the left header stamps
    cal = seq.calibration
    assert cal.rectified_input and cal.maps is None
    assert cal.baseline == pytest.approx(BASELINE, abs=1e-12) and cal.bf == pytest.approx(FX * BASELINE, abs=1e-9)
    c = seq.camera
    assert c is cal.camera and (c.fx, c.fy, c.cx, c.cy, c.width, c.height) == (FX, FY, CX, CY, W, H)
    for k, frame in enumerate(seq):
        left, right = pair(k, 1)
        assert frame.right is not None and frame.rgb.shape == frame.right.shape == (H, W, 3)
        assert np.array_equal(frame.rgb, np.repeat(left, 3, axis=2))
        assert np.array_equal(frame.right, np.repeat(right, 3, axis=2))
        assert np.array_equal(frame.right[:, DISP:], frame.rgb[:, :-DISP])  # disparity DISP everywhere
        assert frame.depth is None


def test_ground_truth_from_tf(euroc_bag: Path) -> None:
    seq = open_stereo_rosbag(euroc_bag)
    assert seq.groundtruth is not None and seq.groundtruth_path is not None and seq.groundtruth_path.is_file()
    assert np.allclose(seq.groundtruth.timestamps, T0 + 0.01 * np.arange(30), atol=1e-6)
    assert np.allclose(seq.groundtruth.poses, np.array(tf_poses()), atol=1e-9)


@pytest.mark.parametrize("topics", [("/stereo/left/image_raw", "/stereo/right/image_raw"),
                                    ("/camera/infra1/image_rect_raw", "/camera/infra2/image_rect_raw")])
def test_bgr_pair_on_other_topics(tmp_path: Path, topics: tuple[str, str]) -> None:
    """bgr8 is turned to RGB; other topic names and their camera_info are found."""
    bag = write_stereo_bag(tmp_path / "rig.bag", topics=topics, encoding="bgr8", n=3)
    assert bag_has_stereo(bag)
    seq = open_stereo_rosbag(bag)
    assert len(seq) == 3 and seq.calibration.bf == pytest.approx(FX * BASELINE)
    frame = seq.load(2)
    left, right = pair(2, 3)
    assert np.array_equal(frame.rgb, left) and frame.right is not None and np.array_equal(frame.right, right)
    assert seq.groundtruth_path is None


def test_pairing_by_nearest_stamp(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """A right image missing: its left image is dropped (warning); the others pair by stamp."""
    bag = write_stereo_bag(tmp_path / "gap.bag", right_lag=0.004, drop_right=(2,))
    seq = open_stereo_rosbag(bag)
    assert len(seq) == N - 1 and "1 of 6 left images have no right image" in caplog.text
    kept = [k for k in range(N) if k != 2]
    assert np.allclose(seq.timestamps, T0 + 0.05 * np.array(kept), atol=1e-6)
    for frame, k in zip(seq, kept):
        assert frame.right is not None and np.array_equal(frame.right[..., 0], pair(k, 1)[1][..., 0])
    with pytest.raises(DataError, match=r"gap.bag: no left/right pairs within 0.001 s"):
        open_stereo_rosbag(bag, max_diff=0.001)


def test_unrectified_pair_from_camera_info(tmp_path: Path) -> None:
    """ROS stereo calibration's R1, R2, P2 give back the right camera's pose; rectified
    projections of a 3-D point share a row and have disparity bf / Z."""
    k1 = np.array([[FX, 0, CX], [0, FY, CY], [0, 0, 1.0]])
    k2 = np.array([[FX + 3, 0, CX - 2], [0, FY + 2, CY + 1], [0, 0, 1.0]])
    d1, d2 = np.array([-0.05, 0.01, 0.001, -0.0005, 0.0]), np.array([-0.04, 0.008, -0.001, 0.0003, 0.0])
    t_lr = make_pose(cv2.Rodrigues(np.array([0.01, -0.02, 0.005]))[0], [BASELINE, 0.002, -0.001])
    t_rl = np.linalg.inv(t_lr)
    r1, r2, p1, p2, *_ = cv2.stereoRectify(k1, d1, k2, d2, (W, H), t_rl[:3, :3], t_rl[:3, 3],
                                           flags=cv2.CALIB_ZERO_DISPARITY, alpha=0)
    bag = write_stereo_bag(tmp_path / "raw.bag", n=2, infos=(camera_info(T0, k1, d1, r1, p1),
                                                             camera_info(T0, k2, d2, r2, p2)))
    seq = open_stereo_rosbag(bag)
    cal = seq.calibration
    assert not cal.rectified_input and cal.maps is not None
    assert np.allclose(cal.T_lr, t_lr, atol=1e-9)
    assert cal.baseline == pytest.approx(np.linalg.norm(t_lr[:3, 3]), abs=1e-9)
    point = np.array([0.3, -0.2, 2.5])  # in the left camera's frame
    uv_l = cv2.projectPoints(point[None], np.zeros(3), np.zeros(3), k1, d1)[0].reshape(1, 2)
    in_right = t_rl[:3, :3] @ point + t_rl[:3, 3]
    uv_r = cv2.projectPoints(in_right[None], np.zeros(3), np.zeros(3), k2, d2)[0].reshape(1, 2)
    rl, rr = cal.rectify_points(uv_l, "left")[0], cal.rectify_points(uv_r, "right")[0]
    z_rect = (cal.R_left @ point)[2]
    assert rl[1] == pytest.approx(rr[1], abs=1e-6) and rl[0] - rr[0] == pytest.approx(cal.bf / z_rect, rel=1e-6)
    frame = seq.load(0)
    assert frame.right is not None and frame.rgb.shape == (H, W, 3)  # remapped with the tables


def test_explicit_calibration(euroc_bag: Path, tmp_path: Path) -> None:
    """An explicit calibration or --camera/--baseline wins over camera_info."""
    given = stereo_from_values(PinholeCamera(90.0, 90.0, 80.0, 60.0), 0.2)
    cal = open_stereo_rosbag(euroc_bag, calibration=given).calibration  # given, with the images' size
    assert cal.bf == pytest.approx(90 * 0.2) and (cal.camera.fx, cal.camera.width, cal.camera.height) == (90, W, H)
    seq = open_stereo_rosbag(euroc_bag, camera="95,96,79,59", baseline=0.3)
    assert seq.calibration.bf == pytest.approx(95 * 0.3) and (seq.camera.width, seq.camera.height) == (W, H)
    with pytest.raises(ConfigError, match="needs both --camera fx,fy,cx,cy and --baseline"):
        open_stereo_rosbag(euroc_bag, camera="95,96,79,59")


def test_errors(tmp_path: Path) -> None:
    """No calibration, an unrectified pair without extrinsics, a missing topic, no stereo at all."""
    bag = write_stereo_bag(tmp_path / "nocal.bag", n=2, infos=None)
    with pytest.raises(DataError, match=r"nocal.bag: no stereo calibration: /cam0/camera_info is missing .*"
                                        r"give --settings camera.yaml .* or --camera fx,fy,cx,cy --baseline B"):
        open_stereo_rosbag(bag)
    assert len(open_stereo_rosbag(bag, calibration=stereo_from_values("100,100,80,60", 0.1))) == 2

    k = np.array([[FX, 0, CX], [0, FY, CY], [0, 0, 1.0]])
    d = np.array([-0.05, 0.01, 0.0, 0.0, 0.0])
    p = np.hstack([k, [[-FX * BASELINE], [0], [0]]])
    raw = write_stereo_bag(tmp_path / "nor.bag", n=2, infos=(camera_info(T0, k, d, np.zeros(9), p),
                                                             camera_info(T0, k, d, np.zeros(9), p)))
    with pytest.raises(DataError, match=r"nor.bag: the stereo pair is not rectified .* \(no extrinsics\); give --settings"):
        open_stereo_rosbag(raw)
    nobase = write_stereo_bag(tmp_path / "nobase.bag", n=2,
                              infos=(camera_info(T0, k, np.zeros(5), np.eye(3), np.hstack([k, np.zeros((3, 1))])),) * 2)
    with pytest.raises(DataError, match=r"/cam1/camera_info has no baseline"):
        open_stereo_rosbag(nobase)

    half = write_stereo_bag(tmp_path / "half.bag", n=2, with_right=False)
    assert not bag_has_stereo(half)
    with pytest.raises(DataError, match=r"half.bag: stereo bag has /cam0/image_raw but no /cam1/image_raw"):
        open_stereo_rosbag(half)
    other = write_stereo_bag(tmp_path / "other.bag", topics=("/a/image", "/b/image"), n=2, infos=None)
    with pytest.raises(DataError, match=r"no stereo image topics \(expected one of /cam0/image_raw \+ "
                                        r"/cam1/image_raw, .*; its image topics: /a/image, /b/image\)"):
        open_stereo_rosbag(other)
    assert len(StereoRosbagSequence(other, left_topic="/a/image", right_topic="/b/image",
                                    calibration=stereo_from_values("100,100,80,60", 0.1))) == 2
    (tmp_path / "junk.bag").write_bytes(b"#ROSBAG V2.0\nnot really")
    assert not bag_has_stereo(tmp_path / "junk.bag") and not bag_has_stereo(tmp_path / "absent.bag")
    with pytest.raises(DataError, match="junk.bag: not a readable ROS 1 bag"):
        open_stereo_rosbag(tmp_path / "junk.bag", calibration=stereo_from_values("100,100,80,60", 0.1))
