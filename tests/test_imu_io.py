"""IMU input (issue 42, item 1): EuRoC / TUM-VI readings, the calibration sources (EuRoC
sensor.yaml, Kalibr, ORB-SLAM3 settings, plain values), the checks a recording must pass,
and EuRoC folders read as stereo, monocular (cam0) and RGB-D (cam0 + depth0) whose frames
carry their readings. Tiny hand-written folders; no rendering."""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np
import pytest

from semslam.core.imu import ImuSamples
from semslam.errors import ConfigError, DataError
from semslam.io.euroc_sequence import EurocSequence
from semslam.io.imu import (check_imu, imu_calibration_from_values, open_imu, read_euroc_imu,
                            read_euroc_imu_calibration, read_kalibr_imu_calibration, read_orbslam3_imu)
from semslam.io.sequence import ImageFolderSequence, TumRgbdSequence, kind_for_sensor, open_sequence
from semslam.io.stereo_sequence import StereoSequence, open_stereo_sequence
from tests.test_stereo_io import EUROC_CAM0, _euroc_folder, write_euroc_sensor, write_settings

HEADER = ("#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
          "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]")
STEP_NS = 5_000_000  # 200 Hz

# EuRoC V1_01's imu0/sensor.yaml as published (comments, a '#' header line, block T_BS).
EUROC_IMU_YAML = """\
#Default imu sensor yaml file
sensor_type: imu
comment: VI-Sensor IMU (ADIS16448)

# Sensor extrinsics wrt. the body-frame.
T_BS:
  cols: 4
  rows: 4
  data: [{t_bs}]
rate_hz: 200

# inertial sensor noise model parameters (static)
gyroscope_noise_density: 1.6968e-04     # [ rad / s / sqrt(Hz) ]   ( gyro "white noise" )
gyroscope_random_walk: 1.9393e-05       # [ rad / s^2 / sqrt(Hz) ] ( gyro bias diffusion )
accelerometer_noise_density: 2.0000e-3  # [ m / s^2 / sqrt(Hz) ]  ( accel "white noise" )
accelerometer_random_walk: 3.0000e-3    # [ m / s^3 / sqrt(Hz) ].  ( accel bias diffusion )
"""


def _pose(rvec: tuple[float, float, float], t: tuple[float, float, float]) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64))[0]
    pose[:3, 3] = t
    return pose


def write_imu(mav0: Path, start_ns: int, end_ns: int, t_bs: np.ndarray | None = None,
              drop: tuple[int, int] | None = None) -> np.ndarray:
    """imu0/data.csv at 200 Hz from start to end (inclusive), readings that encode their
    index, and imu0/sensor.yaml; ``drop`` leaves out readings [a, b). Returns the ns stamps."""
    stamps = np.arange(start_ns, end_ns + 1, STEP_NS, dtype=np.int64)
    if drop is not None:
        stamps = np.delete(stamps, np.arange(*drop))
    folder = mav0 / "imu0"
    folder.mkdir(parents=True, exist_ok=True)
    rows = [HEADER] + [f"{s},{0.001 * k},0.0,-0.01,0.1,9.81,{0.01 * k}" for k, s in enumerate(stamps)]
    (folder / "data.csv").write_text("\n".join(rows) + "\n")
    t_bs = np.eye(4) if t_bs is None else t_bs
    (folder / "sensor.yaml").write_text(EUROC_IMU_YAML.format(t_bs=", ".join(repr(float(v)) for v in t_bs.reshape(-1))))
    return stamps


