"""Stereo inputs (issue 41, item 1): calibration readers, rectification and the three
folder layouts, checked against analytic cases and the datasets' published values."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from semslam.errors import ConfigError, DataError
from semslam.geometry.camera import PinholeCamera
from semslam.io.stereo_calibration import (StereoCalibration, read_euroc_calibration, read_euroc_sensor,
                                           read_kitti_calib, read_orbslam3_settings, stereo_from_values)
from semslam.io.stereo_sequence import euroc_camera_trajectory, open_stereo_sequence, stereo_layout

# --- published calibrations ------------------------------------------------------------

# KITTI odometry sequence 00, calib.txt (P2/P3 are the colour cameras; Tr the Velodyne).
KITTI_00_CALIB = """\
P0: 7.188560000000e+02 0.000000000000e+00 6.071928000000e+02 0.000000000000e+00 0.000000000000e+00 7.188560000000e+02 1.852157000000e+02 0.000000000000e+00 0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 0.000000000000e+00
P1: 7.188560000000e+02 0.000000000000e+00 6.071928000000e+02 -3.861448000000e+02 0.000000000000e+00 7.188560000000e+02 1.852157000000e+02 0.000000000000e+00 0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 0.000000000000e+00
P2: 7.188560000000e+02 0.000000000000e+00 6.071928000000e+02 4.538225000000e+01 0.000000000000e+00 7.188560000000e+02 1.852157000000e+02 -1.130887000000e-01 0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 3.779761000000e-03
P3: 7.188560000000e+02 0.000000000000e+00 6.071928000000e+02 -3.372877000000e+02 0.000000000000e+00 7.188560000000e+02 1.852157000000e+02 2.369057000000e+00 0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 4.915215000000e-03
Tr: 4.276802385584e-04 -9.999672484946e-01 -8.084491683471e-03 -1.198459927713e-02 -7.210626507497e-03 8.081198471645e-03 -9.999413164504e-01 -5.403984729748e-02 9.999738645903e-01 4.859485810390e-04 -7.206933692422e-03 -2.921968648686e-01
"""

# EuRoC MAV, Vicon room 1 (V1_*), mav0/cam0 and mav0/cam1 sensor.yaml.
EUROC_CAM0 = {
    "T_BS": [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975,
             0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768,
             -0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949,
             0.0, 0.0, 0.0, 1.0],
    "intrinsics": [458.654, 457.296, 367.215, 248.375],
    "distortion_coefficients": [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05],
}
EUROC_CAM1 = {
    "T_BS": [0.0125552670891, -0.999755099723, 0.0182237714554, -0.0198435579556,
             0.999598781151, 0.0130119051815, 0.0251588363115, 0.0453689425024,
             -0.0253898008918, 0.0179005838253, 0.999517347078, 0.00786212447038,
             0.0, 0.0, 0.0, 1.0],
    "intrinsics": [457.587, 456.134, 379.999, 255.238],
    "distortion_coefficients": [-0.28368365, 0.07451284, -0.00010473, -3.55590700e-05],
}
# ORB-SLAM3's Examples/Stereo/EuRoC.yaml: the same pair as T_c1_c2 (cam1 in cam0's frame).
ORBSLAM3_EUROC_T_C1_C2 = np.array([
    [0.999997256477797, -0.002317135723275, -0.000343393120620, 0.110074137800478],
    [0.002312067192432, 0.999898048507103, -0.014090668452683, -0.000156612054392],
    [0.000376008102320, 0.014089835846691, 0.999900662638081, 0.000889382785432],
    [0.0, 0.0, 0.0, 1.0]])


def write_euroc_sensor(path: Path, values: dict, resolution: tuple[int, int] = (752, 480)) -> None:
    """A sensor.yaml as EuRoC writes it (comments, block lists, ``T_BS`` with rows/cols/data)."""
    t = values["T_BS"]
    rows = ",\n         ".join(", ".join(repr(v) for v in t[i:i + 4]) for i in range(0, 16, 4))
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(
        "# General sensor definitions.\nsensor_type: camera\ncomment: VI-Sensor cam (MT9M034)\n\n"
        "# Sensor extrinsics wrt. the body-frame.\nT_BS:\n  cols: 4\n  rows: 4\n"
        f"  data: [{rows}]\n\n# Camera specific definitions.\nrate_hz: 20\n"
        f"resolution: [{resolution[0]}, {resolution[1]}]\ncamera_model: pinhole\n"
        f"intrinsics: {values['intrinsics']} #fu, fv, cu, cv\ndistortion_model: radial-tangential\n"
        f"distortion_coefficients: {values['distortion_coefficients']}\n")


def write_settings(path: Path, body: str) -> None:
    path.write_text('%YAML:1.0\n\nFile.version: "1.0"\n' + body)


def pinhole_settings(t_c1_c2: np.ndarray, cam0: dict, cam1: dict, size: tuple[int, int]) -> str:
    lines = ['Camera.type: "PinHole"']
    for prefix, cam in (("Camera1", cam0), ("Camera2", cam1)):
        for name, v in zip(("fx", "fy", "cx", "cy"), cam["intrinsics"]):
            lines.append(f"{prefix}.{name}: {v!r}")
        for name, v in zip(("k1", "k2", "p1", "p2"), cam["distortion_coefficients"]):
            lines.append(f"{prefix}.{name}: {v!r}")
    lines += [f"Camera.width: {size[0]}", f"Camera.height: {size[1]}", "Camera.fps: 20", "Camera.RGB: 1",
              "Stereo.ThDepth: 60.0", "Stereo.T_c1_c2: !!opencv-matrix", "  rows: 4", "  cols: 4", "  dt: f",
              "  data: [" + ", ".join(repr(float(v)) for v in t_c1_c2.reshape(-1)) + "]"]
    return "\n".join(lines) + "\n"


# --- rectification: an analytic case --------------------------------------------------


def _rig() -> StereoCalibration:
    """Two distorted cameras, different intrinsics, the right one rotated by about 2 degrees."""
    left = PinholeCamera(460.0, 458.0, 330.0, 245.0, (-0.28, 0.074, 2e-4, 2e-5, 0.0), width=640, height=480)
    right = PinholeCamera(455.0, 454.0, 318.0, 238.0, (-0.27, 0.07, -1e-4, 3e-5, 0.0), width=640, height=480)
    pose = np.eye(4)
    pose[:3, :3] = cv2.Rodrigues(np.array([0.012, -0.03, 0.008]))[0]
    pose[:3, 3] = [0.11, 0.003, -0.002]
    return StereoCalibration(left, right, pose, "rig")


def _project(cal: StereoCalibration, pts_left: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Raw (distorted) pixels of left-frame points in both cameras, by OpenCV's projection."""
    uv_l = cv2.projectPoints(pts_left, np.zeros(3), np.zeros(3), cal.left.K, cal.left.dist_coeffs)[0].reshape(-1, 2)
    pts_right = (pts_left - cal.T_lr[:3, 3]) @ cal.T_lr[:3, :3]  # X_r = R^T (X_l - t)
    uv_r = cv2.projectPoints(pts_right, np.zeros(3), np.zeros(3), cal.right.K,
                             cal.right.dist_coeffs)[0].reshape(-1, 2)
    return uv_l, uv_r


