"""ROS 1 bags with two image topics (a stereo pair) as a stereo sequence.

The pair is the first of :data:`STEREO_TOPICS` whose two topics are in the bag (EuRoC's
``/cam0/image_raw`` + ``/cam1/image_raw``, a RealSense's infrared pair, ...), or the two
topics given. Images are decoded as the RGB-D reader's colour images (mono8 grey expanded
to RGB), left and right are paired by nearest header stamp (``io/association.match_timestamps``,
``max_diff`` as for colour/depth) and each pair is rectified with a
:class:`~semslam.io.stereo_calibration.StereoCalibration`. The calibration is, in order:

1. ``calibration`` (e.g. from ``--settings camera.yaml``), ``settings`` (an ORB-SLAM3
   settings file), or ``camera`` (fx,fy,cx,cy) + ``baseline`` (metres) of a rectified pair;
2. the two topics' ``CameraInfo`` (``<namespace>/camera_info``): ``K``, ``D`` (plumb_bob),
   ``R`` and the right camera's ``P`` whose ``Tx = P[0,3] = -fx' * baseline``, as ROS's
   stereo calibration writes them. Same ``K``, no distortion and no rotation: already
   rectified (no remap). Otherwise the right camera's pose in the left's frame follows
   from the rectifying rotations: ``T_lr = [R1^T R2 | R1^T (b, 0, 0)]``;
3. else a :class:`~semslam.errors.DataError` asking for a settings file or values.

Ground truth comes from ``/tf`` as for an RGB-D bag, for the left image's frame. An
ORB-SLAM3 ``settings`` file with ``IMU.*`` keys (stereo-inertial) also attaches the bag's
``sensor_msgs/Imu`` topic (``/imu0`` for EuRoC) as the sequence's IMU.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from semslam.core.types import Frame
from semslam.errors import ConfigError, DataError
from semslam.geometry.camera import PinholeCamera
from semslam.io.association import match_timestamps
from semslam.io.images import FrameReadError
from semslam.io.imu import orbslam3_has_imu, read_orbslam3_imu
from semslam.io.rosbag_sequence import DEPTH_TOPICS, TF_TOPICS, RosbagSequence
from semslam.io.stereo_calibration import StereoCalibration, read_orbslam3_settings, stereo_from_values

log = logging.getLogger(__name__)

#: (left, right) image topics of known stereo bags, in order of preference.
STEREO_TOPICS = (
    ("/cam0/image_raw", "/cam1/image_raw"),  # EuRoC MAV
    ("/stereo/left/image_raw", "/stereo/right/image_raw"),
    ("/left/image_raw", "/right/image_raw"),
    ("/camera/infra1/image_rect_raw", "/camera/infra2/image_rect_raw"),  # RealSense D4xx infrared
)
CALIBRATION_HINT = ("give --settings camera.yaml (an ORB-SLAM3 settings file) or --camera fx,fy,cx,cy "
                    "--baseline B (metres) for a rectified pair")


def info_topic(image_topic: str) -> str:
    """The camera info topic beside an image topic (``/cam0/image_raw`` -> ``/cam0/camera_info``)."""
    return image_topic.rstrip("/").rsplit("/", 1)[0] + "/camera_info"


def stereo_topics(topics: dict[str, Any] | list[str]) -> tuple[str, str] | None:
    """The first known (left, right) pair with both topics present."""
    return next(((a, b) for a, b in STEREO_TOPICS if a in topics and b in topics), None)


def _bag_topics(path: str | Path) -> dict[str, Any] | None:
    """The bag's topics, None if it is unreadable (the RGB-D reader then says why)."""
    from rosbags.highlevel import AnyReader

    try:
        with AnyReader([Path(path)]) as reader:
            return dict(reader.topics)
    except Exception:  # noqa: BLE001 - any reader failure means "not a bag we can open"
        return None


def bag_has_stereo(path: str | Path) -> bool:
    """Whether the bag holds both topics of a known stereo pair (False if it is unreadable:
    the RGB-D reader then says why)."""
    topics = _bag_topics(path)
    return topics is not None and stereo_topics(topics) is not None


