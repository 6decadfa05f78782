"""IMU recordings: EuRoC / TUM-VI ``imu0/data.csv``, the calibrations that go with them, and
the checks a recording must pass before its readings are handed to the frames.

Calibration sources, each an :class:`~semslam.core.imu.ImuCalibration` (noise and ``T_bc``,
cam0 -> IMU/body, x_B = T_bc x_C):

- EuRoC: ``imu0/sensor.yaml`` (noise densities, random walks, ``rate_hz``, ``T_BS``) and
  cam0's ``sensor.yaml`` (``T_BS``): ``T_bc = inv(T_BS_imu) @ T_BS_cam0``;
- TUM-VI: Kalibr's ``dso/camchain.yaml`` (``cam0.T_cam_imu``: ``T_bc = inv(T_cam_imu)``) and
  ``dso/imu_config.yaml`` (noise, ``update_rate``);
- an ORB-SLAM3 settings YAML: ``IMU.NoiseGyro``, ``IMU.NoiseAcc``, ``IMU.GyroWalk``,
  ``IMU.AccWalk``, ``IMU.Frequency`` and ``IMU.T_b_c1`` (older files: ``Tbc``);
- plain numbers (a config section).

Bad input is one :class:`~semslam.errors.DataError` line naming the file and the key or line.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from semslam.core.imu import ImuCalibration, ImuNoise, ImuSamples, ImuStream
from semslam.errors import ConfigError, DataError
from semslam.io.stereo_calibration import SettingsFile, check_pose, load_yaml, numbers
from semslam.io.text import read_text_lines

if TYPE_CHECKING:
    from semslam.io.sequence import Sequence

log = logging.getLogger(__name__)

Array = NDArray[np.float64]

#: A gap inside the frames' span longer than this many sample periods is an error: the
#: preintegration across it would hold one reading for too long.
MAX_GAP_PERIODS = 10.0

# ---------------------------------------------------------------------------- readings


def read_euroc_imu(csv: str | Path) -> ImuSamples:
    """An EuRoC / TUM-VI ``imu0/data.csv``: ``timestamp [ns], w_x, w_y, w_z [rad/s], a_x, a_y,
    a_z [m/s^2]`` per line, ``#`` comments skipped. Times in seconds as the image lists have
    them (``float(ns) / 1e9``), so a reading and an image at one nanosecond stamp compare
    equal. A malformed line, a time not after the previous one or a value that is not finite
    is a DataError naming the line."""
    path = Path(csv)
    stamps: list[int] = []
    values: list[list[float]] = []
    for lineno, raw in enumerate(read_text_lines(path), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        parts = [p.strip() for p in line.split(",")]
        if len(parts) != 7 or not parts[0].isdigit():
            raise DataError(path, f"line {lineno}: expected 'timestamp_ns,w_x,w_y,w_z,a_x,a_y,a_z', "
                                  f"got {line[:80]!r}")
        try:
            row = [float(v) for v in parts[1:]]
        except ValueError:
            raise DataError(path, f"line {lineno}: a reading is not a number ({line[:80]!r})") from None
        if not all(math.isfinite(v) for v in row):
            raise DataError(path, f"line {lineno}: a reading is not finite ({line[:80]!r})")
        stamp = int(parts[0])
        if stamps and stamp <= stamps[-1]:
            raise DataError(path, f"line {lineno}: timestamp {parts[0]} is not after the previous one; "
                                  "timestamps must increase")
        stamps.append(stamp)
        values.append(row)
    if not stamps:
        raise DataError(path, "no IMU readings (only comments or blank lines)")
    data = np.asarray(values, dtype=np.float64)
    t = np.asarray(stamps, dtype=np.int64).astype(np.float64) / 1e9  # = float(ns) / 1e9, as read_euroc_list
    return ImuSamples(t, np.ascontiguousarray(data[:, :3]), np.ascontiguousarray(data[:, 3:]))


def check_imu(samples: ImuSamples, frame_times: NDArray[np.float64], source: str | Path) -> None:
    """A recording fit to give each frame its readings: not empty, finite, strictly increasing
    times, covering the frames (within one sample period at either end) and without a gap of
    more than :data:`MAX_GAP_PERIODS` periods inside the frames' span. Each problem is one
    DataError naming ``source`` and where (times in seconds, frame indices)."""
    t = np.asarray(samples.t, dtype=np.float64)
    if len(t) == 0:
        raise DataError(source, "no IMU readings")
    bad = np.flatnonzero(~(np.isfinite(t) & np.isfinite(samples.gyro).all(axis=1)
                           & np.isfinite(samples.acc).all(axis=1)))
    if bad.size:
        k = int(bad[0])
        raise DataError(source, f"IMU reading {k} (t = {t[k]:.6f} s) is not finite ({bad.size} such readings)")
    steps = np.diff(t)
    back = np.flatnonzero(steps <= 0)
    if back.size:
        k = int(back[0]) + 1
        raise DataError(source, f"IMU reading {k} at {t[k]:.9f} s is not after the previous one "
                                f"({t[k - 1]:.9f} s); times must increase")
    frames = np.asarray(frame_times, dtype=np.float64)
    if len(frames) == 0:
        return
    period = float(np.median(steps)) if len(steps) else 0.0
    early = np.flatnonzero(frames < t[0] - period)
    if early.size:
        raise DataError(source, f"the IMU starts at {t[0]:.6f} s, {t[0] - frames[0]:.3f} s after the first frame: "
                                f"{_frames(early, 'comes', 'come')} before its first reading")
    late = np.flatnonzero(frames > t[-1] + period)
    if late.size:
        raise DataError(source, f"the IMU ends at {t[-1]:.6f} s, {frames[-1] - t[-1]:.3f} s before the last frame: "
                                f"{_frames(late, 'comes', 'come')} after its last reading")
    if period > 0:
        # The part of each gap inside the frames' span: the recording may pause before or after them.
        inside = np.minimum(t[1:], frames[-1]) - np.maximum(t[:-1], frames[0])
        gaps = np.flatnonzero(inside > MAX_GAP_PERIODS * period)
        if gaps.size:
            k = int(gaps[0])
            hit = np.flatnonzero((frames > t[k]) & (frames < t[k + 1]))
            within = f"; {_frames(hit, 'falls', 'fall')} in it" if hit.size else ""
            raise DataError(source, f"a gap of {steps[k]:.3f} s in the IMU readings between {t[k]:.6f} and "
                                    f"{t[k + 1]:.6f} s (the rate is {1.0 / period:.0f} Hz; at most "
                                    f"{MAX_GAP_PERIODS:g} periods allowed){within}")


def _frames(indices: NDArray[np.intp], verb: str, plural: str) -> str:
    """'frame 3 comes' or 'frames 0-4 (5 frames) come' for consecutive indices, as the checks name them."""
    if len(indices) == 1:
        return f"frame {int(indices[0])} {verb}"
    return f"frames {int(indices[0])}-{int(indices[-1])} ({len(indices)} frames) {plural}"


# ---------------------------------------------------------------------------- calibration


def _noise(path: Path, doc: Mapping[str, object], keys: tuple[str, str, str, str, str]) -> ImuNoise:
    """ImuNoise from a mapping's five keys (gyro density, acc density, gyro walk, acc walk, rate)."""
    values = []
    for key in keys:
        if key not in doc:
            raise DataError(path, f"no {key} (the IMU's noise needs {', '.join(keys)})")
        value = numbers(path, key, [doc[key]], 1)[0]
        if value < 0 or (key == keys[4] and value <= 0):
            raise DataError(path, f"{key}: expected a number {'> 0' if key == keys[4] else '>= 0'}, got {value:g}")
        values.append(value)
    return ImuNoise(gyro_noise_density=values[0], acc_noise_density=values[1], gyro_random_walk=values[2],
                    acc_random_walk=values[3], rate_hz=values[4])