def _bilinear(img: np.ndarray, uv: np.ndarray) -> np.ndarray:
    x0, y0 = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
    fx, fy = uv[:, 0] - x0, uv[:, 1] - y0
    return (img[y0, x0] * (1 - fx) * (1 - fy) + img[y0, x0 + 1] * fx * (1 - fy)
            + img[y0 + 1, x0] * (1 - fx) * fy + img[y0 + 1, x0 + 1] * fx * fy)


def test_rectification_puts_points_on_one_row_and_gives_depth_back() -> None:
    cal = _rig()
    rng = np.random.default_rng(3)
    pts = np.column_stack([rng.uniform(-1.2, 1.2, 400), rng.uniform(-0.9, 0.9, 400), rng.uniform(1.5, 8.0, 400)])
    uv_l, uv_r = _project(cal, pts)
    inside = np.all((uv_l > 20) & (uv_l < [620, 460]) & (uv_r > 20) & (uv_r < [620, 460]), axis=1)
    pts, uv_l, uv_r = pts[inside], uv_l[inside], uv_r[inside]
    assert len(pts) > 150
    rect_l, rect_r = cal.rectify_points(uv_l, "left"), cal.rectify_points(uv_r, "right")
    assert np.abs(rect_l[:, 1] - rect_r[:, 1]).max() < 0.1
    depth_rect = (pts @ cal.R_left.T)[:, 2]  # depth along the rectified left camera's axis
    depth = cal.bf / (rect_l[:, 0] - rect_r[:, 0])
    assert np.abs(depth / depth_rect - 1).max() < 0.005
    # The remap tables send each rectified pixel back to the raw pixel it comes from.
    assert cal.maps is not None
    lx, ly, rx, ry = cal.maps
    ok = np.all((rect_l > 1) & (rect_l < [638, 478]) & (rect_r > 1) & (rect_r < [638, 478]), axis=1)
    assert ok.sum() > 100
    back_l = np.column_stack([_bilinear(lx, rect_l[ok]), _bilinear(ly, rect_l[ok])])
    back_r = np.column_stack([_bilinear(rx, rect_r[ok]), _bilinear(ry, rect_r[ok])])
    assert np.abs(back_l - uv_l[ok]).max() < 0.1
    assert np.abs(back_r - uv_r[ok]).max() < 0.1
    assert cal.baseline == pytest.approx(np.linalg.norm(cal.T_lr[:3, 3]), rel=1e-9)
    assert cal.camera.dist_coeffs.tolist() == [0.0] * 5