class StereoRosbagSequence(RosbagSequence):
    """A ROS 1 bag with a left and a right image topic; frames carry ``right``, both rectified."""

    has_depth = False

    def __init__(
        self,
        path: str | Path,
        calibration: StereoCalibration | None = None,
        camera: str | PinholeCamera | None = None,
        baseline: float | None = None,
        max_diff: float = 0.02,
        settings: str | Path | None = None,
        left_topic: str | None = None,
        right_topic: str | None = None,
    ) -> None:
        super(RosbagSequence, self).__init__()  # Sequence's: this opening replaces the RGB-D one
        if calibration is None:
            calibration = _explicit_calibration(camera, baseline, settings)
        self._open(path)
        self.depth_scale = 1.0
        topics = self._reader.topics
        left_name, right_name = self._pick_topics(topics, left_topic, right_topic)
        self._depth = None
        self._rgb = self._stream(topics, left_name, (), "left image")
        self._right = self._stream(topics, right_name, (), "right image")
        infos_wanted = [t for t in (info_topic(left_name), info_topic(right_name)) if t in topics]
        infos, transforms, image_frame = self._scan([self._rgb, self._right], infos_wanted,
                                                    [t for t in TF_TOPICS if t in topics])
        self._pairs = self._associate(max_diff)
        self._timestamps = np.array([self._rgb.stamps[i] for i, _ in self._pairs])
        if calibration is None:
            calibration = self._calibration_from_info(infos.get(info_topic(left_name)),
                                                      infos.get(info_topic(right_name)))
        if calibration.rectified_input and calibration.camera.width <= 0:
            calibration = calibration.with_image_size(*self._image_size())
        self.calibration = calibration
        self.camera: PinholeCamera = calibration.camera
        self._set_groundtruth(transforms, image_frame)
        if settings is not None and orbslam3_has_imu(settings):  # stereo-inertial: the IMU topic too
            self.attach_imu(read_orbslam3_imu(settings))

    # ------------------------------------------------------------------ opening
    def _pick_topics(self, topics: dict[str, Any], left: str | None, right: str | None) -> tuple[str, str]:
        if left or right:
            if not (left and right):
                raise ConfigError("a stereo bag needs both the left and the right image topic")
            return left, right
        found = stereo_topics(topics)
        if found is not None:
            return found
        half = next(((a, b) for a, b in STEREO_TOPICS if a in topics or b in topics), None)
        if half is not None:
            have, lack = half if half[0] in topics else half[::-1]
            raise DataError(self.root, f"stereo bag has {have} but no {lack} (both images of the pair are needed)")
        images = sorted(t for t, info in topics.items() if info.msgtype and info.msgtype.endswith("Image"))
        raise DataError(self.root, "no stereo image topics (expected one of "
                                   f"{', '.join(' + '.join(p) for p in STEREO_TOPICS)}; its image topics: "
                                   f"{', '.join(images) or 'none'})")

    def _associate(self, max_diff: float) -> list[tuple[int, int]]:
        """(left index, right index) per frame, by nearest header stamp."""
        left, right = self._rgb, self._right
        i_left, i_right = match_timestamps(left.stamps, right.stamps, max_diff=max_diff)
        if len(i_left) == 0:
            raise DataError(self.root, f"no left/right pairs within {max_diff} s: {left.topic} spans "
                                       f"{left.stamps[0]:.3f}-{left.stamps[-1]:.3f}, {right.topic} "
                                       f"{right.stamps[0]:.3f}-{right.stamps[-1]:.3f}")
        if len(i_left) < len(left.stamps):
            log.warning("%s: %d of %d left images have no right image within %.3f s; dropped",
                        self.root, len(left.stamps) - len(i_left), len(left.stamps), max_diff)
        order = np.argsort(i_left)
        return [(int(i_left[k]), int(i_right[k])) for k in order]

    def _calibration_from_info(self, left_info: Any, right_info: Any) -> StereoCalibration:
        """The pair from the two CameraInfo messages (see the module docstring)."""
        left_topic, right_topic = info_topic(self._rgb.topic), info_topic(self._right.topic)
        left, right = self._camera_from_info(left_info), self._camera_from_info(right_info)
        if left is None or right is None:
            missing = left_topic if left is None else right_topic
            raise DataError(self.root, f"no stereo calibration: {missing} is missing or uncalibrated; "
                                       + CALIBRATION_HINT)
        width, height = (left.width, left.height) if left.width > 0 else self._image_size()
        left, right = left.with_image_size(width, height), right.with_image_size(width, height)
        p = _matrix(right_info, "P", (3, 4))
        if p is None or p[0, 0] <= 0 or p[0, 3] == 0:
            raise DataError(self.root, f"no stereo calibration: {right_topic} has no baseline (P[0,3] = -fx * "
                                       "baseline is 0); " + CALIBRATION_HINT)
        baseline = -p[0, 3] / p[0, 0]
        r_left, r_right = _rotation(left_info), _rotation(right_info)
        source = f"camera_info in {self.root.name}"
        same = np.allclose(left.K, right.K, rtol=0.0, atol=1e-6)
        rotated = any(r is not None and not np.allclose(r, np.eye(3), atol=1e-9) for r in (r_left, r_right))
        if same and not rotated and not left.is_distorted and not right.is_distorted:
            pose = np.eye(4)
            pose[0, 3] = baseline
            return StereoCalibration(left, left, pose, source, rectified_input=True)
        if r_left is None or r_right is None:
            raise DataError(self.root, f"the stereo pair is not rectified ({left_topic} and {right_topic} differ "
                                       "or have distortion) and the camera infos hold no rectifying rotations R "
                                       "(no extrinsics); " + CALIBRATION_HINT)
        pose = np.eye(4)
        pose[:3, :3] = r_left.T @ r_right
        pose[:3, 3] = r_left.T @ np.array([baseline, 0.0, 0.0])
        return StereoCalibration(left, right, pose, source)

    # ------------------------------------------------------------------ frames
    def load(self, index: int) -> Frame:
        i_left, i_right = self._pairs[index]
        left = self._decode_colour(self._message(self._rgb, i_left), i_left, self._rgb)
        right = self._decode_colour(self._message(self._right, i_right), i_right, self._right)
        t = float(self._timestamps[index])
        if right.shape != left.shape:
            raise FrameReadError(self.root, f"{self._right.topic} at t={t:.6f}: right image is "
                                            f"{right.shape[1]}x{right.shape[0]} but the left one is "
                                            f"{left.shape[1]}x{left.shape[0]}")
        cam = self.calibration.camera
        if self.calibration.maps is not None and (left.shape[1], left.shape[0]) != (cam.width, cam.height):
            raise FrameReadError(self.root, f"{self._rgb.topic} at t={t:.6f}: image is {left.shape[1]}x"
                                            f"{left.shape[0]} but the calibration's is {cam.width}x{cam.height}")
        left, right = self.calibration.rectify(left, right)
        return Frame(index, t, left, None, right=right)


