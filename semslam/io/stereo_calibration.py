"""Stereo calibration: the two cameras, the right one's pose in the left's frame, and the
rectification that puts a point on the same row in both images.

Sources: EuRoC ASL ``sensor.yaml`` files (one per camera, each with ``T_BS``), KITTI
odometry ``calib.txt`` (``P0``/``P1``, already rectified), an ORB-SLAM3 v1.0 settings YAML
(``Camera.type: "PinHole"`` with ``Stereo.T_c1_c2``, or ``"Rectified"`` with ``Stereo.b``),
or explicit values (``--camera fx,fy,cx,cy`` + ``--baseline``).

An unrectified pair is rectified as ORB-SLAM3's stereo examples do: ``cv2.stereoRectify``
with ``CALIB_ZERO_DISPARITY`` and ``alpha=0`` (only valid pixels, same principal point in
both images) and ``cv2.initUndistortRectifyMap`` once; each image is then one ``cv2.remap``.
Bad input is one :class:`~semslam.errors.DataError` naming the file and the key.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import yaml
from numpy.typing import NDArray

from semslam.errors import ConfigError, DataError
from semslam.geometry.camera import PinholeCamera
from semslam.io.calibration import parse_camera_option
from semslam.io.text import read_text_lines

Array = NDArray[np.float64]


@dataclass(eq=False)
class StereoCalibration:
    """A calibrated stereo pair and its rectification.

    ``left``/``right`` are the raw cameras (intrinsics, distortion, image size);
    ``T_lr`` is the right camera's pose in the left's frame (``X_left = R X_right + t``,
    ORB-SLAM3's ``Stereo.T_c1_c2``). ``rectified_input``: the images are already
    rectified (KITTI, ORB-SLAM3 "Rectified"), so no remap is made. Derived on creation:
    ``camera`` (the rectified left camera, no distortion), ``baseline`` (metres), ``bf``
    (``fx * baseline``, ORB-SLAM's ``mbf``) and the remap tables.
    """

    left: PinholeCamera
    right: PinholeCamera
    T_lr: Array  # noqa: N815 - the usual name of the transform
    source: str = ""
    rectified_input: bool = False
    camera: PinholeCamera = field(init=False)
    baseline: float = field(init=False)
    R_left: Array = field(init=False, repr=False)  # noqa: N815 - rectifying rotations (stereoRectify R1, R2)
    R_right: Array = field(init=False, repr=False)  # noqa: N815
    P_left: Array = field(init=False, repr=False)  # noqa: N815 - rectified projections (P1, P2)
    P_right: Array = field(init=False, repr=False)  # noqa: N815
    maps: tuple[Array, Array, Array, Array] | None = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self.T_lr = np.asarray(self.T_lr, dtype=np.float64).reshape(4, 4)
        if self.rectified_input:
            self._rectified()
        else:
            self._rectify()
        if not (math.isfinite(self.baseline) and self.baseline > 0):
            raise DataError(self.source or "stereo calibration",
                            f"baseline {self.baseline:g} m: the right camera must lie to the right of the left "
                            "one (x > 0 in the left camera's frame)")

    @property
    def bf(self) -> float:
        """Baseline times the rectified focal length (pixels x metres): depth = bf / disparity."""
        return self.camera.fx * self.baseline

    @property
    def t(self) -> Array:
        return self.T_lr[:3, 3]

    def _rectified(self) -> None:
        """Already rectified: the left camera as given, no remap; the baseline is the x offset."""
        self.camera = self.left
        self.baseline = float(self.t[0])
        eye = np.eye(3)
        self.R_left, self.R_right = eye, eye.copy()
        k = self.left.K
        self.P_left = np.hstack([k, np.zeros((3, 1))])
        self.P_right = np.hstack([k, np.array([[-k[0, 0] * self.baseline], [0.0], [0.0]])])
        self.maps = None

    def _rectify(self) -> None:
        size = (self.left.width, self.left.height)
        if size[0] <= 0 or size[1] <= 0:
            raise DataError(self.source or "stereo calibration", "image size unknown; rectification needs it")
        if (self.right.width, self.right.height) != size:
            raise DataError(self.source or "stereo calibration",
                            f"left images are {size[0]}x{size[1]} but right ones "
                            f"{self.right.width}x{self.right.height}")
        # OpenCV wants the transform taking left-camera points to right-camera points.
        T_rl = np.linalg.inv(self.T_lr)  # noqa: N806
        r1, r2, p1, p2, _q, _roi1, _roi2 = cv2.stereoRectify(
            self.left.K, self.left.dist_coeffs, self.right.K, self.right.dist_coeffs, size,
            T_rl[:3, :3], T_rl[:3, 3], flags=cv2.CALIB_ZERO_DISPARITY, alpha=0)
        self.R_left, self.R_right, self.P_left, self.P_right = r1, r2, p1, p2
        self.baseline = float(-p2[0, 3] / p2[0, 0])
        self.camera = PinholeCamera(float(p1[0, 0]), float(p1[1, 1]), float(p1[0, 2]), float(p1[1, 2]),
                                    source=f"{self.source} (rectified)", width=size[0], height=size[1])
        # Float maps: exact to sample (tests, point lookups), remapped with bilinear interpolation.
        m1 = cv2.initUndistortRectifyMap(self.left.K, self.left.dist_coeffs, r1, p1, size, cv2.CV_32FC1)
        m2 = cv2.initUndistortRectifyMap(self.right.K, self.right.dist_coeffs, r2, p2, size, cv2.CV_32FC1)
        self.maps = (m1[0], m1[1], m2[0], m2[1])

    def with_image_size(self, width: int, height: int) -> StereoCalibration:
        """An already rectified pair with the image size of the first image (from the files
        that do not state it: KITTI calib.txt, --camera); unchanged if the size is known."""
        if not self.rectified_input or self.camera.width > 0:
            return self
        return StereoCalibration(self.left.with_image_size(width, height), self.right.with_image_size(width, height),
                                 self.T_lr, self.source, True)

    def rectify(self, left: NDArray[np.uint8], right: NDArray[np.uint8]) -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
        """Both images rectified with the stored tables (unchanged for a rectified input)."""
        if self.maps is None:
            return left, right
        lx, ly, rx, ry = self.maps
        return (cv2.remap(left, lx, ly, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT),
                cv2.remap(right, rx, ry, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT))

    def rectify_points(self, uv: NDArray[np.floating], side: str = "left") -> Array:
        """Raw (distorted) pixels of one image at their rectified positions."""
        cam, r, p = (self.left, self.R_left, self.P_left) if side == "left" else (self.right, self.R_right, self.P_right)
        pts = np.asarray(uv, dtype=np.float64).reshape(-1, 1, 2)
        return cv2.undistortPoints(pts, cam.K, cam.dist_coeffs, R=r, P=p).reshape(-1, 2)


# ---------------------------------------------------------------------------- explicit values


def stereo_from_values(camera: str | PinholeCamera, baseline: float, source: str = "--camera/--baseline") -> StereoCalibration:
    """A rectified pair from ``--camera fx,fy,cx,cy`` and ``--baseline`` (metres)."""
    cam = parse_camera_option(camera) if isinstance(camera, str) else camera
    if not (math.isfinite(baseline) and baseline > 0):
        raise ConfigError(f"--baseline: expected the distance between the cameras in metres, a number > 0, got {baseline:g}")
    if cam.is_distorted:
        raise ConfigError("--camera: a stereo pair given by values must be rectified (no distortion coefficients)")
    return StereoCalibration(cam, cam, _translation_x(baseline), source, rectified_input=True)


def _translation_x(baseline: float) -> Array:
    pose = np.eye(4)
    pose[0, 3] = baseline
    return pose


# ---------------------------------------------------------------------------- KITTI calib.txt


def _kitti_matrices(path: Path) -> dict[str, Array]:
    out: dict[str, Array] = {}
    for lineno, raw in enumerate(read_text_lines(path), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        key, sep, rest = line.partition(":")
        if not sep:
            raise DataError(path, f"line {lineno}: expected 'P0: 12 numbers', got {line[:60]!r}")
        try:
            values = [float(v) for v in rest.split()]
        except ValueError:
            raise DataError(path, f"line {lineno}: {key.strip()} is not a list of numbers") from None
        out[key.strip()] = np.asarray(values)
    return out


def read_kitti_calib(path: str | Path) -> StereoCalibration:
    """KITTI odometry ``calib.txt``: ``P0`` and ``P1`` are the rectified projection matrices
    of the left and right grey cameras; ``P1[0, 3] = -fx * baseline``."""
    path = Path(path)
    mats = _kitti_matrices(path)
    projections = []
    for key in ("P0", "P1"):
        if key not in mats:
            raise DataError(path, f"no {key} line (KITTI calib.txt needs P0 and P1, the left and right cameras)")
        if mats[key].size != 12 or not np.all(np.isfinite(mats[key])):
            raise DataError(path, f"{key}: expected 12 finite numbers (a 3x4 matrix), got {mats[key].size}")
        projections.append(mats[key].reshape(3, 4))
    p0, p1 = projections
    if p0[0, 0] <= 0 or p0[1, 1] <= 0:
        raise DataError(path, f"P0: focal lengths must be positive, got fx={p0[0, 0]:g} fy={p0[1, 1]:g}")
    cam = PinholeCamera(p0[0, 0], p0[1, 1], p0[0, 2], p0[1, 2], source=str(path))
    # P0 may carry a translation of its own (not KITTI's grey pair, but other rigs): the
    # baseline is the difference of the two cameras' x offsets.
    baseline = (p0[0, 3] - p1[0, 3]) / p1[0, 0]
    if not baseline > 0:
        raise DataError(path, f"P1[0,3] = {p1[0, 3]:g}: expected a negative value (-fx * baseline)")
    return StereoCalibration(cam, cam, _translation_x(baseline), str(path), rectified_input=True)


# ---------------------------------------------------------------------------- EuRoC sensor.yaml


def load_yaml(path: Path) -> dict:
    """A YAML mapping (EuRoC, Kalibr; OpenCV's ``%YAML:1.0`` header dropped); DataError naming the file."""
    lines = read_text_lines(path)
    if lines and lines[0].startswith("%YAML:"):  # OpenCV's header, which PyYAML refuses
        lines = lines[1:]
    try:
        doc = yaml.safe_load("\n".join(lines))
    except yaml.YAMLError as exc:
        raise DataError(path, f"not valid YAML ({str(exc).splitlines()[0]})") from None
    if not isinstance(doc, dict):
        raise DataError(path, "not a YAML mapping")
    return doc


def numbers(path: Path, key: str, value: object, count: int) -> list[float]:
    """``count`` finite numbers from a list (or EuRoC's ``{rows, cols, data}``); DataError naming the key."""
    if isinstance(value, dict):
        value = value.get("data")
    if not isinstance(value, list) or len(value) != count:
        raise DataError(path, f"{key}: expected {count} numbers, got {value!r}"[:200])
    try:
        out = [float(v) for v in value]
    except (TypeError, ValueError):
        raise DataError(path, f"{key}: expected {count} numbers, got {value!r}"[:200]) from None
    if not all(math.isfinite(v) for v in out):
        raise DataError(path, f"{key}: not finite")
    return out


def read_euroc_sensor(path: str | Path) -> tuple[PinholeCamera, Array]:
    """One EuRoC camera's ``sensor.yaml``: the camera (``intrinsics: [fu, fv, cu, cv]``,
    radial-tangential ``distortion_coefficients: [k1, k2, p1, p2]``, ``resolution: [w, h]``)
    and ``T_BS``, the camera's pose in the body (IMU) frame."""
    path = Path(path)
    doc = load_yaml(path)
    for key in ("intrinsics", "resolution", "T_BS"):
        if key not in doc:
            raise DataError(path, f"no {key} (an EuRoC camera sensor.yaml has intrinsics, resolution, "
                                  "distortion_coefficients and T_BS)")
    model = doc.get("camera_model", "pinhole")
    if model != "pinhole":
        raise DataError(path, f"camera_model {model!r}: only 'pinhole' is supported")
    dist_model = doc.get("distortion_model", "radial-tangential")
    if dist_model not in ("radial-tangential", "radtan", "none"):
        raise DataError(path, f"distortion_model {dist_model!r}: only 'radial-tangential' is supported")
    fu, fv, cu, cv = numbers(path, "intrinsics", doc["intrinsics"], 4)
    w, h = numbers(path, "resolution", doc["resolution"], 2)
    raw_dist = doc.get("distortion_coefficients", [0.0, 0.0, 0.0, 0.0])
    n_dist = len(raw_dist) if isinstance(raw_dist, list) and len(raw_dist) in (4, 5) else 4
    dist = numbers(path, "distortion_coefficients", raw_dist, n_dist) + [0.0] * (5 - n_dist)
    t_bs = np.asarray(numbers(path, "T_BS", doc["T_BS"], 16)).reshape(4, 4)
    check_pose(path, "T_BS", t_bs)
    if fu <= 0 or fv <= 0:
        raise DataError(path, f"intrinsics: focal lengths must be positive, got fu={fu:g} fv={fv:g}")
    cam = PinholeCamera(fu, fv, cu, cv, tuple(dist), source=str(path), width=int(w), height=int(h))  # type: ignore[arg-type]
    return cam, t_bs


def check_pose(path: Path, key: str, pose: Array) -> None:
    """A 4x4 rigid transform, else DataError naming the file and the key."""
    rot = pose[:3, :3]
    if (np.abs(rot.T @ rot - np.eye(3)).max() > 1e-3 or np.linalg.det(rot) < 0
            or not np.allclose(pose[3], [0, 0, 0, 1])):
        raise DataError(path, f"{key}: not a rigid transform (rotation block not orthonormal or last row not 0 0 0 1)")


def read_euroc_calibration(mav0: str | Path) -> tuple[StereoCalibration, Array]:
    """The pair of an EuRoC ``mav0`` folder and cam0's ``T_BS`` (for the ground truth):
    the right camera's pose in the left's frame is ``inv(T_BS0) @ T_BS1``."""
    mav0 = Path(mav0)
    left, t_bs0 = read_euroc_sensor(mav0 / "cam0" / "sensor.yaml")
    right, t_bs1 = read_euroc_sensor(mav0 / "cam1" / "sensor.yaml")
    t_lr = np.linalg.inv(t_bs0) @ t_bs1
    # EuRoC's format cannot say "already rectified"; a pair that is (same intrinsics, no
    # distortion, no rotation, the right camera on the left's x axis) is not resampled.
    return StereoCalibration(left, right, t_lr, str(mav0 / "cam0" / "sensor.yaml"),
                             rectified_input=_is_rectified(left, right, t_lr)), t_bs0


def _is_rectified(left: PinholeCamera, right: PinholeCamera, t_lr: Array, tol: float = 1e-6) -> bool:
    """Whether a pair's images are rectified as they are (nothing to remap)."""
    same = np.allclose(left.K, right.K, rtol=0.0, atol=tol) and (left.width, left.height) == (right.width, right.height)
    return bool(same and not left.is_distorted and not right.is_distorted
                and np.allclose(t_lr[:3, :3], np.eye(3), atol=tol) and np.allclose(t_lr[1:3, 3], 0.0, atol=tol))


# ---------------------------------------------------------------------------- ORB-SLAM3 settings


class SettingsFile:
    """Reads keys of an OpenCV FileStorage, naming the file and key in every error."""

    def __init__(self, path: Path) -> None:
        self.path = path
        if not path.is_file():
            raise DataError(path, "file not found")
        try:
            self.fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
        except cv2.error as exc:
            raise DataError(path, f"not an OpenCV YAML file ({str(exc).strip().splitlines()[-1]})") from None
        if not self.fs.isOpened():
            raise DataError(path, "cannot be opened as an OpenCV YAML file")

    def node(self, key: str, why: str) -> cv2.FileNode:
        node = self.fs.getNode(key)
        if node.empty() or node.isNone():
            raise DataError(self.path, f"{key} missing ({why})")
        return node

    def real(self, key: str, why: str, default: float | None = None) -> float:
        if default is not None and self.fs.getNode(key).empty():
            return default
        node = self.node(key, why)
        if not node.isReal() and not node.isInt():
            raise DataError(self.path, f"{key}: expected a number")
        value = float(node.real())
        if not math.isfinite(value):
            raise DataError(self.path, f"{key}: not finite")
        return value

    def text(self, key: str, why: str) -> str:
        node = self.node(key, why)
        if not node.isString():
            raise DataError(self.path, f"{key}: expected a string")
        return node.string()

    def matrix(self, key: str, why: str, shape: tuple[int, int]) -> Array:
        mat = self.node(key, why).mat()
        if mat is None or mat.shape != shape:
            raise DataError(self.path, f"{key}: expected a {shape[0]}x{shape[1]} !!opencv-matrix")
        return np.asarray(mat, dtype=np.float64)

    def camera(self, prefix: str, why: str, size: tuple[int, int], distorted: bool) -> PinholeCamera:
        k = [self.real(f"{prefix}.{n}", why) for n in ("fx", "fy", "cx", "cy")]
        dist = [self.real(f"{prefix}.{n}", why, 0.0) for n in ("k1", "k2", "p1", "p2", "k3")] if distorted else [0.0] * 5
        if k[0] <= 0 or k[1] <= 0:
            raise DataError(self.path, f"{prefix}.fx/fy: focal lengths must be positive")
        return PinholeCamera(*k, tuple(dist), source=str(self.path), width=size[0], height=size[1])  # type: ignore[arg-type]


def read_orbslam3_settings(path: str | Path) -> StereoCalibration:
    """An ORB-SLAM3 v1.0 settings YAML (``%YAML:1.0``, read with ``cv2.FileStorage``):
    ``Camera.type: "PinHole"`` with ``Camera1.*``, ``Camera2.*``, ``Camera.width``/``height``
    and ``Stereo.T_c1_c2`` (the right camera's pose in the left's frame), or
    ``"Rectified"`` with ``Camera1.*`` and ``Stereo.b`` (metres)."""
    s = SettingsFile(Path(path))
    kind = s.text("Camera.type", 'ORB-SLAM3 v1.0 settings say "PinHole" or "Rectified"')
    if kind == "Rectified":
        cam = s.camera("Camera1", "a rectified stereo camera needs Camera1.fx, fy, cx, cy", (0, 0), distorted=False)
        if not s.fs.getNode("Camera.width").empty():
            cam = cam.with_image_size(int(s.real("Camera.width", "")), int(s.real("Camera.height", "image size")))
        baseline = s.real("Stereo.b", 'a "Rectified" stereo camera needs the baseline in metres')
        if not baseline > 0:
            raise DataError(s.path, f"Stereo.b: expected the baseline in metres, > 0, got {baseline:g}")
        return StereoCalibration(cam, cam, _translation_x(baseline), str(s.path), rectified_input=True)
    if kind != "PinHole":
        raise DataError(s.path, f'Camera.type {kind!r}: stereo reads "PinHole" or "Rectified" (not fisheye "KannalaBrandt8")')
    why = 'a "PinHole" stereo pair needs the image size to rectify'
    size = (int(s.real("Camera.width", why)), int(s.real("Camera.height", why)))
    left = s.camera("Camera1", "the left camera's intrinsics", size, distorted=True)
    right = s.camera("Camera2", "the right camera's intrinsics", size, distorted=True)
    t_lr = s.matrix("Stereo.T_c1_c2", "the right camera's pose in the left's frame, 4x4", (4, 4))
    check_pose(s.path, "Stereo.T_c1_c2", t_lr)
    return StereoCalibration(left, right, t_lr, str(s.path))