def test_rectified_images_put_a_blob_on_one_row() -> None:
    """Images too: a bright spot drawn at a point's raw projections lands on one row
    after ``rectify`` (sub-pixel centroids), at the disparity of its depth."""
    cal = _rig()
    point = np.array([[0.3, -0.2, 3.0]])
    uv_l, uv_r = _project(cal, point)
    yy, xx = np.mgrid[0:480, 0:640]

    def spot(uv: np.ndarray) -> np.ndarray:
        g = 250 * np.exp(-((xx - uv[0, 0]) ** 2 + (yy - uv[0, 1]) ** 2) / (2 * 2.0**2))
        return np.repeat(g.astype(np.uint8)[:, :, None], 3, axis=2)

    left, right = cal.rectify(spot(uv_l), spot(uv_r))
    assert left.shape == right.shape == (480, 640, 3)

    def centroid(img: np.ndarray) -> np.ndarray:
        w = img[:, :, 0].astype(float)
        return np.array([(w * xx).sum(), (w * yy).sum()]) / w.sum()

    cl, cr = centroid(left), centroid(right)
    assert abs(cl[1] - cr[1]) < 0.2
    expected = cal.rectify_points(uv_l, "left")[0]
    assert np.abs(cl - expected).max() < 0.2
    depth = (point @ cal.R_left.T)[0, 2]
    assert cal.bf / (cl[0] - cr[0]) == pytest.approx(depth, rel=0.01)


# --- calibration files -----------------------------------------------------------------


def test_kitti_calib_txt(tmp_path: Path) -> None:
    path = tmp_path / "calib.txt"
    path.write_text(KITTI_00_CALIB)
    cal = read_kitti_calib(path)
    assert cal.rectified_input and cal.maps is None
    assert (cal.camera.fx, cal.camera.fy, cal.camera.cx, cal.camera.cy) == (718.856, 718.856, 607.1928, 185.2157)
    assert cal.baseline == pytest.approx(0.5372, abs=1e-4)
    assert cal.bf == pytest.approx(386.1448, rel=1e-12)  # ORB-SLAM2's KITTI00-02.yaml Camera.bf
    img = np.zeros((376, 1241, 3), np.uint8)
    left, right = cal.rectify(img, img)
    assert left is img and right is img