def euroc_with_imu(root: Path, n: int = 4, depth: bool = False, cam1: bool = True) -> tuple[list[int], np.ndarray]:
    """test_stereo_io's tiny EuRoC folder (cam0 + cam1, 50 ms apart) with an IMU from 20 ms
    before the first image to 20 ms after the last, and optionally depth0 (2.5 m, 1000 per metre)."""
    stamps = _euroc_folder(root, n)
    mav0 = root / "mav0"
    imu = write_imu(mav0, stamps[0] - 4 * STEP_NS, stamps[-1] + 4 * STEP_NS)
    if not cam1:
        for f in sorted((mav0 / "cam1").rglob("*"), reverse=True):
            f.unlink() if f.is_file() else f.rmdir()
        (mav0 / "cam1").rmdir()
    if depth:
        d = mav0 / "depth0"
        (d / "data").mkdir(parents=True)
        for k, s in enumerate(stamps):
            img = np.full((48, 64), 2500 + 100 * k, np.uint16)
            img[0, 0] = 0  # no measurement
            cv2.imwrite(str(d / "data" / f"{s}.png"), img)
        (d / "data.csv").write_text("#timestamp [ns],filename\n" + "".join(f"{s},{s}.png\n" for s in stamps))
        (d / "sensor.yaml").write_text("sensor_type: depth\ndepth_scale: 1000.0\nT_BS:\n  cols: 4\n  rows: 4\n"
                                       "  data: [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, "
                                       "0.0, 0.0, 0.0, 1.0]\n")
    return stamps, imu


# --- readings and calibration ----------------------------------------------------------


def test_read_euroc_imu_and_its_sensor_yaml(tmp_path: Path) -> None:
    mav0 = tmp_path / "mav0"
    t_imu = _pose((0.01, -0.02, 0.03), (0.1, 0.0, -0.05))
    stamps = write_imu(mav0, 1403715273262142976, 1403715273262142976 + 9 * STEP_NS, t_imu)
    samples = read_euroc_imu(mav0 / "imu0" / "data.csv")
    assert len(samples) == 10 and samples.t.dtype == np.float64
    np.testing.assert_array_equal(samples.t, [float(s) / 1e9 for s in stamps])  # as the image lists convert
    # float64 seconds near 1.4e9 s are exact to half an ulp (1.2e-7 s): a step's error is at most 2.4e-7 s
    np.testing.assert_allclose(np.diff(samples.t), 0.005, atol=2.5e-7, rtol=0)
    np.testing.assert_allclose(samples.gyro[3], [0.003, 0.0, -0.01])
    np.testing.assert_allclose(samples.acc[3], [0.1, 9.81, 0.03])

    write_euroc_sensor(mav0 / "cam0" / "sensor.yaml", EUROC_CAM0)
    cal = read_euroc_imu_calibration(mav0)
    assert (cal.noise.gyro_noise_density, cal.noise.acc_noise_density) == (1.6968e-04, 2.0e-3)
    assert (cal.noise.gyro_random_walk, cal.noise.acc_random_walk, cal.noise.rate_hz) == (1.9393e-05, 3.0e-3, 200.0)
    # cam0 -> IMU: through the body frame, x_B = T_BS_imu x_I and x_B = T_BS_cam x_C
    t_cam = np.reshape(EUROC_CAM0["T_BS"], (4, 4))
    np.testing.assert_allclose(cal.T_bc, np.linalg.inv(t_imu) @ t_cam, atol=1e-12)
    x_c = np.array([0.3, -0.2, 1.5, 1.0])
    np.testing.assert_allclose(t_imu @ (cal.T_bc @ x_c), t_cam @ x_c, atol=1e-12)