def _t_bs(path: Path) -> Array:
    """A EuRoC sensor.yaml's ``T_BS``: the sensor's pose in the body frame."""
    doc = load_yaml(path)
    if "T_BS" not in doc:
        raise DataError(path, "no T_BS (the sensor's pose in the body frame)")
    pose = np.asarray(numbers(path, "T_BS", doc["T_BS"], 16)).reshape(4, 4)
    check_pose(path, "T_BS", pose)
    return pose


EUROC_NOISE_KEYS = ("gyroscope_noise_density", "accelerometer_noise_density", "gyroscope_random_walk",
                    "accelerometer_random_walk", "rate_hz")
KALIBR_NOISE_KEYS = ("gyroscope_noise_density", "accelerometer_noise_density", "gyroscope_random_walk",
                     "accelerometer_random_walk", "update_rate")


def read_euroc_imu_calibration(mav0: str | Path) -> ImuCalibration:
    """An EuRoC ``mav0`` folder's IMU: noise from ``imu0/sensor.yaml``, and where cam0 sits on
    it, ``T_bc = inv(T_BS_imu) @ T_BS_cam0`` (both ``T_BS`` place a sensor in the body frame;
    EuRoC's body frame is the IMU's, so ``T_BS_imu`` is the identity there)."""
    mav0 = Path(mav0)
    imu_yaml = mav0 / "imu0" / "sensor.yaml"
    noise = _noise(imu_yaml, load_yaml(imu_yaml), EUROC_NOISE_KEYS)
    t_bs_imu = _t_bs(imu_yaml)
    t_bs_cam = _t_bs(mav0 / "cam0" / "sensor.yaml")
    return ImuCalibration(noise, np.linalg.inv(t_bs_imu) @ t_bs_cam)


