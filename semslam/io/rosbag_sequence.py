"""ROS 1 bags (TUM RGB-D's and Bonn's ``.bag`` files) as a sequence, read with ``rosbags``.

What is taken from the bag:

- colour: ``sensor_msgs/Image`` (rgb8, bgr8, rgba8, bgra8, mono8) or ``CompressedImage``
  on the first of :data:`COLOUR_TOPICS` present (TUM: ``/camera/rgb/image_color``);
- depth: ``sensor_msgs/Image`` 32FC1 in metres (TUM: ``/camera/depth/image``) or 16UC1 in
  millimetres (ROS REP 118) on the first of :data:`DEPTH_TOPICS`;
- intrinsics: ``K`` and ``D`` (plumb_bob) of the first ``CameraInfo`` on
  :data:`INFO_TOPICS`. ``--camera`` wins over it; without one the calibration is recognised
  from the bag's name (TUM freiburg1/2/3, Bonn) as for a folder, and that calibration also
  replaces a ``CameraInfo`` holding the OpenNI driver's uncalibrated defaults
  (525, 525, 319.5, 239.5);
- IMU (``attach_imu``, with a calibration from elsewhere: a bag carries none):
  ``sensor_msgs/Imu`` on the first of :data:`IMU_TOPICS`, by header stamp;
- ground truth: ``/tf`` (and ``/tf_static``). The pose of the colour image's frame
  (its ``header.frame_id``, e.g. ``/openni_rgb_optical_frame``) in the root of its tf tree,
  composed along the chain as TUM's ``bag2gt`` tool does (``/world`` -> ``/kinect`` -> ...
  -> optical frame), at the stamps of the chain's most frequent (motion capture) edge; the
  other edges are taken at their latest value. If the image frame is not in the tree, the
  most frequent edge itself (``/world`` -> ``/kinect``) is used, with a warning. It is
  written as a TUM file in a temporary folder that lives as long as the sequence, so the
  pipeline evaluates against it as against ``groundtruth.txt``.

Timestamps are the messages' header stamps (what TUM's ``rgb.txt`` lists), and colour and
depth are paired by nearest stamp as for a folder (``io/association.match_timestamps``).
Opening a bag reads it once (stamps, camera, tf); frames are decoded on demand. Bags with
a stereo pair of image topics are read by ``io/rosbag_stereo.py``, which reuses this reader.
"""

from __future__ import annotations

import logging
import tempfile
import weakref
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.core.imu import ImuCalibration, ImuSamples, ImuStream
from semslam.core.types import Frame
from semslam.errors import DataError
from semslam.geometry.camera import PinholeCamera
from semslam.geometry.se3 import make_pose, quat_to_rot
from semslam.io.association import match_timestamps
from semslam.io.calibration import DEFAULT_CAMERA, camera_from_folder_name, camera_from_values, parse_camera_option
from semslam.io.images import FrameReadError
from semslam.io.imu import check_imu
from semslam.io.sequence import Sequence
from semslam.core.trajectory import Trajectory
from semslam.io.trajectory import write_tum

log = logging.getLogger(__name__)

COLOUR_TOPICS = ("/camera/rgb/image_color", "/camera/rgb/image_color/compressed", "/camera/rgb/image_raw",
                 "/camera/rgb/image_raw/compressed", "/camera/color/image_raw", "/camera/color/image_raw/compressed")
DEPTH_TOPICS = ("/camera/depth/image", "/camera/depth_registered/image", "/camera/depth/image_raw",
                "/camera/depth_registered/image_raw", "/camera/aligned_depth_to_color/image_raw")
INFO_TOPICS = ("/camera/rgb/camera_info", "/camera/color/camera_info")
#: IMU topics (sensor_msgs/Imu) tried in order: EuRoC's, then common driver names.
IMU_TOPICS = ("/imu0", "/imu", "/imu/data", "/imu/data_raw", "/camera/imu")
TF_TOPICS = ("/tf", "/tf_static")
COLOUR_ENCODINGS = ("rgb8", "bgr8", "rgba8", "bgra8", "mono8")
DEPTH_ENCODINGS = ("32fc1", "16uc1", "mono16")
OPENNI_DEFAULT = (525.0, 525.0, 319.5, 239.5)
# Channels per pixel and the RGB channel order of each colour encoding.
_CHANNELS = {"rgb8": (3, [0, 1, 2]), "bgr8": (3, [2, 1, 0]), "rgba8": (4, [0, 1, 2]), "bgra8": (4, [2, 1, 0]),
             "mono8": (1, [0, 0, 0])}


