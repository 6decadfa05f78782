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
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from semslam.errors import DataError
from semslam.geometry.se3 import invert, pose_to_tum
from semslam.synth import stereo, writer

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


def prepare(out: Path, cams: int) -> None:
    """Create ``out/mav0/camX/data`` for ``cams`` cameras and the ground-truth folder; remove
    the PNGs of an earlier rendering there (and a right camera's lists when there is none
    now, which would announce one)."""
    try:
        for cam in range(2):
            data = cam_dir(out, cam) / "data"
            if cam < cams:
                data.mkdir(parents=True, exist_ok=True)
            for old in data.glob("*.png"):
                old.unlink()
            if cam >= cams:
                for name in ("data.csv", "sensor.yaml"):
                    (cam_dir(out, cam) / name).unlink(missing_ok=True)
        (out / MAV / GT_DIR).mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DataError(out, f"cannot create the output folder: {exc.strerror or exc}") from exc


def write_frame(out: Path, cam: int, ns: int, rgb: NDArray[np.uint8]) -> None:
    writer.write_png(cam_dir(out, cam) / "data" / f"{ns}.png", rgb)


def write_data_csv(path: Path, stamps: NDArray[np.int64]) -> None:
    """``camX/data.csv``: ``#timestamp [ns],filename`` then one ``ns,ns.png`` line per frame."""
    path.write_text("#timestamp [ns],filename\n" + "".join(f"{s},{s}.png\n" for s in stamps))


def sensor_yaml(cam: int, t_bs: NDArray[np.float64], fps: float, width: int, height: int,
                intrinsics: tuple[float, float, float, float]) -> str:
    """A camera's ``sensor.yaml`` in EuRoC's words (``T_BS`` row-major in ``data``)."""
    rows = [", ".join(_real(v) for v in r) for r in t_bs]
    data = (",\n" + " " * 9).join(rows)
    side = "left" if cam == 0 else "right"
    return "\n".join([
        "# General sensor definitions.",
        "sensor_type: camera",
        f"comment: semslam synth cam{cam} ({side}; rectified pinhole, no distortion)",
        "",
        "# Sensor extrinsics wrt. the body-frame.",
        "T_BS:",
        "  cols: 4",
        "  rows: 4",
        f"  data: [{data}]",
        "",
        "# Camera specific definitions.",
        f"rate_hz: {fps:g}",
        f"resolution: [{width}, {height}]",
        "camera_model: pinhole",
        "intrinsics: [{}] #fu, fv, cu, cv".format(", ".join(_real(v) for v in intrinsics)),
        "distortion_model: radial-tangential",
        "distortion_coefficients: [0.0, 0.0, 0.0, 0.0]",
    ]) + "\n"


def _real(v: float) -> str:
    """12 significant digits, always with a decimal point (``1.0``, not ``1``), as EuRoC's files."""
    return repr(float(f"{v:.12g}"))


def write_groundtruth(path: Path, stamps: NDArray[np.int64], cam0_poses: NDArray[np.float64],
                      poses_at: Callable[[NDArray[np.float64]], NDArray[np.float64]],
                      times: NDArray[np.float64]) -> None:
    """``state_groundtruth_estimate0/data.csv``: the body's exact poses, its velocity in the
    world frame (central differences of ``poses_at``, the left camera's T_WC at any time in
    seconds from the first frame) and zero IMU biases (there is no IMU)."""
    rows = pose_to_tum(body_poses(cam0_poses))  # tx ty tz qx qy qz qw
    h = VELOCITY_STEP_S
    ahead, behind = body_poses(poses_at(times + h)), body_poses(poses_at(times - h))
    vel = (ahead[:, :3, 3] - behind[:, :3, 3]) / (2 * h)
    lines = [GT_HEADER]
    for s, r, v in zip(stamps, rows, vel):
        vals = [*r[:3], r[6], *r[3:6], *v]
        lines.append(f"{s}," + ",".join(f"{x:.12f}" for x in vals) + ",0,0,0,0,0,0")
    path.write_text("\n".join(lines) + "\n")


def write_layout(out: Path, stamps: NDArray[np.int64], cam0_poses: NDArray[np.float64],
                 poses_at: Callable[[NDArray[np.float64]], NDArray[np.float64]], times: NDArray[np.float64],
                 intrinsics: tuple[float, float, float, float], width: int, height: int, fps: float,
                 baseline: float) -> None:
    """Everything but the images: each camera's ``data.csv`` and ``sensor.yaml`` (cam1 only
    with a baseline) and the body's ground truth."""
    for cam in range(2 if baseline > 0 else 1):
        d = cam_dir(out, cam)
        write_data_csv(d / "data.csv", stamps)
        (d / "sensor.yaml").write_text(sensor_yaml(cam, cam_t_bs(cam, baseline), fps, width, height, intrinsics))
    write_groundtruth(out / MAV / GT_DIR / "data.csv", stamps, cam0_poses, poses_at, times)
