"""A Rerun recording of a run (rerun-sdk 0.23): each frame's image, dynamic mask, keypoints
and camera pose as it is tracked; at the end the final trajectory, the map points and the
semantic cloud. Saved to an ``.rrd`` file (``rerun FILE.rrd`` opens it) and/or streamed to a
live viewer.

Entity paths (the world is SLAM's: the first camera, x right, y down, z forward):

    world                           view coordinates RDF (static)
    world/camera                    Transform3D, camera to world (T_wc), per frame
    world/camera/image              Pinhole (static) + the colour image (JPEG), per frame
    world/camera/image/dynamic      SegmentationImage: 1 = dynamic (red), 0 = static (clear)
    world/camera/image/depth        DepthImage in metres (when given)
    world/camera/image/keypoints    Points2D: green = static, red = removed as dynamic
    world/trajectory                LineStrips3D: the final (optimised) trajectory (static)
    world/map_points                Points3D: the tracker's map points (static)
    world/semantic_cloud            Points3D in their colours (static)
    world/semantic_cloud/classes    Points3D with class ids and an annotation context (static)

Timelines: ``frame`` (sequence: the frame index) and ``time`` (the frame's timestamp).
Rerun is imported when a recorder is created, so it is needed only by runs that record.
"""

from __future__ import annotations

import uuid
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from semslam.errors import ConfigError
from semslam.geometry.camera import PinholeCamera
from semslam.viz.map_views import read_cloud
from semslam.viz.palette import class_table

STATIC_COLOUR = (40, 200, 60)
DYNAMIC_COLOUR = (230, 40, 40)
MAP_POINT_COLOUR = (150, 150, 150)
TRAJECTORY_COLOUR = (255, 170, 0)


def _import_rerun() -> Any:
    try:
        import rerun as rr
    except ImportError as exc:
        raise ConfigError(f"--rerun / --rerun-spawn need the rerun-sdk package (rerun-sdk==0.23.1): {exc}") from None
    return rr


def _rgba(colour: tuple[int, ...]) -> int:
    r, g, b, a = (*colour, 255)[:4]
    return (int(r) << 24) | (int(g) << 16) | (int(b) << 8) | int(a)


def _annotation_context(rr: Any, classes: Mapping[int, tuple[str, tuple[int, ...]]]) -> Any:
    """``rr.AnnotationContext`` of id -> (name, colour), given as the Arrow array the SDK
    itself builds: rerun-sdk 0.23's ``ClassId.__array__`` passes numpy 2's ``copy=`` to
    ``np.asarray``, which numpy 1.26 (pinned here) refuses, so the SDK's own conversion of
    class descriptions fails (a RerunWarning, nothing logged)."""
    import pyarrow as pa

    rows = [{"class_id": int(i), "class_description": {"info": {"id": int(i), "label": name, "color": _rgba(colour)},
                                                       "keypoint_annotations": [], "keypoint_connections": []}}
            for i, (name, colour) in classes.items()]
    return rr.AnnotationContext(pa.array([rows], type=rr.components.AnnotationContextBatch._ARROW_DATATYPE))