@dataclass
class _Stream:
    """One image topic: where each message is (record time, rank among equal times) and its stamp."""

    topic: str
    connections: list[Any]
    msgtype: str
    encoding: str = ""
    keys: list[tuple[int, int]] = field(default_factory=list)
    stamps: list[float] = field(default_factory=list)


def _stamp(header: Any) -> float:
    return float(header.stamp.sec) + 1e-9 * float(header.stamp.nanosec)


def _frame_id(name: str) -> str:
    return name.strip().lstrip("/")


class RosbagSequence(Sequence):
    """A ROS 1 bag with colour, depth (unless ``with_depth`` is False), camera info and tf."""

    def __init__(
        self,
        path: str | Path,
        camera: str | PinholeCamera | None = None,
        max_diff: float = 0.02,
        with_depth: bool = True,
        depth_scale: float = 1000.0,
        rgb_topic: str | None = None,
        depth_topic: str | None = None,
        info_topic: str | None = None,
    ) -> None:
        super().__init__()
        self._open(path)
        self.has_depth = with_depth
        self.depth_scale = float(depth_scale)  # 16UC1 units per metre (REP 118: millimetres)
        topics = self._reader.topics
        self._rgb = self._stream(topics, rgb_topic, COLOUR_TOPICS, "colour image")
        self._depth = self._stream(topics, depth_topic, DEPTH_TOPICS, "depth image") if with_depth else None
        info = info_topic or next((t for t in INFO_TOPICS if t in topics), None)
        if info_topic and info_topic not in topics:
            raise DataError(self.root, f"no topic {info_topic} in the bag")
        streams = [s for s in (self._rgb, self._depth) if s is not None]
        infos, transforms, image_frame = self._scan(streams, [info] if info else [],
                                                    [t for t in TF_TOPICS if t in topics])
        self._pairs = self._associate(max_diff)
        self._timestamps = np.array([self._rgb.stamps[i] for i, _ in self._pairs])
        self.camera = self._camera(camera, infos.get(info or ""))
        self._set_groundtruth(transforms, image_frame)

    # ------------------------------------------------------------------ opening
    def _open(self, path: str | Path) -> None:
        """The bag's reader (closed with the sequence)."""
        self.root = Path(path)
        if not self.root.is_file():
            raise DataError(self.root, "bag file not found")
        self.name = self.root.stem
        self._reader = self._open_reader()
        self._closer = weakref.finalize(self, self._reader.close)

    def _set_groundtruth(self, transforms: list[tuple[float, str, str, Any]], image_frame: str) -> None:
        """Ground truth from /tf, written as a TUM file that lives as long as the sequence."""
        self.groundtruth: Trajectory | None = _groundtruth_from_tf(transforms, image_frame, self.root)
        self._gt_dir: tempfile.TemporaryDirectory[str] | None = None
        self.groundtruth_path: Path | None = None
        if self.groundtruth is not None:
            self._gt_dir = tempfile.TemporaryDirectory(prefix="semslam-bag-gt-")
            self.groundtruth_path = Path(self._gt_dir.name) / "groundtruth.txt"
            write_tum(self.groundtruth_path, self.groundtruth)

    def _open_reader(self) -> Any:
        from rosbags.highlevel import AnyReader, AnyReaderError

        reader = AnyReader([self.root])
        try:
            reader.open()
        except (AnyReaderError, OSError, ValueError, KeyError) as exc:
            raise DataError(self.root, f"not a readable ROS 1 bag ({exc})") from None
        return reader

    def _stream(self, topics: dict[str, Any], wanted: str | None, candidates: tuple[str, ...], what: str) -> _Stream:
        names = (wanted,) if wanted else candidates
        topic = next((t for t in names if t in topics), None)
        if topic is None:
            images = sorted(t for t, info in topics.items() if info.msgtype and info.msgtype.endswith("Image"))
            present = f"its image topics: {', '.join(images)}" if images else f"its topics: {', '.join(sorted(topics)) or 'none'}"
            raise DataError(self.root, f"no {what} topic {names[0]} in the bag (nor {', '.join(names[1:])}; {present})"
                            if len(names) > 1 else f"no {what} topic {names[0]} in the bag ({present})")
        info = topics[topic]
        if info.msgtype not in ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage"):
            raise DataError(self.root, f"{topic} holds {info.msgtype}, not sensor_msgs/Image or CompressedImage")
        if info.msgcount == 0:
            raise DataError(self.root, f"{topic} has no messages")
        return _Stream(topic, list(info.connections), info.msgtype)

    def _scan(self, image_streams: list[_Stream], info_topics: list[str],
              tf_topics: list[str]) -> tuple[dict[str, Any], list[tuple[float, str, str, Any]], str]:
        """One pass over the bag: image stamps, the first message of each camera info topic,
        every tf transform; the image frame is the colour (left) image's ``frame_id``."""
        streams = {s.topic: s for s in image_streams}
        conns = [c for s in streams.values() for c in s.connections]
        conns += [c for t in [*info_topics, *tf_topics] for c in self._reader.topics[t].connections]
        infos: dict[str, Any] = {}
        transforms: list[tuple[float, str, str, Any]] = []
        image_frame = ""
        last: dict[str, tuple[int, int]] = {}
        try:
            for conn, t_ns, raw in self._reader.messages(connections=conns):
                if conn.topic in streams:
                    s = streams[conn.topic]
                    prev = last.get(s.topic)
                    key = (t_ns, prev[1] + 1 if prev and prev[0] == t_ns else 0)
                    last[s.topic] = key
                    msg = self._reader.deserialize(raw, conn.msgtype)
                    if not s.keys:
                        s.encoding = self._check_encoding(s, msg)
                        image_frame = image_frame or (msg.header.frame_id if s is self._rgb else "")
                    stamp = _stamp(msg.header)
                    s.keys.append(key)
                    s.stamps.append(stamp if stamp > 0 else t_ns * 1e-9)  # unstamped: the record time
                elif conn.topic in info_topics:
                    if conn.topic not in infos:
                        infos[conn.topic] = self._reader.deserialize(raw, conn.msgtype)
                else:
                    for tr in self._reader.deserialize(raw, conn.msgtype).transforms:
                        transforms.append((_stamp(tr.header), _frame_id(tr.header.frame_id),
                                           _frame_id(tr.child_frame_id), tr.transform))
        except Exception as exc:  # rosbags raises its own reader / serde errors on damaged data
            if isinstance(exc, DataError):
                raise
            raise DataError(self.root, f"damaged bag ({exc.__class__.__name__}: {exc})") from None
        for s in streams.values():
            self._sort(s)
        return infos, transforms, _frame_id(image_frame)

    def _check_encoding(self, s: _Stream, msg: Any) -> str:
        if s.msgtype.endswith("CompressedImage"):
            if s is self._depth:
                raise DataError(self.root, f"{s.topic}: compressed depth is not supported (use the raw depth topic)")
            return "compressed"
        enc = str(msg.encoding).lower()
        allowed = DEPTH_ENCODINGS if s is self._depth else COLOUR_ENCODINGS
        if enc not in allowed:
            raise DataError(self.root, f"{s.topic}: encoding {msg.encoding!r} is not supported ({', '.join(allowed)})")
        return enc

    def _sort(self, s: _Stream) -> None:
        """Messages by stamp; a repeated stamp (a duplicated message) is dropped with a warning."""
        order = np.argsort(np.asarray(s.stamps), kind="stable")
        stamps = np.asarray(s.stamps)[order]
        keep = np.concatenate([[True], np.diff(stamps) > 0])
        if not keep.all():
            log.warning("%s: %s has %d messages with a repeated stamp; using the first of each",
                        self.root, s.topic, int((~keep).sum()))
        s.keys = [s.keys[i] for i in order[keep]]
        s.stamps = [float(t) for t in stamps[keep]]

    def _associate(self, max_diff: float) -> list[tuple[int, int]]:
        """(colour index, depth index) per frame; depth index -1 without depth."""
        if self._depth is None:
            return [(i, -1) for i in range(len(self._rgb.stamps))]
        i_rgb, i_depth = match_timestamps(self._rgb.stamps, self._depth.stamps, max_diff=max_diff)
        if len(i_rgb) == 0:
            raise DataError(self.root, f"no colour/depth pairs within {max_diff} s: {self._rgb.topic} spans "
                                       f"{self._rgb.stamps[0]:.3f}-{self._rgb.stamps[-1]:.3f}, {self._depth.topic} "
                                       f"{self._depth.stamps[0]:.3f}-{self._depth.stamps[-1]:.3f}")
        if len(i_rgb) < 0.5 * len(self._rgb.stamps):
            log.warning("%s: only %d of %d colour images have a depth image within %.3f s",
                        self.root, len(i_rgb), len(self._rgb.stamps), max_diff)
        return [(int(a), int(b)) for a, b in zip(i_rgb, i_depth)]

    def attach_imu(self, calibration: ImuCalibration, topic: str | None = None) -> None:
        """Set ``imu`` to the bag's ``sensor_msgs/Imu`` readings (``topic``, else the first of
        :data:`IMU_TOPICS`, else the bag's only Imu topic) with ``calibration``, which a bag
        does not carry (an ORB-SLAM3 settings file's IMU.* keys); checked against the frames."""
        topics = self._reader.topics
        imu_topics = sorted(t for t, info in topics.items() if info.msgtype == "sensor_msgs/msg/Imu")
        if topic is None:
            topic = next((t for t in IMU_TOPICS if t in imu_topics), imu_topics[0] if len(imu_topics) == 1 else None)
        if topic is None or topic not in imu_topics:
            raise DataError(self.root, f"no IMU topic {topic or IMU_TOPICS[0]} (sensor_msgs/Imu) in the bag "
                                       f"(its Imu topics: {', '.join(imu_topics) or 'none'})")
        rows: list[tuple[float, float, float, float, float, float, float]] = []
        try:
            for conn, t_ns, raw in self._reader.messages(connections=topics[topic].connections):
                msg = self._reader.deserialize(raw, conn.msgtype)
                stamp = _stamp(msg.header)
                w, a = msg.angular_velocity, msg.linear_acceleration
                rows.append((stamp if stamp > 0 else t_ns * 1e-9, w.x, w.y, w.z, a.x, a.y, a.z))
        except Exception as exc:  # rosbags raises its own reader / serde errors on damaged data
            raise DataError(self.root, f"damaged bag ({exc.__class__.__name__}: {exc})") from None
        data = np.asarray(rows, dtype=np.float64).reshape(-1, 7)
        data = data[np.argsort(data[:, 0], kind="stable")]  # bags are in record order, not stamp order
        keep = np.concatenate([[True], np.diff(data[:, 0]) > 0]) if len(data) else np.zeros(0, bool)
        if not keep.all():
            log.warning("%s: %s has %d messages with a repeated stamp; using the first of each",
                        self.root, topic, int((~keep).sum()))
        data = data[keep]
        samples = ImuSamples(data[:, 0].copy(), data[:, 1:4].copy(), data[:, 4:7].copy())
        check_imu(samples, self.timestamps, f"{self.root} ({topic})")
        self.imu = ImuStream(samples, calibration)

    def _camera(self, option: str | PinholeCamera | None, info: Any) -> PinholeCamera:
        """Intrinsics in the order of the module docstring, with the colour images' size."""
        named = camera_from_folder_name(self.root.with_suffix(""))
        if isinstance(option, PinholeCamera):
            cam = option
        elif option:
            cam = parse_camera_option(option)
        elif (from_info := self._camera_from_info(info)) is not None:
            cam = from_info
            if named is not None and (cam.fx, cam.fy, cam.cx, cam.cy) == OPENNI_DEFAULT and not cam.is_distorted:
                log.info("%s: camera_info holds OpenNI's default intrinsics; using the %s", self.root, named.source)
                cam = named
        elif named is not None:
            cam = named
        else:
            log.warning("%s: no --camera, no camera_info and no known dataset name; using Kinect defaults "
                        "525 525 319.5 239.5", self.root)
            cam = camera_from_values(DEFAULT_CAMERA, "default Kinect intrinsics")
        if cam.width > 0:
            return cam
        width, height = self._image_size()
        return cam.with_image_size(width, height) if width > 0 else cam

    def _camera_from_info(self, info: Any) -> PinholeCamera | None:
        if info is None:
            return None
        k = np.asarray(getattr(info, "K", getattr(info, "k", np.zeros(9))), dtype=np.float64)
        d = [float(v) for v in getattr(info, "D", getattr(info, "d", []))]
        if k.size != 9 or k[0] <= 0 or k[4] <= 0:  # an uncalibrated camera publishes zeros
            return None
        model = str(getattr(info, "distortion_model", "") or "plumb_bob")
        if len(d) > 5 and any(abs(v) > 0 for v in d[5:]):
            raise DataError(self.root, f"camera_info: distortion model {model!r} with {len(d)} coefficients is "
                                       "not supported (plumb_bob k1 k2 p1 p2 k3); give --camera")
        dist = (d + [0.0] * 5)[:5]
        cam = camera_from_values([k[0], k[4], k[2], k[5], *dist], f"camera_info in {self.root.name}")
        w, h = int(getattr(info, "width", 0)), int(getattr(info, "height", 0))
        return cam.with_image_size(w, h) if w > 0 and h > 0 else cam

    def _image_size(self) -> tuple[int, int]:
        rgb = self._decode_colour(self._message(self._rgb, 0), 0)
        return rgb.shape[1], rgb.shape[0]

    # ------------------------------------------------------------------ frames
    @property
    def timestamps(self) -> NDArray[np.float64]:
        return self._timestamps

    def close(self) -> None:
        """Close the bag (also done when the sequence is garbage collected)."""
        self._closer()

    def _message(self, s: _Stream, i: int) -> Any:
        t_ns, rank = s.keys[i]
        try:
            for k, (conn, _, raw) in enumerate(self._reader.messages(connections=s.connections, start=t_ns,
                                                                     stop=t_ns + 1)):
                if k == rank:
                    return self._reader.deserialize(raw, conn.msgtype)
        except Exception as exc:  # damaged chunk
            raise FrameReadError(self.root, f"{s.topic} at t={s.stamps[i]:.6f}: unreadable ({exc})") from None
        raise FrameReadError(self.root, f"{s.topic} at t={s.stamps[i]:.6f}: message not found")

    def load(self, index: int) -> Frame:
        i_rgb, i_depth = self._pairs[index]
        rgb = self._decode_colour(self._message(self._rgb, i_rgb), i_rgb)
        depth = None
        if self._depth is not None:
            depth = self._decode_depth(self._message(self._depth, i_depth), i_depth)
            if depth.shape != rgb.shape[:2]:
                raise DataError(self.root, f"{self._depth.topic}: depth is {depth.shape[1]}x{depth.shape[0]} but "
                                           f"colour is {rgb.shape[1]}x{rgb.shape[0]}")
        return Frame(index, float(self._timestamps[index]), rgb, depth)

    def _rows(self, s: _Stream, i: int, msg: Any, dtype: np.dtype[Any], channels: int) -> NDArray[Any]:
        """The image's pixels ``(H, W, C)`` from a raw Image message (row padding removed)."""
        h, w, step = int(msg.height), int(msg.width), int(msg.step)
        data = np.asarray(msg.data, dtype=np.uint8)
        if h <= 0 or w <= 0 or step < w * channels * dtype.itemsize or data.size < h * step:
            raise FrameReadError(self.root, f"{s.topic} at t={s.stamps[i]:.6f}: {data.size} bytes of data for "
                                            f"{w}x{h}, step {step}")
        rows = data[: h * step].reshape(h, step)[:, : w * channels * dtype.itemsize]
        return rows.copy().view(dtype).reshape(h, w, channels)

    def _decode_colour(self, msg: Any, i: int, stream: _Stream | None = None) -> NDArray[np.uint8]:
        """RGB pixels of a colour (or grey, expanded) message of ``stream`` (default: the colour topic)."""
        s = stream or self._rgb
        if s.encoding == "compressed":
            bgr = cv2.imdecode(np.asarray(msg.data, dtype=np.uint8), cv2.IMREAD_COLOR)
            if bgr is None:
                raise FrameReadError(self.root, f"{s.topic} at t={s.stamps[i]:.6f}: not a decodable image")
            return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
        channels, order = _CHANNELS[s.encoding]
        pixels = self._rows(s, i, msg, np.dtype(np.uint8), channels)
        return np.ascontiguousarray(pixels[..., order])

    def _decode_depth(self, msg: Any, i: int) -> NDArray[np.float32]:
        s = self._depth
        assert s is not None
        endian = ">" if int(msg.is_bigendian) else "<"
        if s.encoding == "32fc1":
            depth = self._rows(s, i, msg, np.dtype(f"{endian}f4"), 1)[..., 0].astype(np.float32)
            depth = np.nan_to_num(depth, nan=0.0, posinf=0.0, neginf=0.0)
            depth[depth < 0] = 0.0
            return depth
        raw = self._rows(s, i, msg, np.dtype(f"{endian}u2"), 1)[..., 0]
        return raw.astype(np.float32) * np.float32(1.0 / self.depth_scale)