def _explicit_calibration(camera: str | PinholeCamera | None, baseline: float | None,
                          settings: str | Path | None) -> StereoCalibration | None:
    if settings is not None:
        return read_orbslam3_settings(settings)
    if camera is None and baseline is None:
        return None
    if camera is None or baseline is None:
        raise ConfigError("explicit stereo calibration needs both --camera fx,fy,cx,cy and --baseline")
    return stereo_from_values(camera, float(baseline))


def _matrix(info: Any, name: str, shape: tuple[int, int]) -> np.ndarray | None:
    values = np.asarray(getattr(info, name, getattr(info, name.lower(), [])), dtype=np.float64)
    if values.size != shape[0] * shape[1] or not np.all(np.isfinite(values)):
        return None
    return values.reshape(shape)


def _rotation(info: Any) -> np.ndarray | None:
    """The rectifying rotation ``R`` of a camera info; None where it is unset (zeros) or not a rotation."""
    r = _matrix(info, "R", (3, 3))
    if r is None or np.abs(r.T @ r - np.eye(3)).max() > 1e-4 or np.linalg.det(r) < 0:
        return None
    return r


def open_stereo_rosbag(path: str | Path, calibration: StereoCalibration | None = None,
                       camera: str | PinholeCamera | None = None, baseline: float | None = None,
                       max_diff: float = 0.02, settings: str | Path | None = None) -> StereoRosbagSequence:
    """A stereo ROS 1 bag as a sequence (calibration order: see the module docstring)."""
    return StereoRosbagSequence(path, calibration=calibration, camera=camera, baseline=baseline,
                                max_diff=max_diff, settings=settings)


def open_rosbag(path: str | Path, camera: str | PinholeCamera | None = None, max_diff: float = 0.02,
                read_as: str = "auto", baseline: float | None = None,
                settings: str | Path | None = None) -> RosbagSequence:
    """A ROS 1 bag as ``open_sequence`` opens it (``read_as`` auto, rgbd, mono or stereo): a
    stereo sequence when asked for, or (auto, and rgbd on a bag without a depth topic) when
    both topics of a stereo pair are there; else colour (and depth, unless mono) as
    ``RosbagSequence`` reads them."""
    topics = _bag_topics(path) if read_as in ("auto", "rgbd") and Path(path).is_file() else None
    if read_as == "rgbd" and topics is not None and not any(t in topics for t in DEPTH_TOPICS):
        read_as = "auto"  # no depth of its own: what the bag is (as open_sequence does for folders)
    if read_as == "stereo" or (read_as == "auto" and topics is not None and stereo_topics(topics) is not None):
        return open_stereo_rosbag(path, camera=camera, baseline=baseline, max_diff=max_diff, settings=settings)
    if baseline is not None or settings is not None:
        raise ConfigError("--baseline / --settings describe a stereo pair; this bag is read as "
                          f"{'monocular' if read_as == 'mono' else 'RGB-D'} (give --sensor stereo for a stereo bag)")
    return RosbagSequence(path, camera=camera, max_diff=max_diff, with_depth=read_as != "mono")