def read_kalibr_imu_calibration(camchain: str | Path, imu_config: str | Path) -> ImuCalibration:
    """TUM-VI's Kalibr files (``dso/camchain.yaml``, ``dso/imu_config.yaml``): ``cam0.T_cam_imu``
    maps IMU points into cam0, so ``T_bc = inv(T_cam_imu)``."""
    camchain, imu_config = Path(camchain), Path(imu_config)
    noise = _noise(imu_config, load_yaml(imu_config), KALIBR_NOISE_KEYS)
    cam0 = load_yaml(camchain).get("cam0")
    if not isinstance(cam0, dict) or "T_cam_imu" not in cam0:
        raise DataError(camchain, "no cam0.T_cam_imu (Kalibr's pose of the IMU in cam0's frame, 4x4)")
    rows = cam0["T_cam_imu"]
    flat = [v for row in rows for v in row] if isinstance(rows, list) and all(isinstance(r, list) for r in rows) else rows
    t_cam_imu = np.asarray(numbers(camchain, "cam0.T_cam_imu", flat, 16)).reshape(4, 4)
    check_pose(camchain, "cam0.T_cam_imu", t_cam_imu)
    return ImuCalibration(noise, np.linalg.inv(t_cam_imu))


#: ORB-SLAM3's IMU keys, in ImuNoise's order.
ORBSLAM3_NOISE_KEYS = ("IMU.NoiseGyro", "IMU.NoiseAcc", "IMU.GyroWalk", "IMU.AccWalk", "IMU.Frequency")


def read_orbslam3_imu(path: str | Path) -> ImuCalibration:
    """An ORB-SLAM3 settings YAML's IMU (``IMU.*`` keys; ``IMU.T_b_c1``, or ``Tbc`` in files
    before v1.0: cam1's pose in the body frame, an ``!!opencv-matrix`` 4x4)."""
    s = SettingsFile(Path(path))
    why = "an inertial ORB-SLAM3 settings file has IMU.NoiseGyro, NoiseAcc, GyroWalk, AccWalk and Frequency"
    values = [s.real(key, why) for key in ORBSLAM3_NOISE_KEYS]
    for key, value in zip(ORBSLAM3_NOISE_KEYS, values):
        if value < 0 or (key == "IMU.Frequency" and value <= 0):
            raise DataError(s.path, f"{key}: expected a number {'> 0' if key == 'IMU.Frequency' else '>= 0'}, "
                                    f"got {value:g}")
    key = "Tbc" if s.fs.getNode("IMU.T_b_c1").empty() and not s.fs.getNode("Tbc").empty() else "IMU.T_b_c1"
    t_bc = s.matrix(key, "the camera's pose in the IMU (body) frame, 4x4", (4, 4))
    check_pose(s.path, key, t_bc)
    noise = ImuNoise(gyro_noise_density=values[0], acc_noise_density=values[1], gyro_random_walk=values[2],
                     acc_random_walk=values[3], rate_hz=values[4])
    return ImuCalibration(noise, t_bc)


def orbslam3_has_imu(path: str | Path) -> bool:
    """Whether an ORB-SLAM3 settings YAML describes an IMU (has ``IMU.NoiseGyro``)."""
    return not SettingsFile(Path(path)).fs.getNode("IMU.NoiseGyro").empty()


