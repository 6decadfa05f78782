"""Sequence readers: TUM RGB-D (and the datasets that share its layout) and image folders.

A sequence is a list of frames with timestamps, a camera and, where it exists, a ground
truth file. Frames are decoded on demand. Iterating skips a few unreadable or missing frames
(and frames of another size than the first) with a warning naming the file and counts them
in ``skipped``; too many, or an unreadable first frame, is an error. List files may name
only files inside the sequence folder, each at its own, increasing timestamp; a broken
ground truth file is a warning (no evaluation), not an error.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.core import registry
from semslam.core.imu import ImuStream
from semslam.core.types import Frame
from semslam.datasets import is_dataset_name, resolve as resolve_dataset
from semslam.errors import ConfigError, DataError
from semslam.geometry.camera import PinholeCamera
from semslam.io.calibration import resolve_camera
from semslam.io.images import FrameReadError, read_depth, read_rgb
from semslam.io.text import read_text_lines
from semslam.io.trajectory import read_trajectory

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".ppm", ".pgm", ".bmp", ".tif", ".tiff")


@dataclass(frozen=True)
class ListEntry:
    timestamp: float
    path: Path
    line: int


def _data_lines(path: Path) -> Iterator[tuple[int, str]]:
    """(line number, stripped line) of a list file's lines that are not blank or comments."""
    for lineno, raw in enumerate(read_text_lines(path), start=1):
        line = raw.strip()
        if line and not line.startswith("#"):
            yield lineno, line


def _timestamp(path: Path, lineno: int, text: str) -> float:
    try:
        stamp = float(text)
    except ValueError:
        raise DataError(path, f"line {lineno}: timestamp {text!r} is not a number") from None
    if not np.isfinite(stamp):
        raise DataError(path, f"line {lineno}: timestamp is not finite")
    return stamp


def _check_after(path: Path, lineno: int, text: str, stamp: float, previous: ListEntry) -> None:
    """Timestamps must increase strictly: association pairs images by time, so two images
    at one instant (a logger with a coarse clock, lists pasted together) cannot be told apart."""
    if stamp == previous.timestamp:
        raise DataError(path, f"line {lineno}: duplicate timestamp {text} (line {previous.line} has it too); "
                              "each image needs its own timestamp")
    if stamp < previous.timestamp:
        before = f"{previous.timestamp:.6f}" if abs(previous.timestamp) < 1e12 else f"{previous.timestamp:.6g}"
        raise DataError(path, f"line {lineno}: timestamp {text} is not after the previous one ({before}, "
                              f"line {previous.line}); timestamps must increase")


def listed_path(list_file: Path, lineno: int, root: Path, name: str) -> Path:
    """``root / name`` for a file a list names; a name that leaves the sequence folder (an
    absolute path, or ``..`` climbing out) is refused: a sequence is one self-contained folder,
    and a list must not make the reader open files elsewhere on the machine. Checked on the
    name, not the resolved path, so folders of symbolic links (a dataset kept on another
    disk) still work."""
    posix = name.replace("\\", "/")
    parts = [p for p in posix.split("/") if p not in ("", ".")]
    depth = 0
    for part in parts:
        depth += -1 if part == ".." else 1
        if depth < 0:
            break
    if posix.startswith("/") or re.match(r"^[A-Za-z]:", posix) or depth < 0:
        raise DataError(list_file, f"line {lineno}: {name!r} points outside the sequence folder; "
                                   "list files must name files inside it, by relative paths")
    return root / Path(*parts) if parts else root