def test_tum_vi_kalibr_files(tmp_path: Path) -> None:
    t_cam_imu = _pose((1.2, -0.4, 2.0), (0.0456, -0.0712, -0.0447))
    dso = tmp_path / "dataset-room1_512_16" / "dso"
    dso.mkdir(parents=True)
    rows = "\n".join(f"  - [{', '.join(repr(float(v)) for v in row)}]" for row in t_cam_imu)
    (dso / "camchain.yaml").write_text(f"cam0:\n  T_cam_imu:\n{rows}\n  cam_overlaps: [1]\n  camera_model: pinhole\n"
                                       "  distortion_model: equidistant\n  resolution: [512, 512]\n"
                                       "  rostopic: /cam0/image_raw\n")
    (dso / "imu_config.yaml").write_text("accelerometer_noise_density: 0.0028     # m/s^1.5\n"
                                         "accelerometer_random_walk:   0.00086    # m/s^2.5\n"
                                         "gyroscope_noise_density:     0.00016    # rad/s^0.5\n"
                                         "gyroscope_random_walk:       0.000022   # rad/s^1.5\n"
                                         "rostopic:                    /imu0\nupdate_rate:                 200.0\n")
    cal = read_kalibr_imu_calibration(dso / "camchain.yaml", dso / "imu_config.yaml")
    assert (cal.noise.acc_noise_density, cal.noise.acc_random_walk) == (0.0028, 0.00086)
    assert (cal.noise.gyro_noise_density, cal.noise.gyro_random_walk, cal.noise.rate_hz) == (0.00016, 0.000022, 200.0)
    np.testing.assert_allclose(cal.T_bc, np.linalg.inv(t_cam_imu), atol=1e-12)
    # open_imu finds TUM-VI's mav0/imu0 and the dso/ beside it (no imu0/sensor.yaml there)
    mav0 = dso.parent / "mav0"
    write_imu(mav0, 10**18, 10**18 + 20 * STEP_NS)
    (mav0 / "imu0" / "sensor.yaml").unlink()
    stream = open_imu(dso.parent)
    assert stream is not None and len(stream.samples) == 21
    np.testing.assert_allclose(stream.calibration.T_bc, cal.T_bc)
    (dso / "imu_config.yaml").write_text("accelerometer_noise_density: 0.0028\n")
    with pytest.raises(DataError, match=r"imu_config\.yaml: no gyroscope_noise_density"):
        open_imu(dso.parent)


def test_orbslam3_settings_imu(tmp_path: Path) -> None:
    t_b_c1 = np.reshape(EUROC_CAM0["T_BS"], (4, 4))
    matrix = ("!!opencv-matrix\n   rows: 4\n   cols: 4\n   dt: f\n   data: ["
              + ", ".join(repr(float(v)) for v in t_b_c1.reshape(-1)) + "]\n")
    imu = ("IMU.NoiseGyro: 1.7e-4 #1.6968e-04\nIMU.NoiseAcc: 2.0000e-3 #2.0e-3\nIMU.GyroWalk: 1.9393e-05\n"
           "IMU.AccWalk: 3.0000e-03 # 3e-03\nIMU.Frequency: 200.0\n")
    path = tmp_path / "EuRoC.yaml"
    write_settings(path, 'Camera.type: "PinHole"\nIMU.T_b_c1: ' + matrix + "IMU.InsertKFsWhenLost: 0\n" + imu)
    cal = read_orbslam3_imu(path)
    assert (cal.noise.gyro_noise_density, cal.noise.acc_noise_density, cal.noise.gyro_random_walk,
            cal.noise.acc_random_walk, cal.noise.rate_hz) == (1.7e-4, 2.0e-3, 1.9393e-05, 3.0e-3, 200.0)
    np.testing.assert_allclose(cal.T_bc, t_b_c1, atol=1e-7)  # "dt: f": float precision
    write_settings(path, "Tbc: " + matrix + imu)  # before v1.0
    np.testing.assert_allclose(read_orbslam3_imu(path).T_bc, t_b_c1, atol=1e-7)
    write_settings(path, "Tbc: " + matrix + imu.replace("IMU.AccWalk", "IMU.AccWalkk"))
    with pytest.raises(DataError, match=r"EuRoC\.yaml: IMU\.AccWalk missing"):
        read_orbslam3_imu(path)
    write_settings(path, imu)
    with pytest.raises(DataError, match=r"EuRoC\.yaml: IMU\.T_b_c1 missing"):
        read_orbslam3_imu(path)


