"""Writing a synthetic render in the EuRoC ASL layout (issue 41): ``mav0/cam0``, ``mav0/cam1``
and ``mav0/state_groundtruth_estimate0``, as the EuRoC MAV dataset and its readers (ORB-SLAM3's
examples, evo's ``read_euroc_csv_trajectory``) expect.

EuRoC's ground truth is the pose of a body frame B, not of a camera; each camera's
``sensor.yaml`` holds ``T_BS``, the camera's pose in the body frame (a point x_S in the camera
frame is ``T_BS x_S`` in the body frame). :data:`T_BS_CAM0` is EuRoC's own cam0 extrinsics,
rounded (a 90 degree turn about z and a few centimetres): not the identity, so a reader that
forgets ``T_BS`` is caught. The body's pose is then
``T_WB = T_WC0 @ inv(T_BS_CAM0)`` and cam1's ``T_BS = T_BS_CAM0 @ T_LR`` (the baseline).
Images are the left and right RGB renders (EuRoC's are grey; readers convert).

Issue 42 adds, on request, ``mav0/imu0`` (a simulated 200 Hz IMU at the body frame, so its
``T_BS`` is the identity as EuRoC's; ``synth/imu.py``) with the true biases in the ground
truth's bias columns, and ``mav0/depth0``: the render's Kinect-like depth registered to cam0
(same stamps, intrinsics and ``T_BS``), 16-bit PNGs in TUM's scale (metres x 5000). All
stamps are on one integer-nanosecond clock (:func:`ns_stamps`, :func:`imu_ns`).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from semslam.errors import DataError
from semslam.geometry.se3 import invert, pose_to_tum
from semslam.core.imu import ImuNoise
from semslam.synth import stereo, writer
from semslam.synth.depth_noise import DEPTH_SCALE
from semslam.synth.imu import SimulatedImu

#: cam0 in the body frame: EuRoC MH_01's cam0 T_BS rounded to a clean rotation (camera x =
#: body y, camera y = -body x, camera z = body z) and its lever arm to the centimetre.
T_BS_CAM0 = np.array([
    [0.0, -1.0, 0.0, -0.02],
    [1.0, 0.0, 0.0, -0.06],
    [0.0, 0.0, 1.0, 0.01],
    [0.0, 0.0, 0.0, 1.0],
])
MAV = "mav0"
GT_DIR = "state_groundtruth_estimate0"
IMU_DIR = "imu0"
DEPTH_DIR = "depth0"
#: Header of EuRoC's ``imu0/data.csv`` (gyroscope, then accelerometer, in the IMU frame S).
IMU_HEADER = ("#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
              "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]")
#: Header of EuRoC's ground-truth CSV (position, quaternion w first, velocity, biases).
GT_HEADER = ("#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], "
             "q_RS_z [], v_RS_R_x [m s^-1], v_RS_R_y [m s^-1], v_RS_R_z [m s^-1], b_w_RS_S_x [rad s^-1], "
             "b_w_RS_S_y [rad s^-1], b_w_RS_S_z [rad s^-1], b_a_RS_S_x [m s^-2], b_a_RS_S_y [m s^-2], "
             "b_a_RS_S_z [m s^-2]")
VELOCITY_STEP_S = 1e-4  # central differences of the body's path for v_RS_R


def ns_stamps(start_time: float, frames: int, fps: float) -> NDArray[np.int64]:
    """Frame times in integer nanoseconds (EuRoC's stamps and file names)."""
    return int(round(start_time * 1e9)) + np.round(np.arange(frames) * 1e9 / fps).astype(np.int64)


def cam_t_bs(cam: int, baseline: float) -> NDArray[np.float64]:
    """T_BS of ``cam0`` (left) or ``cam1`` (right, the baseline along the left camera's x)."""
    return T_BS_CAM0 if cam == 0 else T_BS_CAM0 @ stereo.left_to_right(baseline)


def body_poses(cam0_poses: NDArray[np.float64]) -> NDArray[np.float64]:
    """T_WB of the body from the left camera's T_WC0 (``(N, 4, 4)``)."""
    return cam0_poses @ invert(T_BS_CAM0)


def cam_dir(out: Path, cam: int) -> Path:
    return out / MAV / f"cam{cam}"


def prepare(out: Path, cams: int, imu: bool = False, depth: bool = False) -> None:
    """Create ``out/mav0/camX/data`` for ``cams`` cameras, the ground-truth folder and, when
    asked, ``imu0`` and ``depth0/data``; remove the PNGs of an earlier rendering there (and the
    lists of a right camera, IMU or depth camera that is not rendered now, which would
    announce one)."""
    try:
        for cam in range(2):
            data = cam_dir(out, cam) / "data"
            if cam < cams:
                data.mkdir(parents=True, exist_ok=True)
            for old in data.glob("*.png"):
                old.unlink()
            if cam >= cams:
                _remove_lists(cam_dir(out, cam))
        (out / MAV / GT_DIR).mkdir(parents=True, exist_ok=True)
        if imu:
            (out / MAV / IMU_DIR).mkdir(parents=True, exist_ok=True)
        else:
            _remove_lists(out / MAV / IMU_DIR)
        depth_data = out / MAV / DEPTH_DIR / "data"
        if depth:
            depth_data.mkdir(parents=True, exist_ok=True)
        for old in depth_data.glob("*.png"):
            old.unlink()
        if not depth:
            _remove_lists(out / MAV / DEPTH_DIR)
    except OSError as exc:
        raise DataError(out, f"cannot create the output folder: {exc.strerror or exc}") from exc


def _remove_lists(sensor: Path) -> None:
    for name in ("data.csv", "sensor.yaml"):
        (sensor / name).unlink(missing_ok=True)


def write_frame(out: Path, cam: int, ns: int, rgb: NDArray[np.uint8]) -> None:
    writer.write_png(cam_dir(out, cam) / "data" / f"{ns}.png", rgb)


def write_depth_frame(out: Path, ns: int, depth: NDArray[np.uint16]) -> None:
    """``depth0/data/<ns>.png``: 16-bit, metres x 5000, 0 = no depth (as the TUM layout's depth/)."""
    writer.write_png(out / MAV / DEPTH_DIR / "data" / f"{ns}.png", depth)


def write_data_csv(path: Path, stamps: NDArray[np.int64]) -> None:
    """``camX/data.csv``: ``#timestamp [ns],filename`` then one ``ns,ns.png`` line per frame."""
    path.write_text("#timestamp [ns],filename\n" + "".join(f"{s},{s}.png\n" for s in stamps))


def _t_bs_lines(t_bs: NDArray[np.float64]) -> list[str]:
    """``T_BS`` as EuRoC writes it: row-major in ``data``, one row a line."""
    rows = [", ".join(_real(v) for v in r) for r in t_bs]
    data = (",\n" + " " * 9).join(rows)
    return ["# Sensor extrinsics wrt. the body-frame.", "T_BS:", "  cols: 4", "  rows: 4", f"  data: [{data}]"]


def _pinhole_lines(fps: float, width: int, height: int, intrinsics: tuple[float, float, float, float]) -> list[str]:
    return [
        f"rate_hz: {fps:g}",
        f"resolution: [{width}, {height}]",
        "camera_model: pinhole",
        "intrinsics: [{}] #fu, fv, cu, cv".format(", ".join(_real(v) for v in intrinsics)),
    ]


def sensor_yaml(cam: int, t_bs: NDArray[np.float64], fps: float, width: int, height: int,
                intrinsics: tuple[float, float, float, float]) -> str:
    """A camera's ``sensor.yaml`` in EuRoC's words (``T_BS`` row-major in ``data``)."""
    side = "left" if cam == 0 else "right"
    return "\n".join([
        "# General sensor definitions.",
        "sensor_type: camera",
        f"comment: semslam synth cam{cam} ({side}; rectified pinhole, no distortion)",
        "",
        *_t_bs_lines(t_bs),
        "",
        "# Camera specific definitions.",
        *_pinhole_lines(fps, width, height, intrinsics),
        "distortion_model: radial-tangential",
        "distortion_coefficients: [0.0, 0.0, 0.0, 0.0]",
    ]) + "\n"


def imu_sensor_yaml(noise: ImuNoise) -> str:
    """``imu0/sensor.yaml`` as EuRoC's (the IMU is the body frame: ``T_BS`` the identity)."""
    return "\n".join([
        "# General sensor definitions.",
        "sensor_type: imu",
        "comment: semslam synth imu0 (simulated, EuRoC's ADIS16448 noise model; see sequence.json)",
        "",
        *_t_bs_lines(np.eye(4)),
        f"rate_hz: {noise.rate_hz:g}",
        "",
        "# inertial sensor noise model parameters (static)",
        f"gyroscope_noise_density: {_sci(noise.gyro_noise_density)}  # [ rad / s / sqrt(Hz) ] (gyro white noise)",
        f"gyroscope_random_walk: {_sci(noise.gyro_random_walk)}  # [ rad / s^2 / sqrt(Hz) ] (gyro bias diffusion)",
        f"accelerometer_noise_density: {_sci(noise.acc_noise_density)}  # [ m / s^2 / sqrt(Hz) ] (accel white noise)",
        f"accelerometer_random_walk: {_sci(noise.acc_random_walk)}  # [ m / s^3 / sqrt(Hz) ] (accel bias diffusion)",
    ]) + "\n"


def depth_sensor_yaml(fps: float, width: int, height: int, intrinsics: tuple[float, float, float, float]) -> str:
    """``depth0/sensor.yaml``: a depth camera registered to cam0 (its ``T_BS``, intrinsics and
    stamps) with the PNGs' scale."""
    return "\n".join([
        "# General sensor definitions.",
        "sensor_type: depth",
        "comment: semslam synth depth0 (Kinect-like depth registered to cam0; 0 = no depth)",
        "",
        *_t_bs_lines(T_BS_CAM0),
        "",
        "# Depth camera specific definitions.",
        *_pinhole_lines(fps, width, height, intrinsics),
        f"depth_scale: {DEPTH_SCALE!r} # PNG units per metre (TUM's)",
    ]) + "\n"


def _sci(v: float) -> str:
    """Scientific notation with every digit the value has (``1.6968e-04``, ``2.0e-03``), as
    EuRoC writes noise densities; YAML 1.1 readers take it as a float."""
    return np.format_float_scientific(v, unique=True, min_digits=1, exp_digits=2)


def _real(v: float) -> str:
    """12 significant digits, always with a decimal point (``1.0``, not ``1``), as EuRoC's files."""
    return repr(float(f"{v:.12g}"))


def write_groundtruth(path: Path, stamps: NDArray[np.int64], cam0_poses: NDArray[np.float64],
                      poses_at: Callable[[NDArray[np.float64]], NDArray[np.float64]],
                      times: NDArray[np.float64], imu: SimulatedImu | None = None) -> None:
    """``state_groundtruth_estimate0/data.csv``: the body's exact poses, its velocity in the
    world frame (central differences of ``poses_at``, the left camera's T_WC at any time in
    seconds from the first frame) and the IMU's true biases at each frame (zero without an
    IMU, or with an exact one)."""
    rows = pose_to_tum(body_poses(cam0_poses))  # tx ty tz qx qy qz qw
    h = VELOCITY_STEP_S
    ahead, behind = body_poses(poses_at(times + h)), body_poses(poses_at(times - h))
    vel = (ahead[:, :3, 3] - behind[:, :3, 3]) / (2 * h)
    b_g, b_a = imu.biases_at(times) if imu is not None else (np.zeros((len(times), 3)), np.zeros((len(times), 3)))
    lines = [GT_HEADER]
    for s, r, v, bg, ba in zip(stamps, rows, vel, b_g, b_a):
        vals = [*r[:3], r[6], *r[3:6], *v]
        biases = ",".join(f"{x:.12f}" for x in (*bg, *ba)) if imu is not None and imu.noisy else "0,0,0,0,0,0"
        lines.append(f"{s}," + ",".join(f"{x:.12f}" for x in vals) + "," + biases)
    path.write_text("\n".join(lines) + "\n")


def imu_ns(first_ns: int, t_rel: NDArray[np.float64]) -> NDArray[np.int64]:
    """IMU stamps on the frames' clock: ``first_ns`` (the first frame's) plus the sample times
    in seconds from the first frame, rounded to the nanosecond (exact at 200 Hz)."""
    return int(first_ns) + np.round(np.asarray(t_rel) * 1e9).astype(np.int64)


def write_imu(out: Path, first_ns: int, imu: SimulatedImu) -> None:
    """``imu0/data.csv`` (EuRoC's header, integer-ns stamps, gyroscope then accelerometer in
    full float precision) and ``imu0/sensor.yaml``."""
    d = out / MAV / IMU_DIR
    ns = imu_ns(first_ns, imu.t_rel).tolist()
    vals = np.concatenate([imu.samples.gyro, imu.samples.acc], axis=1).tolist()
    body = "".join(f"{s}," + ",".join(repr(v) for v in row) + "\n" for s, row in zip(ns, vals))
    (d / "data.csv").write_text(IMU_HEADER + "\n" + body)
    (d / "sensor.yaml").write_text(imu_sensor_yaml(imu.calibration.noise))


def write_layout(out: Path, stamps: NDArray[np.int64], cam0_poses: NDArray[np.float64],
                 poses_at: Callable[[NDArray[np.float64]], NDArray[np.float64]], times: NDArray[np.float64],
                 intrinsics: tuple[float, float, float, float], width: int, height: int, fps: float,
                 baseline: float, imu: SimulatedImu | None = None, depth: bool = False) -> None:
    """Everything but the images: each camera's ``data.csv`` and ``sensor.yaml`` (cam1 only
    with a baseline), the body's ground truth and, when given, the IMU's recording and the
    depth camera's lists."""
    for cam in range(2 if baseline > 0 else 1):
        d = cam_dir(out, cam)
        write_data_csv(d / "data.csv", stamps)
        (d / "sensor.yaml").write_text(sensor_yaml(cam, cam_t_bs(cam, baseline), fps, width, height, intrinsics))
    write_groundtruth(out / MAV / GT_DIR / "data.csv", stamps, cam0_poses, poses_at, times, imu)
    if imu is not None:
        write_imu(out, int(stamps[0]), imu)
    if depth:
        d = out / MAV / DEPTH_DIR
        write_data_csv(d / "data.csv", stamps)
        (d / "sensor.yaml").write_text(depth_sensor_yaml(fps, width, height, intrinsics))
