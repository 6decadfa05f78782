"""An EuRoC ASL folder read with one camera: cam0 alone (monocular, e.g. mono-inertial) or
cam0 with ``depth0`` registered to it (RGB-D).

- cam0: ``mav0/cam0/data.csv`` (``#timestamp [ns],filename``), ``data/`` images and
  ``sensor.yaml`` (the camera, distortion included, and ``T_BS``); without the
  ``sensor.yaml`` the intrinsics come as for any folder (``io.calibration``).
- depth0: ``data.csv`` and ``data/<ns>.png`` (16-bit, metres x ``depth_scale``), each image
  paired with cam0's at its stamp; ``sensor.yaml`` gives ``depth_scale`` and a ``T_BS`` that
  must be cam0's (registered depth lies on cam0's pixels).
- ground truth ``state_groundtruth_estimate0/data.csv`` turned into cam0's poses and the IMU
  (``imu0``) attached as the stereo reader does (``io.stereo_sequence``, ``io.imu``).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from semslam.core.types import Frame
from semslam.errors import DataError
from semslam.geometry.camera import PinholeCamera
from semslam.io.calibration import resolve_camera
from semslam.io.images import FrameReadError, read_depth, read_rgb
from semslam.io.imu import attach_imu
from semslam.io.sequence import euroc_folder, with_image_size
from semslam.io.stereo_calibration import load_yaml, numbers, read_euroc_sensor
from semslam.io.stereo_sequence import LayoutSequence, pair_lists, read_euroc_list

log = logging.getLogger(__name__)


class EurocSequence(LayoutSequence):
    """cam0's images (and depth0's, for RGB-D) of an EuRoC folder, by index."""

    def __init__(self, root: Path, images: list[Path], timestamps: NDArray[np.float64], camera: PinholeCamera,
                 depths: list[Path] | None = None, depth_scale: float = 5000.0,
                 groundtruth_path: Path | None = None, t_bs: NDArray[np.float64] | None = None) -> None:
        super().__init__()
        self._set_frames(root, timestamps)
        self._images, self._depths = images, depths
        self.has_depth = depths is not None
        self.depth_scale = float(depth_scale)
        self._check_listed_files([images] if depths is None else [images, depths])
        self.camera = with_image_size(camera, next((p for p in images if p.is_file()), None))
        self._set_groundtruth(groundtruth_path, "euroc", t_bs)

    @property
    def timestamps(self) -> NDArray[np.float64]:
        return self._timestamps

    def load(self, index: int) -> Frame:
        path = self._images[index]
        rgb = read_rgb(path)
        if self._depths is None:
            return Frame(index, float(self._timestamps[index]), rgb, None, path, None)
        depth_path = self._depths[index]
        depth = read_depth(depth_path, self.depth_scale)
        if depth.shape != rgb.shape[:2]:
            raise FrameReadError(depth_path, f"depth is {depth.shape[1]}x{depth.shape[0]} but cam0's image is "
                                             f"{rgb.shape[1]}x{rgb.shape[0]}")
        return Frame(index, float(self._timestamps[index]), rgb, depth, path, depth_path)


def _depth_scale(mav0: Path, t_bs_cam0: NDArray[np.float64] | None, default: float) -> float:
    """depth0/sensor.yaml's ``depth_scale`` (units per metre), checking that its ``T_BS`` is
    cam0's; ``default`` without the file (a warning: the scale is a guess then)."""
    path = mav0 / "depth0" / "sensor.yaml"
    if not path.is_file():
        log.warning("%s not found; depth read at %g units per metre", path, default)
        return default
    doc = load_yaml(path)
    if "depth_scale" not in doc:
        raise DataError(path, "no depth_scale (the depth images' units per metre, e.g. 5000.0)")
    scale = numbers(path, "depth_scale", [doc["depth_scale"]], 1)[0]
    if not scale > 0:
        raise DataError(path, f"depth_scale: expected a number > 0, got {scale:g}")
    if "T_BS" in doc and t_bs_cam0 is not None:
        t_bs = np.asarray(numbers(path, "T_BS", doc["T_BS"], 16)).reshape(4, 4)
        if not np.allclose(t_bs, t_bs_cam0, atol=1e-6):
            raise DataError(path, "T_BS is not cam0's: depth0 must be registered to cam0 (its pixels on cam0's)")
    return scale


def open_euroc(root: str | Path, with_depth: bool = False, camera: str | PinholeCamera | None = None,
               depth_scale: float = 5000.0, max_diff: float = 0.001) -> EurocSequence:
    """An EuRoC folder (the folder holding ``mav0/``, or ``mav0`` itself) as a monocular
    sequence of cam0's images, or (``with_depth``) as RGB-D with depth0's images paired to
    them by stamp (within ``max_diff`` s). ``camera`` replaces cam0's ``sensor.yaml``;
    ``depth_scale`` is used only where depth0 has no ``sensor.yaml``."""
    root = Path(root)
    mav0 = euroc_folder(root)
    if mav0 is None:
        raise DataError(root / "mav0" / "cam0" / "data.csv", "file not found (an EuRoC sequence lists cam0's images there)")
    cam0_csv = mav0 / "cam0" / "data.csv"
    entries = read_euroc_list(cam0_csv)
    sensor = mav0 / "cam0" / "sensor.yaml"
    cam0, t_bs = read_euroc_sensor(sensor) if sensor.is_file() else (None, None)
    cam = resolve_camera(root, camera) if camera is not None or cam0 is None else cam0
    depths: list[Path] | None = None
    if with_depth:
        depth_csv = mav0 / "depth0" / "data.csv"
        if not depth_csv.is_file():
            raise DataError(depth_csv, "file not found (EuRoC RGB-D reads depth0's images registered to cam0)")
        depth_scale = _depth_scale(mav0, t_bs, depth_scale)
        entries, depth_entries = pair_lists(entries, read_euroc_list(depth_csv), cam0_csv, depth_csv, max_diff,
                                            what="depth image")
        depths = [e.path for e in depth_entries]
    gt = mav0 / "state_groundtruth_estimate0" / "data.csv"
    seq = EurocSequence(root, [e.path for e in entries], np.array([e.timestamp for e in entries]), cam, depths,
                        depth_scale, gt if gt.is_file() else None, t_bs)
    attach_imu(seq, mav0)  # imu0, where the folder has one: each frame then carries its readings
    return seq