def test_calibration_from_values() -> None:
    values = {"gyro_noise_density": 1.7e-4, "acc_noise_density": 2e-3, "gyro_random_walk": 2e-5,
              "acc_random_walk": 3e-3, "rate_hz": 100, "T_bc": np.eye(4).tolist()}
    cal = imu_calibration_from_values(values)
    assert cal.noise.rate_hz == 100.0 and cal.noise.acc_random_walk == 3e-3
    np.testing.assert_array_equal(cal.T_bc, np.eye(4))
    with pytest.raises(ConfigError, match=r"imu\.acc_noise_density: missing"):
        imu_calibration_from_values({k: v for k, v in values.items() if k != "acc_noise_density"})
    with pytest.raises(ConfigError, match=r"imu\.gyro_random_walk: expected a number >= 0"):
        imu_calibration_from_values({**values, "gyro_random_walk": -1.0})
    with pytest.raises(ConfigError, match=r"imu\.T_bc: not a rigid transform"):
        imu_calibration_from_values({**values, "T_bc": (2 * np.eye(4)).tolist()})


def test_bad_files_are_one_line_naming_the_file_and_where(tmp_path: Path) -> None:
    mav0 = tmp_path / "mav0"
    write_imu(mav0, 10**18, 10**18 + 5 * STEP_NS)
    csv = mav0 / "imu0" / "data.csv"
    lines = csv.read_text().splitlines()
    for k, (bad, match) in enumerate([
        ("1000000000010000000,0.1,0.2", r"line 3: expected 'timestamp_ns,w_x"),
        ("1000000000010000000,0.1,0.2,x,0,0,9.8", r"line 3: a reading is not a number"),
        ("1000000000010000000,0.1,0.2,nan,0,0,9.8", r"line 3: a reading is not finite"),
        ("1000000000000000000,0.1,0.2,0.3,0,0,9.8", r"line 3: timestamp 1000000000000000000 is not after"),
    ]):
        csv.write_text("\n".join(lines[:2] + [bad] + lines[3:]) + "\n")
        with pytest.raises(DataError, match=match) as info:
            read_euroc_imu(csv)
        assert str(info.value).startswith(str(csv)) and "\n" not in str(info.value), k
    csv.write_text(HEADER + "\n")
    with pytest.raises(DataError, match=r"data\.csv: no IMU readings"):
        read_euroc_imu(csv)
    write_imu(mav0, 10**18, 10**18 + 5 * STEP_NS)
    (mav0 / "imu0" / "sensor.yaml").write_text("rate_hz: 200\ngyroscope_noise_density: 1.0e-4\n")
    with pytest.raises(DataError, match=r"imu0/sensor\.yaml: no accelerometer_noise_density"):
        read_euroc_imu_calibration(mav0)


# --- checks ----------------------------------------------------------------------------


def _samples(t: np.ndarray) -> ImuSamples:
    return ImuSamples(np.asarray(t, dtype=np.float64), np.zeros((len(t), 3)), np.tile([0.0, 0.0, 9.81], (len(t), 1)))


@pytest.mark.parametrize(("samples", "frames", "match"), [
    (ImuSamples.empty(), [1.0], r"no IMU readings"),
    (_samples(np.r_[1.0, 1.005, 1.005, 1.01]), [1.0], r"IMU reading 2 at 1\.005000000 s is not after the previous one"),
    (_samples(np.r_[1.0, 1.01, 1.005]), [1.0], r"IMU reading 2 at 1\.005000000 s is not after"),
    (ImuSamples(np.arange(5) * 0.005, np.r_[np.zeros((3, 3)), [[np.nan, 0, 0]], np.zeros((1, 3))], np.zeros((5, 3))),
     [0.0], r"IMU reading 3 \(t = 0\.015000 s\) is not finite"),
    (_samples(1.0 + np.arange(100) * 0.005), [0.9, 0.95, 1.0, 1.05], r"the IMU starts at 1\.000000 s, 0\.100 s after "
                                                                     r"the first frame: frames 0-1 \(2 frames\) come before"),
    (_samples(1.0 + np.arange(100) * 0.005), [1.1, 1.3, 1.5, 1.6], r"the IMU ends at 1\.495000 s, 0\.105 s before the "
                                                                   r"last frame: frame 3 comes after its last reading"),
    (_samples(np.r_[1.0 + np.arange(20) * 0.005, 1.5 + np.arange(20) * 0.005]), [1.0, 1.2, 1.3, 1.55],
     r"a gap of 0\.405 s in the IMU readings between 1\.095000 and 1\.500000 s .*frames 1-2 \(2 frames\) fall in it"),
])
def test_check_imu_errors_are_one_line(samples: ImuSamples, frames: list[float], match: str) -> None:
    source = Path("seq/mav0/imu0/data.csv")
    with pytest.raises(DataError, match=match) as info:
        check_imu(samples, np.asarray(frames), source)
    assert str(info.value).startswith(str(source) + ": ") and "\n" not in str(info.value)


