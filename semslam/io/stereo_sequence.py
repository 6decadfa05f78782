"""Stereo sequence readers: EuRoC ASL, KITTI odometry and a TUM-like folder with a right list.

Each yields :class:`~semslam.core.types.Frame` with ``right`` set, both images rectified
with the sequence's :class:`~semslam.io.stereo_calibration.StereoCalibration` (one remap
per image with the tables made once); ``camera`` is the rectified left camera. They follow
:class:`~semslam.io.sequence.Sequence` (frames by index, skipping a few unreadable ones).
``io.sequence.open_sequence`` opens these layouts as stereo (kind ``stereo``, or ``auto``
for EuRoC, KITTI and a TUM-like folder without depth); ``open_stereo_sequence`` is the
reader itself.

Layouts:

- EuRoC ASL: ``mav0/cam{0,1}/data.csv`` (``#timestamp [ns],filename``), ``data/`` images,
  ``sensor.yaml``; ground truth ``mav0/state_groundtruth_estimate0/data.csv`` is the body's
  pose, so :meth:`StereoSequence.groundtruth` returns ``T_WB @ T_BS`` (cam0), as evo's
  ``transform(T_BS, right_mul=True)`` does. ``mav0/imu0`` (readings and ``sensor.yaml``)
  becomes the sequence's ``imu`` (``io.imu``): each frame then carries its readings.
- KITTI odometry: ``image_0/``, ``image_1/`` (same file names), ``calib.txt``, ``times.txt``;
  ground truth ``poses/XX.txt`` (cam0 poses, 3x4) beside ``sequences/`` or given.
- TUM-like: ``rgb.txt`` + ``rgb/`` and ``rgb_right.txt`` + ``rgb_right/``, pairs by
  timestamp; calibration from an ORB-SLAM3 settings YAML in the folder (``camera.yaml`` or
  ``settings.yaml``) or explicit values.
"""

from __future__ import annotations

import logging
import tempfile
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from semslam.core.trajectory import Trajectory
from semslam.core.types import Frame
from semslam.errors import ConfigError, DataError
from semslam.geometry.camera import PinholeCamera
from semslam.io.association import match_timestamps
from semslam.io.images import FrameReadError, read_rgb
from semslam.io.imu import attach_imu
from semslam.io.sequence import (IMAGE_SUFFIXES, ListEntry, Sequence, _natural_key, euroc_root, listed_path,
                                 read_file_list, stereo_layout)
from semslam.io.stereo_calibration import (StereoCalibration, read_euroc_calibration, read_euroc_sensor,
                                           read_kitti_calib,
                                           read_orbslam3_settings, stereo_from_values)
from semslam.io.text import read_text_lines
from semslam.io.trajectory import read_euroc_csv, read_kitti, read_tum, write_tum

log = logging.getLogger(__name__)

#: Settings files a TUM-like stereo folder may hold, in order.
SETTINGS_NAMES = ("camera.yaml", "settings.yaml")


def euroc_camera_trajectory(body: Trajectory, t_bs: NDArray[np.float64]) -> Trajectory:
    """EuRoC ground truth of the body (IMU) turned into the camera's: ``T_WC = T_WB @ T_BS``."""
    return Trajectory(body.timestamps.copy(), body.poses @ np.asarray(t_bs, dtype=np.float64), body.name)