def test_euroc_sensor_yaml(tmp_path: Path) -> None:
    mav0 = tmp_path / "mav0"
    write_euroc_sensor(mav0 / "cam0" / "sensor.yaml", EUROC_CAM0)
    write_euroc_sensor(mav0 / "cam1" / "sensor.yaml", EUROC_CAM1)
    cam0, t_bs0 = read_euroc_sensor(mav0 / "cam0" / "sensor.yaml")
    assert (cam0.fx, cam0.fy, cam0.cx, cam0.cy, cam0.width, cam0.height) == (458.654, 457.296, 367.215, 248.375, 752, 480)
    assert cam0.dist == (-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05, 0.0)
    np.testing.assert_array_equal(t_bs0, np.reshape(EUROC_CAM0["T_BS"], (4, 4)))
    cal, t_bs = read_euroc_calibration(mav0)
    np.testing.assert_array_equal(t_bs, t_bs0)
    # The pair as ORB-SLAM3 publishes it for EuRoC (its values are rounded from these).
    np.testing.assert_allclose(cal.T_lr, ORBSLAM3_EUROC_T_C1_C2, atol=1e-6)
    assert cal.baseline == pytest.approx(0.110, abs=0.001)
    assert cal.baseline == pytest.approx(np.linalg.norm(ORBSLAM3_EUROC_T_C1_C2[:3, 3]), rel=1e-6)
    assert cal.bf == pytest.approx(cal.camera.fx * cal.baseline)
    assert (cal.camera.width, cal.camera.height) == (752, 480)
    assert cal.maps is not None and cal.maps[0].shape == (480, 752)


def test_orbslam3_settings_pinhole_matches_the_euroc_files(tmp_path: Path) -> None:
    mav0 = tmp_path / "mav0"
    write_euroc_sensor(mav0 / "cam0" / "sensor.yaml", EUROC_CAM0)
    write_euroc_sensor(mav0 / "cam1" / "sensor.yaml", EUROC_CAM1)
    from_files, _ = read_euroc_calibration(mav0)
    path = tmp_path / "EuRoC.yaml"
    write_settings(path, pinhole_settings(from_files.T_lr, EUROC_CAM0, EUROC_CAM1, (752, 480)))
    cal = read_orbslam3_settings(path)
    assert not cal.rectified_input
    # ORB-SLAM3 stores the matrix as float ("dt: f"): agreement to float precision
    np.testing.assert_allclose(cal.T_lr, from_files.T_lr, atol=1e-7)
    assert cal.baseline == pytest.approx(from_files.baseline, rel=1e-6)
    np.testing.assert_allclose(cal.camera.K, from_files.camera.K, rtol=1e-5)
    np.testing.assert_allclose(cal.maps[0], from_files.maps[0], atol=1e-2)


def test_orbslam3_settings_rectified(tmp_path: Path) -> None:
    path = tmp_path / "KITTI00-02.yaml"
    write_settings(path, 'Camera.type: "Rectified"\nCamera1.fx: 718.856\nCamera1.fy: 718.856\n'
                         "Camera1.cx: 607.1928\nCamera1.cy: 185.2157\nCamera.width: 1241\nCamera.height: 376\n"
                         "Camera.fps: 10\nStereo.ThDepth: 35.0\nStereo.b: 0.53716\n")
    cal = read_orbslam3_settings(path)
    assert cal.rectified_input and cal.maps is None
    assert (cal.camera.fx, cal.camera.cx, cal.camera.width, cal.camera.height) == (718.856, 607.1928, 1241, 376)
    assert cal.baseline == 0.53716
    assert cal.bf == pytest.approx(386.14, abs=0.01)


def test_explicit_values() -> None:
    cal = stereo_from_values("500,501,320,240", 0.12)
    assert (cal.camera.fx, cal.camera.fy, cal.baseline) == (500.0, 501.0, 0.12)
    assert cal.bf == pytest.approx(60.0)
    with pytest.raises(ConfigError, match="--baseline"):
        stereo_from_values("500,501,320,240", -0.1)


# --- bad input: one line naming the file and the problem -------------------------------


