"""The stereo rig of synthetic renders (issue 41): geometry and its ORB-SLAM3 settings file.

The right camera is the left one moved by the baseline ``B`` along the left camera's x axis,
with the same intrinsics and orientation: an ideal rectified pair, so a point at depth ``z``
seen at ``(u, v)`` in the left image lies at ``(u - fx B / z, v)`` in the right one.
The left camera is the RGB-D camera of a TUM render (``groundtruth.txt`` is its pose).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from semslam.errors import DataError

#: Seed stream of the right camera's sensor noise (the left camera's is 5): its own draw.
RIGHT_NOISE_STREAM = 6
#: ORB-SLAM3's close/far split: points closer than ThDepth baselines are "close".
TH_DEPTH = 40.0
#: Files a TUM-like stereo render adds (``camera.yaml``: the ORB-SLAM3 v1.0 settings).
RIGHT_DIR = "rgb_right"
RIGHT_LIST = "rgb_right.txt"
SETTINGS_FILE = "camera.yaml"


def left_to_right(baseline: float) -> NDArray[np.float64]:
    """T_LR, the right camera's pose in the left camera's frame (x right, y down, z ahead)."""
    t = np.eye(4)
    t[0, 3] = baseline
    return t


def settings_yaml(intrinsics: tuple[float, float, float, float], width: int, height: int,
                  fps: float, baseline: float) -> str:
    """An ORB-SLAM3 settings file (``File.version: "1.0"``, ``Camera.type: "Rectified"``).

    Reals are written with a decimal point and integers without: ORB-SLAM3's Settings reads
    each with ``isReal()`` / ``isInt()`` and stops at the wrong one. ``Camera.RGB: 1``: the
    images are RGB (PNG files written as OpenCV's BGR, read back as such)."""
    fx, fy, cx, cy = intrinsics
    lines = [
        "%YAML:1.0",
        "",
        "# semslam synth: an exact rectified stereo pair (no distortion; right = left + b along x)",
        'File.version: "1.0"',
        'Camera.type: "Rectified"',
        f"Camera1.fx: {fx:.6f}",
        f"Camera1.fy: {fy:.6f}",
        f"Camera1.cx: {cx:.6f}",
        f"Camera1.cy: {cy:.6f}",
        f"Camera.width: {width:d}",
        f"Camera.height: {height:d}",
        f"Camera.fps: {int(round(fps)):d}",
        "Camera.RGB: 1",
        f"Stereo.b: {baseline:.9f}",
        f"Stereo.ThDepth: {TH_DEPTH:.1f}",
        "",
        "# ORB-SLAM3 stops on a missing ORB or (with its viewer) Viewer key: its EuRoC stereo values",
        "ORBextractor.nFeatures: 1200",
        "ORBextractor.scaleFactor: 1.2",
        "ORBextractor.nLevels: 8",
        "ORBextractor.iniThFAST: 20",
        "ORBextractor.minThFAST: 7",
        "Viewer.KeyFrameSize: 0.05",
        "Viewer.KeyFrameLineWidth: 1.0",
        "Viewer.GraphLineWidth: 0.9",
        "Viewer.PointSize: 2.0",
        "Viewer.CameraSize: 0.08",
        "Viewer.CameraLineWidth: 3.0",
        "Viewer.ViewpointX: 0.0",
        "Viewer.ViewpointY: -0.7",
        "Viewer.ViewpointZ: -1.8",
        "Viewer.ViewpointF: 500.0",
    ]
    return "\n".join(lines) + "\n"


def write_settings(path: Path, intrinsics: tuple[float, float, float, float], width: int, height: int,
                   fps: float, baseline: float) -> None:
    """Write :func:`settings_yaml` to ``path``; DataError naming it on failure."""
    try:
        path.write_text(settings_yaml(intrinsics, width, height, fps, baseline))
    except OSError as exc:
        raise DataError(path, f"cannot write the stereo settings: {exc.strerror or exc}") from exc