def test_check_imu_accepts_one_period_of_slack_and_gaps_outside_the_frames() -> None:
    t = np.r_[1.0 + np.arange(20) * 0.005, 2.0 + np.arange(20) * 0.005]  # a pause after the frames
    check_imu(_samples(t), np.array([0.996, 1.05, 1.09]), "x")
    check_imu(_samples(t), np.array([1.0, 1.05, 1.097]), "x")


# --- sequences: frames carry their readings --------------------------------------------


def _check_frames_carry_the_stream(seq: object, stamps: list[int], imu_ns: np.ndarray) -> None:
    frames = list(seq.frames())  # type: ignore[attr-defined]
    t_imu = imu_ns.astype(np.float64) / 1e9
    assert len(frames) == len(stamps)
    for prev, frame in zip([None, *frames[:-1]], frames):
        assert frame.imu is not None
        if prev is None:  # the first frame: the last reading at or before it
            np.testing.assert_array_equal(frame.imu.t, t_imu[t_imu <= frame.timestamp][-1:])
        else:
            want = t_imu[(t_imu > prev.timestamp) & (t_imu <= frame.timestamp)]
            np.testing.assert_array_equal(frame.imu.t, want)
            assert len(want) == 10 and frame.imu.t[-1] == frame.timestamp  # 50 ms at 200 Hz, one on the image
    whole = ImuSamples.concatenate([f.imu for f in frames])
    span = (t_imu >= frames[0].timestamp) & (t_imu <= frames[-1].timestamp)
    np.testing.assert_array_equal(whole.t, t_imu[span])
    full = read_euroc_imu(seq.root / "mav0" / "imu0" / "data.csv")  # type: ignore[attr-defined]
    np.testing.assert_array_equal(whole.acc, full.acc[span])


def test_euroc_stereo_frames_carry_their_imu_readings(tmp_path: Path) -> None:
    stamps, imu = euroc_with_imu(tmp_path)
    seq = open_stereo_sequence(tmp_path)
    assert isinstance(seq, StereoSequence) and seq.imu is not None
    assert seq.imu.calibration.noise.rate_hz == 200.0
    np.testing.assert_array_equal(seq.imu.calibration.T_bc, np.eye(4))
    _check_frames_carry_the_stream(seq, stamps, imu)
    assert isinstance(open_sequence(tmp_path), StereoSequence)  # auto: cam1 -> stereo, as before


def test_euroc_mono_reads_cam0_with_its_imu_and_ground_truth(tmp_path: Path) -> None:
    stamps, imu = euroc_with_imu(tmp_path)
    seq = open_sequence(tmp_path, kind=kind_for_sensor("mono"))
    assert isinstance(seq, EurocSequence) and not seq.has_depth and seq.imu is not None
    assert (seq.camera.fx, seq.camera.width, seq.camera.height) == (60.0, 64, 48)
    np.testing.assert_array_equal(seq.timestamps, np.array(stamps, dtype=float) / 1e9)
    _check_frames_carry_the_stream(seq, stamps, imu)
    frame = next(iter(seq))
    assert frame.right is None and frame.depth is None and frame.rgb_path.parent.parent.name == "cam0"
    gt = seq.groundtruth()
    assert gt is not None and seq.groundtruth_path is not None and seq.groundtruth_path.is_file()
    np.testing.assert_allclose(gt.poses[:, 0, 3], [0.0, 0.1, 0.2, 0.3])
    # without cam1 and depth0, auto reads cam0 alone too
    mono_only = tmp_path / "mono"
    euroc_with_imu(mono_only, cam1=False)
    assert isinstance(open_sequence(mono_only / "mav0"), EurocSequence)