def read_file_list(path: Path, root: Path | None = None) -> list[ListEntry]:
    """Parse a TUM list file (``timestamp path`` per line, ``#`` comments).

    Timestamps must increase strictly: a list out of order means a broken file, and
    associating it would silently pair the wrong images.
    """
    root = root or path.parent
    entries: list[ListEntry] = []
    for lineno, line in _data_lines(path):
        parts = [p for p in re.split(r"[,\s]+", line) if p]
        if len(parts) < 2:
            raise DataError(path, f"line {lineno}: expected 'timestamp filename', got {line!r}")
        stamp = _timestamp(path, lineno, parts[0])
        if entries:
            _check_after(path, lineno, parts[0], stamp, entries[-1])
        entries.append(ListEntry(stamp, listed_path(path, lineno, root, parts[1]), lineno))
    if not entries:
        raise DataError(path, "no entries (only comments or blank lines)")
    return entries


def _read_associations(path: Path, root: Path) -> tuple[list[ListEntry], list[ListEntry]]:
    """Read an associations file (4 columns; the column whose path says 'depth' is depth)."""
    rgb: list[ListEntry] = []
    depth: list[ListEntry] = []
    for lineno, line in _data_lines(path):
        parts = line.split()
        if len(parts) < 4:
            raise DataError(path, f"line {lineno}: expected 't_rgb rgb_file t_depth depth_file', got {line!r}")
        t1, t2 = _timestamp(path, lineno, parts[0]), _timestamp(path, lineno, parts[2])
        first_is_depth = "depth" in parts[1].lower() and "depth" not in parts[3].lower()
        a = ListEntry(t1, listed_path(path, lineno, root, parts[1]), lineno)
        b = ListEntry(t2, listed_path(path, lineno, root, parts[3]), lineno)
        rgb_e, depth_e = (b, a) if first_is_depth else (a, b)
        if rgb:
            _check_after(path, lineno, parts[2] if first_is_depth else parts[0], rgb_e.timestamp, rgb[-1])
        rgb.append(rgb_e)
        depth.append(depth_e)
    if not rgb:
        raise DataError(path, "no associations (only comments or blank lines)")
    return rgb, depth


def find_groundtruth(root: Path) -> Path | None:
    """``groundtruth.txt`` (TUM, Bonn) or ``*.gt.freiburg`` (ICL-NUIM's TUM release)."""
    gt = root / "groundtruth.txt"
    if gt.is_file():
        return gt
    found = sorted(root.glob("*.gt.freiburg"))
    return found[0] if found else None


def usable_groundtruth(root: Path) -> Path | None:
    """The ground truth file if it can be read; a broken one is reported now, as a warning,
    and the run goes on without evaluation (the trajectory is worth having without it, and
    an error after an hour of tracking would lose stats.json)."""
    gt = find_groundtruth(root)
    if gt is None:
        return None
    try:
        read_trajectory(gt)
    except DataError as exc:
        log.warning("%s; the run goes on without evaluation (no ATE/RPE)", exc)
        return None
    return gt