def test_bad_calibration_files(tmp_path: Path) -> None:
    calib = tmp_path / "calib.txt"
    calib.write_text(KITTI_00_CALIB.splitlines()[0] + "\n")
    with pytest.raises(DataError, match=r"calib\.txt: no P1 line"):
        read_kitti_calib(calib)
    settings = tmp_path / "camera.yaml"
    write_settings(settings, 'Camera.type: "Rectified"\nCamera1.fx: 500.0\nCamera1.fy: 500.0\n'
                             "Camera1.cx: 320.0\nCamera1.cy: 240.0\n")
    with pytest.raises(DataError, match=r"camera\.yaml: Stereo\.b missing"):
        read_orbslam3_settings(settings)
    write_settings(settings, 'Camera.type: "KannalaBrandt8"\n')
    with pytest.raises(DataError, match="Camera.type 'KannalaBrandt8'"):
        read_orbslam3_settings(settings)
    sensor = tmp_path / "sensor.yaml"
    write_euroc_sensor(sensor, {**EUROC_CAM0, "intrinsics": [458.654, 457.296, 367.215]})
    with pytest.raises(DataError, match=r"sensor\.yaml: intrinsics: expected 4 numbers"):
        read_euroc_sensor(sensor)
    with pytest.raises(DataError) as info:
        read_kitti_calib(calib)
    assert "\n" not in str(info.value) and str(info.value).startswith(str(calib))


# --- folders ---------------------------------------------------------------------------

W, H = 64, 48


def _png(path: Path, value: int) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), np.full((H, W), value, np.uint8))


def _euroc_folder(root: Path, n: int = 4, right_shift_ns: int = 0) -> list[int]:
    """A tiny EuRoC sequence: undistorted cameras 11 cm apart, uniform grey images."""
    stamps = [1403715273262142976 + k * 50_000_000 for k in range(n)]
    plain = {"intrinsics": [60.0, 60.0, 31.5, 23.5], "distortion_coefficients": [0.0, 0.0, 0.0, 0.0]}
    t0 = np.eye(4)
    t1 = np.eye(4)
    t1[0, 3] = 0.11  # body frame = cam0 frame here
    for cam, t_bs, shift, base in (("cam0", t0, 0, 10), ("cam1", t1, right_shift_ns, 100)):
        d = root / "mav0" / cam
        write_euroc_sensor(d / "sensor.yaml", {**plain, "T_BS": t_bs.reshape(-1).tolist()}, (W, H))
        lines = ["#timestamp [ns],filename"]
        for k, s in enumerate(stamps):
            lines.append(f"{s + shift},{s + shift}.png")
            _png(d / "data" / f"{s + shift}.png", base + k)
        (d / "data.csv").write_text("\n".join(lines) + "\n")
    gt = root / "mav0" / "state_groundtruth_estimate0" / "data.csv"
    gt.parent.mkdir(parents=True)
    rows = ["#timestamp,p_RS_R_x [m],p_RS_R_y [m],p_RS_R_z [m],q_RS_w [],q_RS_x [],q_RS_y [],q_RS_z []"]
    rows += [f"{s},{0.1 * k},0,0,1,0,0,0" for k, s in enumerate(stamps)]
    gt.write_text("\n".join(rows) + "\n")
    return stamps