class LayoutSequence(Sequence):
    """A sequence read from a dataset layout whose ground truth may need converting before
    evaluation reads it (EuRoC: body poses; KITTI: 3x4 poses with times.txt), and whose
    listed images are checked for existence once (the stereo readers, EuRoC mono / RGB-D)."""

    def _set_frames(self, root: Path, timestamps: NDArray[np.float64]) -> None:
        """The folder, its name (EuRoC's ``mav0`` is named after its parent) and the frames' times."""
        self.root = root
        resolved = root.resolve()
        self.name = resolved.parent.name if resolved.name == "mav0" else resolved.name
        self._timestamps = np.asarray(timestamps, dtype=np.float64)

    def _set_groundtruth(self, groundtruth_path: Path | None, groundtruth_format: str = "tum",
                         t_bs: NDArray[np.float64] | None = None, times_path: Path | None = None) -> None:
        #: The ground truth file as the layout has it (EuRoC: the body's; KITTI: 3x4 poses).
        self.groundtruth_source = groundtruth_path
        self._gt_format = groundtruth_format
        self._times_path = times_path
        #: cam0's pose in the body frame (EuRoC), applied to the body ground truth.
        self.t_bs = t_bs
        #: What evaluation reads (``semslam run``, the report): cam0's poses as a TUM file, written
        #: to a temporary folder that lives as long as the sequence where the layout's file is not.
        self.groundtruth_path = groundtruth_path
        self._gt_dir: tempfile.TemporaryDirectory[str] | None = None
        if groundtruth_path is not None and groundtruth_format != "tum":
            camera_poses = self.groundtruth()
            assert camera_poses is not None
            self._gt_dir = tempfile.TemporaryDirectory(prefix="semslam-layout-gt-")
            self.groundtruth_path = Path(self._gt_dir.name) / "groundtruth.txt"
            write_tum(self.groundtruth_path, camera_poses)

    def groundtruth(self) -> Trajectory | None:
        """The ground truth as cam0 poses (EuRoC: body poses times ``T_BS``); None without one."""
        source = self.groundtruth_source
        if source is None:
            return None
        if self._gt_format == "euroc":
            body = read_euroc_csv(source)
            return body if self.t_bs is None else euroc_camera_trajectory(body, self.t_bs)
        if self._gt_format == "kitti":
            return read_kitti(source, self._times_path)
        return read_tum(source)

    def _check_listed_files(self, columns: list[list[Path]]) -> None:
        """Many listed images missing is a broken download (an error now, naming the first);
        a few are skipped when reached, as the RGB-D reader does. ``columns``: the images of
        each frame, one list per camera."""
        n = len(columns[0])
        missing = [p for row in zip(*columns) for p in row if not p.is_file()]
        allowed = max(3, int(self.max_skip_fraction * n))
        if missing and (len(missing) > allowed or len(missing) >= n):
            raise DataError(missing[0], f"file not found, and {len(missing) - 1} more listed images are missing")


class StereoSequence(LayoutSequence):
    """Rectified stereo pairs: left/right paths per frame, timestamps, calibration."""

    has_depth = False

    def __init__(self, root: Path, left: list[Path], right: list[Path], timestamps: NDArray[np.float64],
                 calibration: StereoCalibration, groundtruth_path: Path | None = None,
                 groundtruth_format: str = "tum", t_bs: NDArray[np.float64] | None = None,
                 times_path: Path | None = None) -> None:
        super().__init__()
        self._set_frames(root, timestamps)
        self._left, self._right = left, right
        self._check_listed_files([self._left, self._right])
        first = next((p for p in left if p.is_file()), None)
        if calibration.rectified_input and calibration.camera.width <= 0 and first is not None:
            try:
                h, w = read_rgb(first).shape[:2]
                calibration = calibration.with_image_size(w, h)
            except FrameReadError:
                pass  # reported when iteration reaches it
        self.calibration = calibration
        self.camera: PinholeCamera = calibration.camera
        self._set_groundtruth(groundtruth_path, groundtruth_format, t_bs, times_path)

    @property
    def timestamps(self) -> NDArray[np.float64]:
        return self._timestamps

    def load(self, index: int) -> Frame:
        lp, rp = self._left[index], self._right[index]
        left, right = read_rgb(lp), read_rgb(rp)
        if right.shape != left.shape:
            raise FrameReadError(rp, f"right image is {right.shape[1]}x{right.shape[0]} but the left one is "
                                     f"{left.shape[1]}x{left.shape[0]}")
        cal = self.calibration
        if cal.maps is not None and (left.shape[1], left.shape[0]) != (cal.camera.width, cal.camera.height):
            raise FrameReadError(lp, f"image is {left.shape[1]}x{left.shape[0]} but the calibration's is "
                                     f"{cal.camera.width}x{cal.camera.height}")
        left, right = cal.rectify(left, right)
        return Frame(index, float(self._timestamps[index]), left, None, lp, None, right=right, right_path=rp)


# ---------------------------------------------------------------------------- pairing