class Sequence:
    """Base of all readers: frames by index, iteration with skipping, camera, ground truth."""

    name: str
    root: Path
    camera: PinholeCamera
    groundtruth_path: Path | None
    has_depth: bool
    max_skip_fraction: float = 0.05

    def __init__(self) -> None:
        self.skipped: list[tuple[int, str]] = []
        #: The IMU recording (EuRoC / TUM-VI imu0, a bag's Imu topic); each frame yielded by
        #: ``frames()`` then carries its readings since the frame before.
        self.imu: ImuStream | None = None

    @property
    def timestamps(self) -> NDArray[np.float64]:
        raise NotImplementedError

    def __len__(self) -> int:
        return len(self.timestamps)

    def load(self, index: int) -> Frame:
        """Decode frame ``index``; raises FrameReadError if its image cannot be used."""
        raise NotImplementedError

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[Frame]:
        """Yield readable frames, skipping a few unreadable or missing ones with a warning
        naming each one's file (and counting them in ``skipped``). An unreadable first frame
        is an error (a wrong format or a broken folder, most likely); a missing one is not."""
        stop = len(self) if stop is None else min(stop, len(self))
        allowed = max(3, int(self.max_skip_fraction * max(stop - start, 1)))
        first = True
        previous_t: float | None = None
        for i in range(start, stop):
            try:
                frame = self._same_size(self.load(i))
            except FrameReadError as exc:
                missing = exc.problem == "file not found"
                if first and not missing:
                    raise DataError(exc.path, f"first frame unreadable: {exc.problem}") from None
                self.skipped.append((i, str(exc)))
                log.warning("skipping frame %d: %s", i, exc)
                if len(self.skipped) > allowed:
                    raise DataError(
                        self.root, f"{len(self.skipped)} unreadable frames (more than {allowed} allowed); last: {exc}"
                    ) from None
                continue
            first = False
            if self.imu is not None:
                samples = self.imu.samples
                frame.imu = (samples.last_at(frame.timestamp) if previous_t is None
                             else samples.between(previous_t, frame.timestamp))
            previous_t = frame.timestamp
            yield frame

    def __iter__(self) -> Iterator[Frame]:
        return self.frames()

    def _same_size(self, frame: Frame) -> Frame:
        """A frame of another size than the sequence's first (the camera's): its intrinsics
        would not fit it, so it cannot be used."""
        h, w = frame.rgb.shape[:2]
        cam = self.camera
        if cam.width > 0 and (w, h) != (cam.width, cam.height):
            raise FrameReadError(frame.rgb_path or self.root,
                                 f"image is {w}x{h} but the sequence's first image is {cam.width}x{cam.height}")
        return frame


class TumRgbdSequence(Sequence):
    """A TUM RGB-D folder as published (rgb.txt, depth.txt, groundtruth.txt).

    Also reads the datasets that use its layout: Bonn RGB-D Dynamic, ICL-NUIM's TUM
    release (associations file + ``*.gt.freiburg``) and semslam's own synthetic sequences.
    rgb and depth are paired by nearest timestamp within ``max_diff`` seconds as TUM's
    associate.py does, unless an associations file is given or is the only list present.
    """

    def __init__(
        self,
        root: str | Path,
        camera: str | PinholeCamera | None = None,
        depth_scale: float = 5000.0,
        max_diff: float = 0.02,
        associations: str | Path | None = None,
    ) -> None:
        super().__init__()
        from semslam.io.association import match_timestamps

        self.root = Path(root)
        if not self.root.is_dir():
            raise DataError(self.root, "sequence folder not found")
        self.name = self.root.resolve().name
        self.depth_scale = float(depth_scale)
        self.has_depth = True
        rgb_txt, depth_txt = self.root / "rgb.txt", self.root / "depth.txt"
        assoc = Path(associations) if associations else None
        if assoc is None and not rgb_txt.is_file():
            candidates = sorted(self.root.glob("assoc*.txt"))
            assoc = candidates[0] if candidates else None
        if assoc is not None:
            if not assoc.is_file():
                raise DataError(assoc, "associations file not found")
            self._rgb, self._depth = _read_associations(assoc, self.root)
        else:
            if not rgb_txt.is_file():
                raise DataError(rgb_txt, "file not found (not a TUM RGB-D folder?)")
            if not depth_txt.is_file():
                raise DataError(depth_txt, "file not found (RGB-D needs depth; use an image folder for monocular)")
            rgb_all, depth_all = read_file_list(rgb_txt), read_file_list(depth_txt)
            t_rgb = np.array([e.timestamp for e in rgb_all])
            t_depth = np.array([e.timestamp for e in depth_all])
            i_rgb, i_depth = match_timestamps(t_rgb, t_depth, max_diff=max_diff)
            if len(i_rgb) == 0:
                raise DataError(
                    self.root,
                    f"no rgb/depth pairs within {max_diff} s: rgb.txt spans "
                    f"{t_rgb[0]:.3f}-{t_rgb[-1]:.3f}, depth.txt {t_depth[0]:.3f}-{t_depth[-1]:.3f}",
                )
            order = np.argsort(i_rgb)
            self._rgb = [rgb_all[i] for i in np.asarray(i_rgb)[order]]
            self._depth = [depth_all[i] for i in np.asarray(i_depth)[order]]
            if len(self._rgb) < 0.5 * len(rgb_all):
                log.warning("%s: only %d of %d rgb images have a depth image within %.3f s",
                            self.root, len(self._rgb), len(rgb_all), max_diff)
        self._check_missing_files()
        self._timestamps = np.array([e.timestamp for e in self._rgb])
        self.camera = with_image_size(resolve_camera(self.root, camera), self._first_present_rgb())
        self.groundtruth_path = usable_groundtruth(self.root)

    def _check_missing_files(self) -> None:
        """Listed files that do not exist: many mean a broken download (an error now); a few
        are skipped when iteration reaches them, each warned about by its own name and
        counted in ``skipped``, so a run's frame counts still add up to the list's length."""
        missing = [r.path if not r.path.is_file() else d.path
                   for r, d in zip(self._rgb, self._depth) if not (r.path.is_file() and d.path.is_file())]
        if not missing:
            return
        allowed = max(3, int(self.max_skip_fraction * len(self._rgb)))
        if len(missing) > allowed or len(missing) == len(self._rgb):
            raise DataError(missing[0], f"file not found, and {len(missing) - 1} more listed images are missing")

    def _first_present_rgb(self) -> Path | None:
        """The first listed colour image that exists: the camera's image size comes from it."""
        return next((e.path for e in self._rgb if e.path.is_file()), None)

    @property
    def timestamps(self) -> NDArray[np.float64]:
        return self._timestamps

    def load(self, index: int) -> Frame:
        rgb_e, depth_e = self._rgb[index], self._depth[index]
        rgb = read_rgb(rgb_e.path)
        depth = read_depth(depth_e.path, self.depth_scale)
        if depth.shape != rgb.shape[:2]:
            raise FrameReadError(depth_e.path, f"depth is {depth.shape[1]}x{depth.shape[0]} but rgb is "
                                               f"{rgb.shape[1]}x{rgb.shape[0]}")
        return Frame(index, rgb_e.timestamp, rgb, depth, rgb_e.path, depth_e.path)