def test_euroc_rgbd_decodes_depth0_with_its_scale(tmp_path: Path) -> None:
    stamps, imu = euroc_with_imu(tmp_path, depth=True)
    assert isinstance(open_sequence(tmp_path), StereoSequence)  # auto with cam1: stereo, as before
    seq = open_sequence(tmp_path, kind=kind_for_sensor("rgbd"))  # --sensor rgbd: depth0
    assert isinstance(seq, EurocSequence) and seq.has_depth and seq.depth_scale == 1000.0
    _check_frames_carry_the_stream(seq, stamps, imu)
    for k, frame in enumerate(seq):
        assert frame.depth is not None and frame.depth.dtype == np.float32 and frame.depth.shape == (48, 64)
        assert frame.depth[5, 5] == pytest.approx(2.5 + 0.1 * k) and frame.depth[0, 0] == 0.0
        assert frame.depth_path is not None and frame.depth_path.name == f"{stamps[k]}.png"
    no_cam1 = tmp_path / "no_cam1"
    euroc_with_imu(no_cam1, depth=True, cam1=False)
    assert open_sequence(no_cam1).has_depth  # auto without cam1: depth0


def test_sensor_kinds_elsewhere_are_unchanged(tmp_path: Path, tum_folder: Path) -> None:
    """--sensor rgbd still reads a TUM folder's lists, and an input without depth opens as
    auto did (an image folder; a stereo folder, which the run then takes as stereo)."""
    assert kind_for_sensor("rgbd") == "rgbd" and kind_for_sensor("lidar") == "auto"
    assert isinstance(open_sequence(tum_folder, kind=kind_for_sensor("rgbd")), TumRgbdSequence)
    assert isinstance(open_sequence(tum_folder / "rgb", kind="rgbd"), ImageFolderSequence)
    euroc_with_imu(tmp_path / "stereo")
    assert isinstance(open_sequence(tmp_path / "stereo", kind="rgbd"), StereoSequence)