class RerunRecorder:
    """Logs a run to Rerun. ``path``: an ``.rrd`` file written as the run goes (complete once
    ``close`` is called); ``spawn``: also stream to a viewer started now."""

    def __init__(self, application_id: str = "semslam", path: str | Path | None = None, spawn: bool = False,
                 jpeg_quality: int | None = 85) -> None:
        if path is None and not spawn:
            raise ConfigError("a Rerun recording needs a file (--rerun FILE.rrd) or a viewer (--rerun-spawn)")
        rr = self.rr = _import_rerun()
        self.jpeg_quality = jpeg_quality
        self._camera: PinholeCamera | None = None
        self._image_size: tuple[int, int] | None = None
        self.frames_logged = 0
        # One stream per sink (0.23 has no multi-sink stream); one recording id, so the file
        # and the live viewer show the same recording.
        recording_id = str(uuid.uuid4())
        self._streams: list[Any] = []
        if path is not None:
            path = Path(path)
            if path.suffix != ".rrd":
                raise ConfigError(f"--rerun {path}: expected a .rrd file name")
            path.parent.mkdir(parents=True, exist_ok=True)
            stream = rr.RecordingStream(application_id, recording_id=recording_id)
            stream.save(path)
            self._streams.append(stream)
        if spawn:
            stream = rr.RecordingStream(application_id, recording_id=recording_id)
            stream.spawn()
            self._streams.append(stream)
        self.path = path
        self._log("world", rr.ViewCoordinates.RDF, static=True)
        self._log("world/camera/image/dynamic",
                  _annotation_context(rr, {0: ("static", (0, 0, 0, 0)), 1: ("dynamic", DYNAMIC_COLOUR)}), static=True)

    # ------------------------------------------------------------------ per frame
    def log_frame(self, index: int, timestamp: float, rgb: NDArray[np.uint8],
                  dynamic_mask: NDArray[np.bool_] | None = None, keypoints_xy: NDArray[np.floating] | None = None,
                  keypoint_static: NDArray[np.bool_] | None = None, T_wc: NDArray[np.float64] | None = None,
                  camera: PinholeCamera | None = None, depth: NDArray[np.float32] | None = None) -> None:
        """One frame on the ``frame`` and ``time`` timelines. ``T_wc`` None (not tracked)
        leaves the camera where it was; keypoints are in image pixels as detected."""
        rr = self.rr
        for s in self._streams:
            s.set_time("frame", sequence=int(index))
            s.set_time("time", timestamp=float(timestamp))
        h, w = rgb.shape[:2]
        if camera is not None and (camera != self._camera or self._image_size != (w, h)):
            self._camera, self._image_size = camera, (w, h)
            self._log("world/camera/image", rr.Pinhole(image_from_camera=camera.K, resolution=[w, h]), static=True)
        if T_wc is not None:
            self._log("world/camera", rr.Transform3D(translation=T_wc[:3, 3], mat3x3=T_wc[:3, :3]))
        image = rr.Image(rgb)
        self._log("world/camera/image", image.compress(self.jpeg_quality) if self.jpeg_quality else image)
        if dynamic_mask is not None:
            self._log("world/camera/image/dynamic", rr.SegmentationImage(dynamic_mask.astype(np.uint8), opacity=0.45))
        if depth is not None:
            self._log("world/camera/image/depth", rr.DepthImage(depth, meter=1.0))
        if keypoints_xy is not None:
            xy = np.asarray(keypoints_xy, np.float32).reshape(-1, 2)
            static = np.ones(len(xy), bool) if keypoint_static is None else np.asarray(keypoint_static, bool)
            colours = np.where(static[:, None], STATIC_COLOUR, DYNAMIC_COLOUR).astype(np.uint8)
            self._log("world/camera/image/keypoints", rr.Points2D(xy, colors=colours, radii=2.0))
        self.frames_logged += 1

    # ------------------------------------------------------------------ at the end (static)
    def log_trajectory(self, positions: NDArray[np.floating]) -> None:
        """Camera positions (N, 3) of the final trajectory, as one line strip."""
        if len(positions) >= 2:
            self._log("world/trajectory", self.rr.LineStrips3D([np.asarray(positions, np.float32)],
                                                               colors=[TRAJECTORY_COLOUR], radii=0.004), static=True)

    def log_map_points(self, xyz: NDArray[np.floating]) -> None:
        self._log("world/map_points", self.rr.Points3D(np.asarray(xyz, np.float32), colors=[MAP_POINT_COLOUR],
                                                       radii=0.006), static=True)

    def log_semantic_cloud(self, xyz: NDArray[np.floating], rgb: NDArray[np.uint8],
                           labels: NDArray[np.integer] | None = None,
                           class_colours: Mapping[int, tuple[str, tuple[int, int, int]]] | None = None) -> None:
        """The cloud in its colours; with ``labels`` also the same points by class (id ->
        (name, colour) from ``class_colours``, hover shows the class name)."""
        rr = self.rr
        xyz = np.asarray(xyz, np.float32)
        self._log("world/semantic_cloud", rr.Points3D(xyz, colors=np.asarray(rgb, np.uint8), radii=0.008), static=True)
        if labels is not None:
            self._log("world/semantic_cloud/classes", _annotation_context(rr, class_colours or {}), static=True)
            self._log("world/semantic_cloud/classes",
                      rr.Points3D(xyz, class_ids=np.asarray(labels, np.uint16), radii=0.008), static=True)

    def log_map_dir(self, map_dir: str | Path) -> None:
        """The semantic cloud of a run's map folder (``semantic_cloud.ply``), if there is one."""
        path = Path(map_dir) / "semantic_cloud.ply"
        if path.is_file():
            cloud = read_cloud(path)
            table = class_table(cloud.labels) if cloud.labels is not None else None
            self.log_semantic_cloud(cloud.xyz, cloud.rgb, cloud.labels, table)

    def close(self) -> None:
        """Flush every sink (the ``.rrd`` file is complete afterwards); safe to call twice."""
        for s in self._streams:
            s.flush(blocking=True)
            s.disconnect()
        self._streams = []

    def _log(self, entity: str, archetype: Any, static: bool = False) -> None:
        for s in self._streams:
            s.log(entity, archetype, static=static)