def with_image_size(camera: PinholeCamera, first_image: Path | None) -> PinholeCamera:
    """The camera with the image size of the sequence's first image (read from its header by
    decoding it once); unchanged if it already has one or the image cannot be read (the frame
    reader then reports the file)."""
    if camera.width > 0 or first_image is None:
        return camera
    try:
        img = cv2.imread(str(first_image), cv2.IMREAD_UNCHANGED)
    except cv2.error:
        img = None
    if img is None or img.ndim < 2 or img.size == 0:
        return camera
    return camera.with_image_size(img.shape[1], img.shape[0])


def _natural_key(path: Path) -> list[object]:
    return [int(tok) if tok.isdigit() else tok for tok in re.split(r"(\d+)", path.name)]


class ImageFolderSequence(Sequence):
    """Monocular images in one folder (or its ``rgb/``, ``image_0/``, ``cam0/data/`` child).

    Timestamps come from, in order: ``rgb.txt`` (TUM list), ``times.txt`` (one per line,
    KITTI/EuRoC), numeric file names (EuRoC nanoseconds are converted), else index / fps.
    """

    def __init__(self, root: str | Path, camera: str | PinholeCamera | None = None, fps: float = 30.0) -> None:
        super().__init__()
        self.root = Path(root)
        if not self.root.is_dir():
            raise DataError(self.root, "image folder not found")
        self.name = self.root.resolve().name
        self.has_depth = False
        if (self.root / "rgb.txt").is_file():
            entries = read_file_list(self.root / "rgb.txt")
            self._paths = [e.path for e in entries]
            self._timestamps = np.array([e.timestamp for e in entries])
        else:
            folder = next((self.root / s for s in ("rgb", "image_0", "cam0/data", "images") if (self.root / s).is_dir()), self.root)
            self._paths = sorted((p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES), key=_natural_key)
            if not self._paths:
                raise DataError(folder, f"no images ({', '.join(IMAGE_SUFFIXES)}) in folder")
            self._timestamps = self._folder_timestamps(fps)
        first = next((p for p in self._paths if p.is_file()), None)  # a missing one is skipped when reached
        self.camera = with_image_size(resolve_camera(self.root, camera), first)
        self.groundtruth_path = usable_groundtruth(self.root)

    def _folder_timestamps(self, fps: float) -> NDArray[np.float64]:
        times = self.root / "times.txt"
        if times.is_file():
            try:
                values = np.loadtxt(times, comments="#", ndmin=1, usecols=0)
            except ValueError as exc:
                raise DataError(times, f"not a column of numbers ({exc})") from None
            if len(values) != len(self._paths):
                raise DataError(times, f"{len(values)} timestamps for {len(self._paths)} images")
        else:
            try:
                values = np.array([float(p.stem) for p in self._paths])
            except ValueError:
                return np.arange(len(self._paths)) / fps
            if values.max() > 1e12:  # EuRoC names images by nanoseconds
                values = values / 1e9
            elif all(p.stem.isdigit() for p in self._paths) and values.max() < 1e9:
                return np.arange(len(self._paths)) / fps  # KITTI-style frame numbers
        bad = np.nonzero(np.diff(values) <= 0)[0]
        if len(bad):
            raise DataError(times if times.is_file() else self._paths[bad[0] + 1],
                            f"timestamps must increase; entry {bad[0] + 2} is not after entry {bad[0] + 1}")
        return values.astype(np.float64)

    @property
    def timestamps(self) -> NDArray[np.float64]:
        return self._timestamps

    def load(self, index: int) -> Frame:
        path = self._paths[index]
        return Frame(index, float(self._timestamps[index]), read_rgb(path), None, path, None)