def pair_lists(left: list[ListEntry], right: list[ListEntry], left_file: Path, right_file: Path,
               max_diff: float, max_skip_fraction: float = 0.05,
               what: str = "right image") -> tuple[list[ListEntry], list[ListEntry]]:
    """Left and right entries at the same time (within ``max_diff`` s). A few left images
    without a right one (``what``: EuRoC RGB-D pairs cam0 with a depth image) are dropped with
    a warning; more is an error naming the first."""
    il, ir = match_timestamps([e.timestamp for e in left], [e.timestamp for e in right], max_diff=max_diff)
    matched = set(int(i) for i in il)
    unmatched = [e for k, e in enumerate(left) if k not in matched]
    allowed = int(max_skip_fraction * len(left))
    if unmatched and (len(unmatched) > allowed or not len(il)):
        first = unmatched[0]
        raise DataError(left_file, f"line {first.line}: image at {first.timestamp:.9f} s has no {what} in "
                                   f"{right_file} within {max_diff:g} s ({len(unmatched)} of {len(left)} unmatched)")
    if unmatched:
        log.warning("%s: %d images have no %s in %s; dropped", left_file, len(unmatched), what, right_file)
    order = np.argsort(il)
    return [left[int(i)] for i in np.asarray(il)[order]], [right[int(i)] for i in np.asarray(ir)[order]]