def test_euroc_errors(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    # an IMU that stops in the middle of the frames: one line naming imu0/data.csv at opening
    stamps = _euroc_folder(tmp_path / "gap")
    write_imu(tmp_path / "gap" / "mav0", stamps[0] - 4 * STEP_NS, stamps[-1] + 4 * STEP_NS, drop=(10, 30))
    with pytest.raises(DataError, match=r"imu0/data\.csv: a gap of 0\.105 s .*frames 1-2 \(2 frames\) fall in it") as info:
        open_sequence(tmp_path / "gap")
    assert "\n" not in str(info.value)
    # an IMU that starts after the first image
    stamps = _euroc_folder(tmp_path / "late")
    write_imu(tmp_path / "late" / "mav0", stamps[1], stamps[-1])
    with pytest.raises(DataError, match=r"imu0/data\.csv: the IMU starts at .* frame 0 comes before its first reading"):
        open_sequence(tmp_path / "late", kind="mono")
    # readings without a calibration: not used, with a warning
    stamps = _euroc_folder(tmp_path / "nocal")
    write_imu(tmp_path / "nocal" / "mav0", stamps[0], stamps[-1])
    (tmp_path / "nocal" / "mav0" / "imu0" / "sensor.yaml").unlink()
    with caplog.at_level(logging.WARNING):
        assert open_sequence(tmp_path / "nocal").imu is None
    assert "no IMU calibration" in caplog.text
    # depth0 listed but not registered to cam0
    euroc_with_imu(tmp_path / "reg", depth=True)
    sensor = tmp_path / "reg" / "mav0" / "depth0" / "sensor.yaml"
    sensor.write_text(sensor.read_text().replace("data: [1.0, 0.0, 0.0, 0.0,", "data: [1.0, 0.0, 0.0, 0.2,"))
    with pytest.raises(DataError, match=r"depth0/sensor\.yaml: T_BS is not cam0's"):
        open_sequence(tmp_path / "reg", kind="rgbd")
    assert open_imu(tmp_path / "nowhere") is None


# --- a stereo bag with an IMU topic (ORB-SLAM3 stereo-inertial settings) ----------------


def test_stereo_bag_with_imu_settings_carries_the_imu_topic(tmp_path: Path) -> None:
    from rosbags.rosbag1 import Writer

    from semslam.io.rosbag_stereo import open_rosbag
    from tests.test_rosbag_stereo import BASELINE, CX, CY, EUROC, FX, FY, H, M, N, STORE, T0, W, _header, pair

    bag = tmp_path / "MH_01.bag"
    imu_t = T0 - 0.02 + 0.005 * np.arange(int(round((0.05 * (N - 1) + 0.04) / 0.005)) + 1)
    with Writer(bag) as w:
        conns = [w.add_connection(t, "sensor_msgs/msg/Image", typestore=STORE) for t in EUROC]
        for k in range(N):
            for side, (conn, img) in enumerate(zip(conns, pair(k, 1))):
                msg = M["sensor_msgs/msg/Image"](header=_header(T0 + 0.05 * k, f"cam{side}", k), height=H, width=W,
                                                 encoding="mono8", is_bigendian=0, step=W,
                                                 data=np.ascontiguousarray(img).reshape(-1))
                w.write(conn, int(round((T0 + 0.05 * k) * 1e9)), STORE.serialize_ros1(msg, "sensor_msgs/msg/Image"))
        c = w.add_connection("/imu0", "sensor_msgs/msg/Imu", typestore=STORE)
        vec, quat = M["geometry_msgs/msg/Vector3"], M["geometry_msgs/msg/Quaternion"]
        for k, t in enumerate(imu_t):
            msg = M["sensor_msgs/msg/Imu"](header=_header(float(t), "imu4", k), orientation=quat(x=0, y=0, z=0, w=1),
                                           orientation_covariance=np.zeros(9), angular_velocity=vec(x=0.001 * k, y=0, z=0),
                                           angular_velocity_covariance=np.zeros(9),
                                           linear_acceleration=vec(x=0, y=0, z=9.81), linear_acceleration_covariance=np.zeros(9))
            w.write(c, int(round(float(t) * 1e9)), STORE.serialize_ros1(msg, "sensor_msgs/msg/Imu"))
    settings = tmp_path / "EuRoC_inertial.yaml"
    stereo = (f'Camera.type: "Rectified"\nCamera1.fx: {FX}\nCamera1.fy: {FY}\nCamera1.cx: {CX}\nCamera1.cy: {CY}\n'
              f"Camera.width: {W}\nCamera.height: {H}\nStereo.b: {BASELINE}\n")
    imu = ("IMU.NoiseGyro: 1.7e-4\nIMU.NoiseAcc: 2.0e-3\nIMU.GyroWalk: 1.9393e-05\nIMU.AccWalk: 3.0e-03\n"
           "IMU.Frequency: 200.0\nIMU.T_b_c1: !!opencv-matrix\n   rows: 4\n   cols: 4\n   dt: f\n"
           "   data: [1., 0., 0., 0., 0., 1., 0., 0., 0., 0., 1., 0., 0., 0., 0., 1.]\n")
    write_settings(settings, stereo + imu)
    seq = open_rosbag(bag, read_as="stereo", settings=settings)
    assert seq.imu is not None and seq.imu.calibration.noise.gyro_noise_density == 1.7e-4
    np.testing.assert_allclose(seq.imu.samples.t, imu_t, atol=1e-6)
    frames = list(seq.frames())
    for prev, frame in zip(frames, frames[1:]):
        assert frame.imu is not None
        np.testing.assert_array_equal(frame.imu.t, seq.imu.samples.t[(seq.imu.samples.t > prev.timestamp)
                                                                     & (seq.imu.samples.t <= frame.timestamp)])
    write_settings(settings, stereo)  # a visual-only settings file: no IMU
    assert open_rosbag(bag, read_as="stereo", settings=settings).imu is None