def kind_for_sensor(sensor: str) -> str:
    """The ``open_sequence`` kind a config's sensor reads: ``mono`` reads a TUM folder's
    colour images only (its depth is not the monocular tracker's to use) and EuRoC's cam0
    alone, ``stereo`` the left and right images, ``rgbd`` the input's depth where it has
    some (a TUM folder's, EuRoC's depth0) and otherwise what ``auto`` opens; else ``auto``."""
    return sensor if sensor in ("mono", "stereo", "rgbd") else "auto"


def open_sequence(
    path: str | Path,
    camera: str | PinholeCamera | None = None,
    kind: str = "auto",
    depth_scale: float = 5000.0,
    max_diff: float = 0.02,
    baseline: float | None = None,
    settings: str | Path | None = None,
) -> Sequence:
    """Open a sequence folder; ``kind`` is ``auto``, ``rgbd``, ``mono`` or ``stereo``.

    - ``rgbd``: the input's depth (a TUM layout's lists, EuRoC's ``depth0`` registered to
      cam0, a bag's depth topic); an input without depth opens as ``auto`` would (a stereo
      folder then runs an RGB-D preset as stereo, ``pipeline.config_for_sequence``).
    - ``mono``: an image folder, a TUM folder's ``rgb.txt`` images without their depth, or
      EuRoC's cam0 alone (``io.euroc_sequence``).
    - ``stereo`` (``io.stereo_sequence``): EuRoC, KITTI, or a TUM-like folder with
      ``rgb_right.txt``; the calibration from the layout's files, an ORB-SLAM3 ``settings``
      YAML, or ``camera`` + ``baseline``.
    - ``auto`` opens EuRoC (with cam1) and KITTI stereo folders, and a TUM-like one with
      right images but no depth, as stereo; EuRoC without cam1 as RGB-D where it has depth0,
      else as monocular.

    EuRoC and TUM-VI folders with ``mav0/imu0`` carry their IMU (``Sequence.imu``)."""
    root = Path(path)
    if root.suffix.lower() == ".bag":  # a ROS 1 bag (io/rosbag_sequence.py, io/rosbag_stereo.py): the registry's
        return registry.create("sequence_source", "rosbag", root, camera=camera, max_diff=max_diff, read_as=kind,
                               baseline=baseline, settings=settings)
    if not root.exists() and is_dataset_name(str(path)):  # tum/fr3_walking_xyz: its downloaded folder
        root = resolve_dataset(str(path))
    if not root.exists():
        raise DataError(root, "sequence not found")
    if not root.is_dir():
        raise DataError(root, "not a folder (give the sequence folder, e.g. rgbd_dataset_freiburg3_walking_xyz/)")
    if kind not in ("auto", "rgbd", "mono", "stereo"):
        raise DataError(root, f"unknown sequence kind {kind!r} (auto, rgbd, mono, stereo)")
    is_rgbd = (root / "depth.txt").is_file() or any(root.glob("assoc*.txt"))
    euroc = euroc_folder(root)
    euroc_depth = euroc is not None and not is_rgbd and (euroc / "depth0").is_dir()
    if kind == "rgbd" and not (is_rgbd or euroc_depth):
        kind = "auto"  # no depth of its own: what the input is (pipeline.config_for_sequence follows it)
    if kind == "stereo" or (kind == "auto" and _opens_as_stereo(root, is_rgbd)):  # io/stereo_sequence.py
        return registry.create("sequence_source", "stereo", root, camera=camera, baseline=baseline, settings=settings)
    if baseline is not None or settings is not None:
        raise ConfigError("--baseline / --settings describe a stereo pair; this sequence is read as "
                          f"{'RGB-D' if kind == 'rgbd' or is_rgbd or euroc_depth else 'monocular'} (give --sensor "
                          "stereo for its right images)")
    if euroc is not None and not is_rgbd:  # io/euroc_sequence.py: cam0 alone, or with depth0
        return registry.create("sequence_source", "euroc", root, with_depth=kind != "mono" and euroc_depth,
                               camera=camera, depth_scale=depth_scale)
    if kind == "rgbd" or (kind == "auto" and is_rgbd):
        return TumRgbdSequence(root, camera=camera, depth_scale=depth_scale, max_diff=max_diff)
    return ImageFolderSequence(root, camera=camera)