def read_euroc_list(path: Path) -> list[ListEntry]:
    """An EuRoC ``data.csv`` (``timestamp [ns],filename``): entries in seconds, images in
    the ``data/`` folder beside it."""
    entries: list[ListEntry] = []
    for lineno, raw in enumerate(read_text_lines(path), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        parts = [p.strip() for p in line.split(",")]
        if len(parts) < 2 or not parts[0].isdigit():
            raise DataError(path, f"line {lineno}: expected 'timestamp_ns,filename', got {line[:80]!r}")
        stamp = float(int(parts[0])) / 1e9  # as evo converts EuRoC nanoseconds
        if entries and stamp <= entries[-1].timestamp:
            raise DataError(path, f"line {lineno}: timestamp {parts[0]} is not after the previous one; "
                                  "timestamps must increase")
        entries.append(ListEntry(stamp, listed_path(path, lineno, path.parent / "data", parts[1]), lineno))
    if not entries:
        raise DataError(path, "no entries (only comments or blank lines)")
    return entries


# ---------------------------------------------------------------------------- layouts


def open_euroc_stereo(root: Path, calibration: StereoCalibration | None = None,
                      max_diff: float = 0.001) -> StereoSequence:
    """An EuRoC ASL sequence (the folder holding ``mav0/``, or ``mav0`` itself), with its
    IMU (``mav0/imu0``, ``io.imu.open_imu``) where it has one."""
    mav0 = euroc_root(root)
    if mav0 is None:
        raise DataError(root / "mav0" / "cam1", "not found (an EuRoC stereo sequence has mav0/cam0 and mav0/cam1)")
    lists = []
    for cam in ("cam0", "cam1"):
        csv = mav0 / cam / "data.csv"
        if not csv.is_file():
            raise DataError(csv, f"file not found (EuRoC stereo needs {cam}'s list of images)")
        lists.append(read_euroc_list(csv))
    left, right = pair_lists(lists[0], lists[1], mav0 / "cam0" / "data.csv", mav0 / "cam1" / "data.csv", max_diff)
    t_bs = None
    if calibration is None:
        calibration, t_bs = read_euroc_calibration(mav0)
    elif (mav0 / "cam0" / "sensor.yaml").is_file():  # T_BS still places cam0 on the body for the ground truth
        t_bs = read_euroc_sensor(mav0 / "cam0" / "sensor.yaml")[1]
    gt = mav0 / "state_groundtruth_estimate0" / "data.csv"
    seq = StereoSequence(root, [e.path for e in left], [e.path for e in right],
                         np.array([e.timestamp for e in left]), calibration,
                         gt if gt.is_file() else None, "euroc", t_bs)
    attach_imu(seq, mav0)  # imu0, where the folder has one: each frame then carries its readings
    return seq


def _kitti_groundtruth(root: Path) -> Path | None:
    """``poses/XX.txt`` of KITTI's layout (``dataset/sequences/XX`` beside ``dataset/poses``),
    or ``poses.txt`` / ``poses/XX.txt`` inside the sequence folder."""
    name = root.resolve().name
    for cand in (root.resolve().parent.parent / "poses" / f"{name}.txt", root / "poses" / f"{name}.txt",
                 root / "poses.txt"):
        if cand.is_file():
            return cand
    return None


def open_kitti_stereo(root: Path, calibration: StereoCalibration | None = None,
                      groundtruth: str | Path | None = None) -> StereoSequence:
    """A KITTI odometry sequence folder (``image_0``, ``image_1``, ``calib.txt``, ``times.txt``)."""
    folders = [root / "image_0", root / "image_1"]
    for folder in folders:
        if not folder.is_dir():
            raise DataError(folder, "folder not found (KITTI stereo needs image_0 and image_1)")
    left = sorted((p for p in folders[0].iterdir() if p.suffix.lower() in IMAGE_SUFFIXES), key=_natural_key)
    if not left:
        raise DataError(folders[0], "no images")
    right = [folders[1] / p.name for p in left]
    times = root / "times.txt"
    if not times.is_file():
        raise DataError(times, "file not found (KITTI odometry gives one time per image there)")
    rows = [(k, line.split()) for k, line in enumerate(read_text_lines(times), start=1) if line.strip()]
    try:
        stamps = np.array([float(parts[0]) for _, parts in rows])
    except ValueError:
        raise DataError(times, "not a column of numbers") from None
    if len(stamps) != len(left):
        raise DataError(times, f"{len(stamps)} times for {len(left)} images in {folders[0]}")
    bad = np.flatnonzero(np.diff(stamps) <= 0)
    if bad.size:
        raise DataError(times, f"line {rows[int(bad[0]) + 1][0]}: time is not after the previous one")
    if calibration is None:
        calibration = read_kitti_calib(root / "calib.txt")
    gt = Path(groundtruth) if groundtruth is not None else _kitti_groundtruth(root)
    if gt is not None and not gt.is_file():
        raise DataError(gt, "ground truth file not found")
    return StereoSequence(root, left, right, stamps, calibration, gt, "kitti", times_path=times)


def open_tum_stereo(root: Path, calibration: StereoCalibration | None = None,
                    max_diff: float = 0.001) -> StereoSequence:
    """A TUM-like folder: ``rgb.txt`` (left) and ``rgb_right.txt`` (right), paired by time."""
    left_txt, right_txt = root / "rgb.txt", root / "rgb_right.txt"
    for f in (left_txt, right_txt):
        if not f.is_file():
            raise DataError(f, "file not found (a TUM-like stereo folder has rgb.txt and rgb_right.txt)")
    left, right = pair_lists(read_file_list(left_txt), read_file_list(right_txt), left_txt, right_txt, max_diff)
    if calibration is None:
        settings = next((root / n for n in SETTINGS_NAMES if (root / n).is_file()), None)
        if settings is None:
            raise DataError(root, f"no stereo calibration: put an ORB-SLAM3 settings file ({' or '.join(SETTINGS_NAMES)}) "
                                  "in the folder, or give --camera and --baseline")
        calibration = read_orbslam3_settings(settings)
    gt = root / "groundtruth.txt"
    return StereoSequence(root, [e.path for e in left], [e.path for e in right],
                          np.array([e.timestamp for e in left]), calibration, gt if gt.is_file() else None, "tum")


def open_stereo_sequence(path: str | Path, camera: str | PinholeCamera | None = None, baseline: float | None = None,
                         settings: str | Path | None = None, calibration: StereoCalibration | None = None,
                         groundtruth: str | Path | None = None) -> StereoSequence:
    """Open a stereo folder of any layout above. The calibration is, in order: ``calibration``,
    an ORB-SLAM3 ``settings`` YAML, ``camera`` (fx,fy,cx,cy) + ``baseline`` (metres) of a
    rectified pair, else the layout's own files."""
    root = Path(path)
    if not root.is_dir():
        raise DataError(root, "stereo sequence folder not found")
    if calibration is None and settings is not None:
        calibration = read_orbslam3_settings(settings)
    if calibration is None and (camera is not None or baseline is not None):
        if camera is None or baseline is None:
            raise ConfigError("explicit stereo calibration needs both --camera fx,fy,cx,cy and --baseline")
        calibration = stereo_from_values(camera, baseline)
    layout = stereo_layout(root)
    if layout == "euroc":
        return open_euroc_stereo(root, calibration)
    if layout == "kitti":
        return open_kitti_stereo(root, calibration, groundtruth)
    if layout == "tum":
        return open_tum_stereo(root, calibration)
    raise DataError(root, "not a stereo sequence (expected mav0/cam0 + mav0/cam1, image_0 + image_1 + calib.txt, "
                          "or rgb.txt + rgb_right.txt)")