def test_euroc_folder_pairs_by_timestamp(tmp_path: Path) -> None:
    stamps = _euroc_folder(tmp_path)
    assert stereo_layout(tmp_path) == "euroc"
    seq = open_stereo_sequence(tmp_path)
    assert len(seq) == 4 and not seq.has_depth
    np.testing.assert_array_equal(seq.timestamps, np.array(stamps, dtype=float) / 1e9)
    frames = list(seq)
    for k, f in enumerate(frames):
        assert f.right is not None and f.rgb.shape == f.right.shape == (H, W, 3)
        assert f.rgb_path.name == f.right_path.name == f"{stamps[k]}.png"
        assert f.right_path.parent.parent.name == "cam1"
        # uniform images stay uniform inside the rectified view
        assert f.rgb[H // 2, W // 2, 0] == 10 + k and f.right[H // 2, W // 2, 0] == 100 + k
    assert seq.calibration.baseline == pytest.approx(0.11, rel=1e-9)
    gt = seq.groundtruth()
    assert gt is not None
    np.testing.assert_allclose(gt.poses[:, 0, 3], [0.0, 0.1, 0.2, 0.3])


def test_euroc_ground_truth_is_body_pose_times_t_bs() -> None:
    """T_WC = T_WB T_BS: a body at x=1 looking along world x, a camera 0.5 m to its left
    (body y) and turned 90 degrees about z, is at (1, 0.5, 0) and looks along world y."""
    from semslam.core.trajectory import Trajectory

    body = np.eye(4)[None].repeat(1, 0)
    body[0, 0, 3] = 1.0
    t_bs = np.eye(4)
    t_bs[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
    t_bs[1, 3] = 0.5
    cam = euroc_camera_trajectory(Trajectory(np.array([0.0]), body), t_bs)
    np.testing.assert_allclose(cam.poses[0, :3, 3], [1.0, 0.5, 0.0])
    np.testing.assert_allclose(cam.poses[0, :3, 0], [0.0, 1.0, 0.0])


def test_kitti_folder_with_poses(tmp_path: Path) -> None:
    seq_dir = tmp_path / "dataset" / "sequences" / "00"
    for k in range(3):
        _png(seq_dir / "image_0" / f"{k:06d}.png", 10 + k)
        _png(seq_dir / "image_1" / f"{k:06d}.png", 100 + k)
    (seq_dir / "calib.txt").write_text("P0: 60 0 31.5 0 0 60 23.5 0 0 0 1 0\nP1: 60 0 31.5 -32.2 0 60 23.5 0 0 0 1 0\n")
    (seq_dir / "times.txt").write_text("0.000000e+00\n1.036602e-01\n2.073204e-01\n")
    poses = tmp_path / "dataset" / "poses" / "00.txt"
    poses.parent.mkdir(parents=True)
    poses.write_text("".join(f"1 0 0 {0.5 * k} 0 1 0 0 0 0 1 {k}\n" for k in range(3)))
    assert stereo_layout(seq_dir) == "kitti"
    seq = open_stereo_sequence(seq_dir)
    assert seq.calibration.baseline == pytest.approx(32.2 / 60)
    assert (seq.camera.width, seq.camera.height) == (W, H)
    frames = list(seq)
    assert [f.timestamp for f in frames] == [0.0, 0.1036602, 0.2073204]
    for k, f in enumerate(frames):  # rectified input: the images as stored
        assert np.all(f.rgb == 10 + k) and np.all(f.right == 100 + k)
    gt = seq.groundtruth()
    assert gt is not None and seq.groundtruth_source == poses
    np.testing.assert_array_equal(gt.timestamps, [0.0, 0.1036602, 0.2073204])
    np.testing.assert_array_equal(gt.poses[:, :3, 3], [[0, 0, 0], [0.5, 0, 1], [1.0, 0, 2]])


def test_tum_like_folder(tmp_path: Path) -> None:
    left_lines, right_lines = [], []
    for k in range(3):
        t = 1.0 + 0.1 * k
        _png(tmp_path / "rgb" / f"{t:.6f}.png", 10 + k)
        _png(tmp_path / "rgb_right" / f"{t:.6f}.png", 100 + k)
        left_lines.append(f"{t:.6f} rgb/{t:.6f}.png")
        right_lines.append(f"{t:.6f} rgb_right/{t:.6f}.png")
    right_lines.insert(0, "0.950000 rgb_right/extra.png")  # a right image with no left one: ignored
    _png(tmp_path / "rgb_right" / "extra.png", 0)
    (tmp_path / "rgb.txt").write_text("# timestamp filename\n" + "\n".join(left_lines) + "\n")
    (tmp_path / "rgb_right.txt").write_text("\n".join(right_lines) + "\n")
    write_settings(tmp_path / "camera.yaml", 'Camera.type: "Rectified"\nCamera1.fx: 60.0\nCamera1.fy: 60.0\n'
                                            "Camera1.cx: 31.5\nCamera1.cy: 23.5\nStereo.b: 0.11\n")
    assert stereo_layout(tmp_path) == "tum"
    seq = open_stereo_sequence(tmp_path)
    frames = list(seq)
    assert [f.right_path.name for f in frames] == ["1.000000.png", "1.100000.png", "1.200000.png"]
    assert [int(f.right[0, 0, 0]) for f in frames] == [100, 101, 102]
    assert seq.calibration.bf == pytest.approx(6.6)
    # explicit values win over the folder's file
    seq = open_stereo_sequence(tmp_path, camera="50,50,31.5,23.5", baseline=0.2)
    assert seq.calibration.bf == pytest.approx(10.0)
    with pytest.raises(ConfigError, match="needs both --camera fx,fy,cx,cy and --baseline"):
        open_stereo_sequence(tmp_path, camera="50,50,31.5,23.5")


def test_bad_folders(tmp_path: Path) -> None:
    a = tmp_path / "a"
    _euroc_folder(a)
    (a / "mav0" / "cam1" / "data.csv").unlink()
    with pytest.raises(DataError, match=r"cam1/data\.csv: file not found"):
        open_stereo_sequence(a)
    b = tmp_path / "b"
    _euroc_folder(b, right_shift_ns=5_000_000)  # right images 5 ms off: no pair
    with pytest.raises(DataError, match=r"cam0/data\.csv: line 2: image at .* has no right image"):
        open_stereo_sequence(b)
    c = tmp_path / "c"
    _euroc_folder(c, n=4)
    right_pngs = sorted((c / "mav0" / "cam1" / "data").glob("*.png"))
    right_pngs[1].unlink()  # one missing right image: that frame is skipped, by name
    seq = open_stereo_sequence(c)
    assert [f.index for f in seq] == [0, 2, 3]
    assert len(seq.skipped) == 1 and right_pngs[1].name in seq.skipped[0][1]
    for p in right_pngs[2:]:
        p.unlink()
    (c / "mav0" / "cam0" / "data" / right_pngs[0].name).unlink()
    with pytest.raises(DataError, match="file not found, and 3 more listed images are missing"):
        open_stereo_sequence(c)
    d = tmp_path / "d"
    d.mkdir()
    (d / "rgb.txt").write_text("1.0 rgb/1.png\n")
    (d / "rgb_right.txt").write_text("1.0 rgb_right/1.png\n")
    with pytest.raises(DataError, match="no stereo calibration"):
        open_stereo_sequence(d)
    with pytest.raises(DataError, match="not a stereo sequence"):
        open_stereo_sequence(tmp_path)


def test_a_euroc_pair_that_is_already_rectified_is_not_resampled(tmp_path: Path) -> None:
    # Same intrinsics, no distortion, no rotation, the right camera 11 cm along x (what
    # `semslam synth --layout-format euroc` writes): the images are used as they are.
    from semslam.io.stereo_calibration import read_euroc_calibration

    t_bs0 = np.array([[0.0, -1.0, 0.0, -0.02], [1.0, 0.0, 0.0, -0.06], [0.0, 0.0, 1.0, 0.01], [0, 0, 0, 1.0]])
    shift = np.eye(4)
    shift[0, 3] = 0.11
    for cam, t_bs in (("cam0", t_bs0), ("cam1", t_bs0 @ shift)):
        (tmp_path / cam).mkdir()
        rows = ", ".join(f"{v:.17g}" for v in t_bs.reshape(-1))
        (tmp_path / cam / "sensor.yaml").write_text(
            "sensor_type: camera\ncomment: test\n"
            f"T_BS:\n  cols: 4\n  rows: 4\n  data: [{rows}]\n"
            "rate_hz: 20\nresolution: [320, 240]\ncamera_model: pinhole\n"
            "intrinsics: [267.7, 251.4, 160.0, 120.0]\ndistortion_model: radial-tangential\n"
            "distortion_coefficients: [0.0, 0.0, 0.0, 0.0]\n")
    calib, _ = read_euroc_calibration(tmp_path)
    assert calib.rectified_input and calib.maps is None
    assert calib.baseline == pytest.approx(0.11, abs=1e-12)
    assert (calib.camera.fx, calib.camera.fy) == (267.7, 251.4)  # not resampled to one focal length
    left = np.random.default_rng(0).integers(0, 255, (240, 320, 3), dtype=np.uint8)
    out_l, out_r = calib.rectify(left, left[:, ::-1].copy())
    assert np.array_equal(out_l, left)