# ---------------------------------------------------------------------------- ground truth from tf
def _matrix(transform: Any) -> NDArray[np.float64]:
    t, q = transform.translation, transform.rotation
    return make_pose(quat_to_rot([q.x, q.y, q.z, q.w]), [t.x, t.y, t.z])


def _groundtruth_from_tf(transforms: list[tuple[float, str, str, Any]], camera_frame: str,
                         bag: Path) -> Trajectory | None:
    """The image frame's poses in the root of its tf tree (see the module docstring)."""
    if not transforms:
        return None
    samples: dict[tuple[str, str], list[tuple[float, Any]]] = {}
    parent_of: dict[str, str] = {}
    for stamp, parent, child, tr in transforms:
        samples.setdefault((parent, child), []).append((stamp, tr))
        parent_of[child] = parent
    chain: list[tuple[str, str]] = []
    frame = camera_frame
    while frame in parent_of and len(chain) < len(parent_of):
        chain.append((parent_of[frame], frame))
        frame = parent_of[frame]
    chain.reverse()

    def moves(edge: tuple[str, str]) -> bool:
        return len({t for t, _ in samples[edge]}) > 1

    busiest = max(samples, key=lambda e: len(samples[e]))
    if not moves(busiest):
        return None  # only static transforms: no trajectory
    if not any(moves(e) for e in chain):
        log.warning("%s: the colour images' frame %r is not linked to a moving frame in /tf; ground truth is "
                    "%s -> %s itself", bag, camera_frame, *busiest)
        chain = [busiest]
    driver = max(chain, key=lambda e: len(samples[e]))
    series = {e: sorted(samples[e], key=lambda s: s[0]) for e in chain}
    times = {e: np.array([t for t, _ in series[e]]) for e in chain}
    stamped: list[tuple[float, NDArray[np.float64]]] = []
    for stamp, tr in series[driver]:
        pose = np.eye(4)
        for edge in chain:  # the other edges at their latest value at or before the stamp
            k = 0 if edge == driver else max(int(np.searchsorted(times[edge], stamp, side="right")) - 1, 0)
            pose = pose @ _matrix(tr if edge == driver else series[edge][k][1])
        if not stamped or stamp > stamped[-1][0]:
            stamped.append((stamp, pose))
    return Trajectory.from_poses(stamped, name=f"{bag} /tf {chain[0][0]} -> {chain[-1][1]}")
