"""Where a sequence's intrinsics come from, in order of precedence.

1. ``--camera fx,fy,cx,cy[,k1,k2,p1,p2,k3]`` on the command line;
2. a ``calib.txt`` in the sequence folder (one line ``fx fy cx cy [k1 k2 p1 p2 k3]``);
3. the published calibration recognised from the folder name (TUM freiburg1/2/3,
   Bonn RGB-D Dynamic, ICL-NUIM);
4. the Kinect defaults 525 525 319.5 239.5, with a warning.

A rolling shutter's readout time is a camera value too: ``rolling_shutter_ms_from_folder``
reads it from the folder's ``sequence.json`` (``semslam synth`` writes it there).
"""

from __future__ import annotations

import json
import logging
import math
import re
from pathlib import Path

from semslam.errors import ConfigError, DataError
from semslam.geometry.camera import PinholeCamera
from semslam.io.text import read_text_lines

log = logging.getLogger(__name__)

# Published calibrations of the RGB cameras (TUM: "File Formats" page of the benchmark;
# Bonn: the dataset page; ICL-NUIM: its TUM-compatible release, fy sign folded in).
KNOWN_CAMERAS: dict[str, tuple[float, ...]] = {
    "freiburg1": (517.3, 516.5, 318.6, 255.3, 0.2624, -0.9531, -0.0054, 0.0026, 1.1633),
    "freiburg2": (520.9, 521.0, 325.1, 249.7, 0.2312, -0.7849, -0.0033, -0.0001, 0.9172),
    "freiburg3": (535.4, 539.2, 320.1, 247.6),
    "bonn": (542.822841, 542.576870, 315.593520, 237.756098, 0.039903, -0.099343, -0.000730, -0.000144, 0.0),
    "icl": (481.20, 480.00, 319.50, 239.50),
}
DEFAULT_CAMERA = (525.0, 525.0, 319.5, 239.5)
#: Sources of intrinsics semslam guessed (not given by the user): a folder name, the defaults.
FROM_FOLDER_NAME = "calibration (from folder name)"
DEFAULT_SOURCE = "default Kinect intrinsics"

_NAME_PATTERNS: list[tuple[str, str]] = [
    (r"freiburg1|fr1", "freiburg1"),
    (r"freiburg2|fr2", "freiburg2"),
    (r"freiburg3|fr3", "freiburg3"),
    (r"bonn", "bonn"),
    (r"icl|living_?room|office_?room|lr_?kt|of_?kt", "icl"),
]


def camera_from_values(values: list[float] | tuple[float, ...], source: str) -> PinholeCamera:
    """Build a camera from 4 (pinhole) or 9 (with k1 k2 p1 p2 k3) numbers."""
    if len(values) not in (4, 9):
        raise ConfigError(f"{source}: expected 4 numbers (fx fy cx cy) or 9 (with k1 k2 p1 p2 k3), got {len(values)}")
    if not all(math.isfinite(float(v)) for v in values):
        raise ConfigError(f"{source}: every value must be a finite number, got {' '.join(str(v) for v in values)}")
    fx, fy, cx, cy = (float(v) for v in values[:4])
    if fx <= 0 or fy <= 0:
        raise ConfigError(f"{source}: focal lengths must be positive, got fx={fx} fy={fy}")
    dist = tuple(float(v) for v in values[4:9]) if len(values) == 9 else (0.0,) * 5
    return PinholeCamera(fx, fy, cx, cy, dist, source=source)  # type: ignore[arg-type]


def parse_camera_option(text: str) -> PinholeCamera:
    """Parse ``--camera fx,fy,cx,cy[,k1,k2,p1,p2,k3]``."""
    try:
        values = [float(v) for v in re.split(r"[,\s]+", text.strip()) if v]
    except ValueError:
        raise ConfigError(f"--camera {text!r}: not a list of numbers") from None
    return camera_from_values(values, "--camera")


def read_calib_file(path: Path) -> PinholeCamera:
    """Read the first non-comment line of a ``calib.txt``."""
    for line in read_text_lines(path):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        try:
            values = [float(v) for v in re.split(r"[,\s]+", line) if v]
        except ValueError:
            raise DataError(path, f"not a list of numbers: {line!r}") from None
        try:
            return camera_from_values(values, str(path))
        except ConfigError as exc:
            raise DataError(path, str(exc).split(": ", 1)[-1]) from None
    raise DataError(path, "no calibration line (expected 'fx fy cx cy [k1 k2 p1 p2 k3]')")


def camera_from_folder_name(folder: Path) -> PinholeCamera | None:
    """The published calibration if the folder name says which dataset/camera it is."""
    name = folder.resolve().name.lower()
    for pattern, key in _NAME_PATTERNS:
        if re.search(pattern, name):
            return camera_from_values(KNOWN_CAMERAS[key], f"{key} {FROM_FOLDER_NAME}")
    return None


def resolve_camera(folder: Path, camera_option: str | PinholeCamera | None = None) -> PinholeCamera:
    """Intrinsics for a sequence folder, following the precedence in the module docstring."""
    if isinstance(camera_option, PinholeCamera):
        return camera_option
    if camera_option:
        return parse_camera_option(camera_option)
    calib = folder / "calib.txt"
    if calib.exists():
        return read_calib_file(calib)
    cam = camera_from_folder_name(folder)
    if cam is not None:
        return cam
    log.warning(
        "%s: no --camera, no calib.txt and no known dataset name; using Kinect defaults 525 525 319.5 239.5",
        folder,
    )
    return camera_from_values(DEFAULT_CAMERA, DEFAULT_SOURCE)


def check_principal_point(camera: PinholeCamera) -> None:
    """ConfigError when intrinsics the user gave (``--camera``, a calib.txt) put the principal
    point outside the image they are used with (size known: ``camera.width > 0``); a guessed
    calibration is left alone (a resized TUM copy still runs, with the published values)."""
    w, h = camera.width, camera.height
    if w <= 0 or camera.source.endswith(FROM_FOLDER_NAME) or camera.source == DEFAULT_SOURCE:
        return
    if not (0.0 <= camera.cx <= w and 0.0 <= camera.cy <= h):
        raise ConfigError(f"{camera.source}: principal point cx={camera.cx:g} cy={camera.cy:g} lies outside the "
                          f"{w}x{h} image (expected 0 <= cx <= {w}, 0 <= cy <= {h})")


def check_depth_scale(value: float | None) -> float | None:
    """``--depth-scale``: depth units per metre, a finite number > 0 (None: the config's)."""
    if value is not None and not (math.isfinite(value) and value > 0):
        raise ConfigError(f"--depth-scale: expected depth units per metre, a number > 0 (TUM 5000), got {value:g}")
    return value


def rolling_shutter_ms_from_folder(folder: Path) -> float | None:
    """The rolling-shutter readout (ms, top row to bottom row) a sequence folder states:
    ``rolling_shutter_ms`` at the top level of its ``sequence.json`` or under its ``config``
    (where ``semslam synth`` writes its render settings); None where it states none."""
    path = Path(folder) / "sequence.json"
    if not path.is_file():
        return None
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DataError(path, f"not readable as JSON ({exc})") from None
    if not isinstance(doc, dict):
        return None
    value = doc.get("rolling_shutter_ms")
    if value is None and isinstance(doc.get("config"), dict):
        value = doc["config"].get("rolling_shutter_ms")
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
        raise DataError(path, f"rolling_shutter_ms: expected a number >= 0, got {value!r}")
    return float(value)