def euroc_folder(root: Path) -> Path | None:
    """The folder holding EuRoC's ``cam0/data.csv`` (``root/mav0`` or ``root``), else None."""
    return next((cand for cand in (root / "mav0", root) if (cand / "cam0" / "data.csv").is_file()), None)


def euroc_root(root: Path) -> Path | None:
    """The folder holding EuRoC's ``cam0`` and ``cam1`` (``root/mav0`` or ``root``), else None."""
    for cand in (root / "mav0", root):
        if (cand / "cam0").is_dir() and (cand / "cam1").exists():
            return cand
    return None


def stereo_layout(root: Path) -> str | None:
    """``euroc``, ``kitti`` or ``tum`` when the folder is a stereo sequence of that layout:
    it has ``mav0/cam1``, ``image_1`` + ``calib.txt``, or ``rgb_right.txt``."""
    if euroc_root(root) is not None:
        return "euroc"
    if (root / "image_1").is_dir() and (root / "calib.txt").is_file():
        return "kitti"
    if (root / "rgb_right.txt").is_file():
        return "tum"
    return None


def _opens_as_stereo(root: Path, is_rgbd: bool) -> bool:
    """EuRoC and KITTI folders, and TUM-like ones with right images but no depth: what
    ``auto`` reads as stereo."""
    layout = stereo_layout(root)
    return layout in ("euroc", "kitti") or (layout == "tum" and not is_rgbd)