def imu_calibration_from_values(values: Mapping[str, object], where: str = "imu") -> ImuCalibration:
    """An IMU calibration given as plain numbers (a config section ``where``): ImuNoise's
    fields (``rate_hz`` optional) and ``T_bc`` (optional, 16 numbers or 4 rows of 4; default
    the identity). Bad values are a ConfigError naming ``where.key``."""
    fields = ("gyro_noise_density", "acc_noise_density", "gyro_random_walk", "acc_random_walk", "rate_hz")
    unknown = sorted(set(values) - set(fields) - {"T_bc"})
    if unknown:
        raise ConfigError(f"{where}.{unknown[0]}: unknown key (expected {', '.join(fields)}, T_bc)")
    numbers_: dict[str, float] = {}
    for key in fields:
        if key not in values:
            if key == "rate_hz":
                continue
            raise ConfigError(f"{where}.{key}: missing (the IMU's noise needs {', '.join(fields[:4])})")
        value = values[key]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ConfigError(f"{where}.{key}: expected a finite number, got {value!r}")
        if value < 0 or (key == "rate_hz" and value <= 0):
            raise ConfigError(f"{where}.{key}: expected a number {'> 0' if key == 'rate_hz' else '>= 0'}, got {value!r}")
        numbers_[key] = float(value)
    t_bc = np.eye(4)
    if values.get("T_bc") is not None:
        try:
            t_bc = np.asarray(values["T_bc"], dtype=np.float64).reshape(4, 4)
        except (TypeError, ValueError):
            raise ConfigError(f"{where}.T_bc: expected 16 numbers (a 4x4 matrix), got {values['T_bc']!r}"[:200]) from None
        rot = t_bc[:3, :3]
        if (not np.all(np.isfinite(t_bc)) or np.abs(rot.T @ rot - np.eye(3)).max() > 1e-3
                or np.linalg.det(rot) < 0 or not np.allclose(t_bc[3], [0, 0, 0, 1])):
            raise ConfigError(f"{where}.T_bc: not a rigid transform (rotation not orthonormal or last row not 0 0 0 1)")
    return ImuCalibration(ImuNoise(**numbers_), t_bc)


# ---------------------------------------------------------------------------- finding a recording


def imu_folder(root: str | Path) -> Path | None:
    """The EuRoC-layout folder holding ``imu0`` under a sequence folder (``root/mav0`` or
    ``root``), else None."""
    root = Path(root)
    return next((cand for cand in (root / "mav0", root) if (cand / "imu0").is_dir()), None)


def open_imu(root: str | Path) -> ImuStream | None:
    """The IMU recording of an EuRoC or TUM-VI sequence folder (the folder holding ``mav0``,
    or ``mav0`` itself), None without an ``imu0`` folder. The calibration is TUM-VI's Kalibr
    files (``dso/`` beside ``mav0``) where they exist, else EuRoC's ``imu0/sensor.yaml``; a
    recording with neither is not used (a warning: visual-only runs need none)."""
    mav0 = imu_folder(root)
    if mav0 is None:
        return None
    csv = mav0 / "imu0" / "data.csv"
    if not csv.is_file():
        raise DataError(csv, "file not found (an imu0 folder holds the IMU's readings in data.csv)")
    dso = next((d for d in (mav0.parent / "dso", mav0 / "dso") if (d / "camchain.yaml").is_file()), None)
    if dso is not None:
        calibration = read_kalibr_imu_calibration(dso / "camchain.yaml", dso / "imu_config.yaml")
    elif (mav0 / "imu0" / "sensor.yaml").is_file():
        calibration = read_euroc_imu_calibration(mav0)
    else:
        log.warning("%s: no IMU calibration (imu0/sensor.yaml, or TUM-VI's dso/camchain.yaml + imu_config.yaml); "
                    "the IMU is not used", mav0 / "imu0")
        return None
    return ImuStream(read_euroc_imu(csv), calibration)


def attach_imu(sequence: Sequence, root: str | Path) -> None:
    """Set ``sequence.imu`` to the folder's IMU recording (checked against the sequence's
    frame times), if it has one."""
    stream = open_imu(root)
    if stream is None:
        return
    mav0 = imu_folder(root)
    assert mav0 is not None
    check_imu(stream.samples, sequence.timestamps, mav0 / "imu0" / "data.csv")
    sequence.imu = stream
