"""Writing a synthetic stereo render in the KITTI odometry layout: ``image_0/``, ``image_1/``
(``000000.png`` ...), ``calib.txt``, ``times.txt`` and the ground truth ``poses.txt``, as
KITTI's readers (``open_kitti_stereo``, ORB-SLAM3's ``stereo_kitti``, evo's ``kitti`` format)
expect.

The sequence folder is the render's folder itself, so ORB-SLAM3 takes it as its
``path_to_sequence`` and ``open_stereo_sequence(OUT)`` opens it; the ground truth lies in it
as ``poses.txt`` (the reader's in-folder place for it) rather than in KITTI's
``dataset/poses/XX.txt`` beside ``dataset/sequences/XX``.

As in KITTI, images are grey 8-bit PNGs (the renders' RGB through OpenCV's RGB-to-grey),
``times.txt`` counts seconds from the first frame, and the poses are cam0's relative to its
first pose, ``inv(T_WC0) @ T_WCi`` (the first line is the identity); ``sequence.json`` keeps
``T_WC0`` (``kitti_T_W_C0``) to bring them back to the scene's world frame (``scene.json``).
``calib.txt`` holds the rectified projections P0 (left) and P1 (right, ``P1[0, 3] =
-fx * B``); P2 and P3 repeat them (there is no colour pair) and ``Tr`` is the identity (no
LiDAR), so that tools reading all five lines (pykitti) find them.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.errors import DataError
from semslam.geometry.se3 import invert
from semslam.synth import writer

#: The left (cam0) and right (cam1) grey cameras' folders.
IMAGE_DIRS = ("image_0", "image_1")
CALIB_FILE = "calib.txt"
TIMES_FILE = "times.txt"
POSES_FILE = "poses.txt"


def frame_name(index: int) -> str:
    """KITTI's image name: the frame index in six digits."""
    return f"{index:06d}.png"


def prepare(out: Path) -> None:
    """Create ``out/image_0`` and ``out/image_1``; remove the PNGs of an earlier rendering there
    (a shorter render must not leave frames that ``times.txt`` does not count)."""
    try:
        for sub in IMAGE_DIRS:
            d = out / sub
            d.mkdir(parents=True, exist_ok=True)
            for old in d.glob("*.png"):
                old.unlink()
    except OSError as exc:
        raise DataError(out, f"cannot create the output folder: {exc.strerror or exc}") from exc


def grey(rgb: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """The grey image KITTI's grey cameras would give of an RGB render."""
    return cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)


def write_frame(out: Path, cam: int, index: int, rgb: NDArray[np.uint8]) -> None:
    """Camera ``cam`` (0 left, 1 right) of frame ``index`` as a grey PNG."""
    writer.write_png(out / IMAGE_DIRS[cam] / frame_name(index), grey(rgb))


def _row(values: NDArray[np.float64]) -> str:
    """KITTI's number format: 12-digit mantissa, exponent (``7.188560000000e+02``)."""
    return " ".join(f"{v:.12e}" for v in np.ravel(values))


def projections(intrinsics: tuple[float, float, float, float], baseline: float) -> tuple[NDArray[np.float64], ...]:
    """P0 and P1 (3x4) of the rectified pair: the right camera ``baseline`` along the left's x."""
    fx, fy, cx, cy = intrinsics
    p0 = np.array([[fx, 0.0, cx, 0.0], [0.0, fy, cy, 0.0], [0.0, 0.0, 1.0, 0.0]])
    p1 = p0.copy()
    p1[0, 3] = -fx * baseline
    return p0, p1


def calib_txt(intrinsics: tuple[float, float, float, float], baseline: float) -> str:
    """``calib.txt``: ``P0:`` .. ``P3:`` and ``Tr:``, 12 numbers each (row-major 3x4)."""
    p0, p1 = projections(intrinsics, baseline)
    rows = {"P0": p0, "P1": p1, "P2": p0, "P3": p1, "Tr": np.eye(4)[:3]}
    return "".join(f"{k}: {_row(m)}\n" for k, m in rows.items())


def relative_poses(cam0_poses: NDArray[np.float64]) -> NDArray[np.float64]:
    """KITTI's ground truth: each left-camera pose in the first one's frame, ``inv(T_WC0) @ T_WCi``."""
    return invert(cam0_poses[0]) @ cam0_poses


def write_layout(out: Path, times: NDArray[np.float64], cam0_poses: NDArray[np.float64],
                 intrinsics: tuple[float, float, float, float], baseline: float) -> None:
    """Everything but the images: ``calib.txt``, ``times.txt`` (seconds from the first frame)
    and ``poses.txt`` (3x4 row-major, relative to the first pose)."""
    (out / CALIB_FILE).write_text(calib_txt(intrinsics, baseline))
    (out / TIMES_FILE).write_text("".join(f"{t:.12e}\n" for t in np.asarray(times) - float(times[0])))
    (out / POSES_FILE).write_text("".join(_row(p[:3]) + "\n" for p in relative_poses(cam0_poses)))
