"""Trajectory files: TUM, KITTI and EuRoC ground-truth csv.

All readers return a :class:`Trajectory` of camera-to-world poses ``T_wc``. Every problem a
user can cause (missing file, wrong column count, NaN, zero quaternion, time going
backwards) is a :class:`~semslam.errors.TrajectoryError` naming the file and, where there
is one, the line, because a metric computed on a half-parsed file is worse than no metric.

Timestamps may repeat (real ground-truth files do: TUM fr2_desk, EuRoC V1_02) but must not
decrease; association relies on sorted stamps.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from semslam.core.trajectory import Trajectory
from semslam.errors import TrajectoryError
from semslam.geometry.se3 import make_pose, pose_to_tum, quat_to_rot
from semslam.io.text import read_text_lines

Array = NDArray[np.float64]

_SPLIT = re.compile(r"[,\s]+")
FORMATS = ("auto", "tum", "kitti", "euroc")


# --------------------------------------------------------------------------------------
# helpers


def _read_lines(path: Path) -> list[str]:
    return read_text_lines(path, TrajectoryError)


def _data_rows(path: Path, lines: Sequence[str]) -> list[tuple[int, list[str]]]:
    """Non-blank, non-comment lines split on commas/whitespace, with 1-based line numbers."""
    rows = []
    for lineno, raw in enumerate(lines, start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        rows.append((lineno, [p for p in _SPLIT.split(line) if p]))
    return rows


def _parse_rows(
    path: Path,
    rows: list[tuple[int, list[str]]],
    ncols: int,
    what: str,
    at_least: bool = False,
) -> tuple[Array, list[int]]:
    """Parse token rows into an ``(N, ncols)`` float array, checking counts and finiteness."""
    if not rows:
        raise TrajectoryError(path, "no poses found (file is empty or has only comments)")
    values = np.empty((len(rows), ncols))
    linenos = []
    for k, (lineno, parts) in enumerate(rows):
        n = len(parts)
        if n != ncols and not (at_least and n > ncols):
            need = f"at least {ncols}" if at_least else str(ncols)
            raise TrajectoryError(
                path, f"line {lineno}: expected {need} values ({what}), found {n}"
            )
        try:
            values[k] = [float(p) for p in parts[:ncols]]
        except ValueError:
            bad = next(p for p in parts[:ncols] if not _is_float(p))
            raise TrajectoryError(path, f"line {lineno}: {bad!r} is not a number") from None
        if not np.all(np.isfinite(values[k])):
            raise TrajectoryError(path, f"line {lineno}: non-finite value (nan or inf)")
        linenos.append(lineno)
    return values, linenos


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _check_times(path: Path, stamps: Array, linenos: Sequence[int]) -> None:
    """Timestamps must not decrease (repeats are allowed: real ground truth has them)."""
    back = np.flatnonzero(np.diff(stamps) < 0)
    if back.size:
        k = int(back[0]) + 1
        raise TrajectoryError(
            path,
            f"line {linenos[k]}: timestamp {stamps[k]:.6f} is before the previous one "
            f"({stamps[k - 1]:.6f}, line {linenos[k - 1]}); timestamps must not decrease",
        )


def _poses_from_xyz_quat_xyzw(path: Path, xyz: Array, quat: Array, linenos: Sequence[int]) -> Array:
    norms = np.linalg.norm(quat, axis=1)
    zero = np.flatnonzero(norms < 1e-12)
    if zero.size:
        raise TrajectoryError(path, f"line {linenos[int(zero[0])]}: zero-length quaternion")
    return make_pose(quat_to_rot(quat), xyz)


# --------------------------------------------------------------------------------------
# readers / writers


def read_tum(path: str | Path) -> Trajectory:
    """Read a TUM trajectory: ``timestamp tx ty tz qx qy qz qw`` per line.

    ``#`` lines and blank lines are skipped; values may be separated by spaces, tabs or
    commas. Quaternions are normalised (files carry rounding errors), as evo does.
    """
    path = Path(path)
    rows = _data_rows(path, _read_lines(path))
    vals, linenos = _parse_rows(path, rows, 8, "timestamp tx ty tz qx qy qz qw")
    _check_times(path, vals[:, 0], linenos)
    poses = _poses_from_xyz_quat_xyzw(path, vals[:, 1:4], vals[:, 4:8], linenos)
    return Trajectory(vals[:, 0].copy(), poses, str(path))


def write_tum(path: str | Path, traj: Trajectory) -> None:
    """Write ``traj`` as a TUM file (stamps with 6 decimals, poses with 9), readable by evo."""
    path = Path(path)
    rows = pose_to_tum(traj.poses) if len(traj) else np.empty((0, 7))
    lines = ["# timestamp tx ty tz qx qy qz qw"]
    for stamp, row in zip(traj.timestamps, rows):
        lines.append(f"{stamp:.6f} " + " ".join(f"{v:.9f}" for v in row))
    try:
        path.write_text("\n".join(lines) + "\n")
    except OSError as exc:
        raise TrajectoryError(path, f"cannot write ({exc.strerror or exc})") from None


def read_times(path: str | Path) -> tuple[Array, list[int]]:
    """Read a KITTI ``times.txt`` (one time in seconds per line)."""
    path = Path(path)
    rows = _data_rows(path, _read_lines(path))
    vals, linenos = _parse_rows(path, rows, 1, "time in seconds")
    stamps = vals[:, 0].copy()
    _check_times(path, stamps, linenos)
    return stamps, linenos


def read_kitti(path: str | Path, times_path: str | Path | None = None) -> Trajectory:
    """Read a KITTI pose file: the first 3 rows of ``T_wc`` (12 numbers) per line.

    Timestamps come from ``times_path`` (KITTI ``times.txt``, one line per pose) or are the
    frame indices 0, 1, 2, ... when no times file is given. Matrices are kept as written
    (not re-orthonormalised), as evo does, so metrics agree with it bit for bit; a 3x3
    block far from a rotation is rejected, as it means a wrong file rather than rounding.
    """
    path = Path(path)
    rows = _data_rows(path, _read_lines(path))
    vals, linenos = _parse_rows(path, rows, 12, "3x4 pose matrix, row-major")
    poses = np.zeros((len(vals), 4, 4))
    poses[:, :3, :] = vals.reshape(-1, 3, 4)
    poses[:, 3, 3] = 1.0
    rot = poses[:, :3, :3]
    dev = np.abs(np.einsum("nji,njk->nik", rot, rot) - np.eye(3)).max(axis=(1, 2))
    bad = np.flatnonzero((dev > 1e-3) | (np.linalg.det(rot) < 0))
    if bad.size:
        raise TrajectoryError(
            path, f"line {linenos[int(bad[0])]}: the 3x3 block is not a rotation matrix"
        )
    if times_path is None:
        stamps = np.arange(len(vals), dtype=np.float64)
    else:
        times_path = Path(times_path)
        stamps, _ = read_times(times_path)
        if len(stamps) != len(vals):
            raise TrajectoryError(
                times_path,
                f"has {len(stamps)} times but the pose file {path} has {len(vals)} poses",
            )
    return Trajectory(stamps, poses, str(path))


def read_euroc_csv(path: str | Path) -> Trajectory:
    """Read EuRoC ground truth (``state_groundtruth_estimate0/data.csv``).

    Columns: timestamp in ns, p_x, p_y, p_z, q_w, q_x, q_y, q_z, then velocities and biases
    (ignored). Stamps become seconds as ``float(ns) / 1e9``, exactly as evo converts them.
    """
    path = Path(path)
    rows = _data_rows(path, _read_lines(path))
    vals, linenos = _parse_rows(
        path, rows, 8, "timestamp[ns] px py pz qw qx qy qz", at_least=True
    )
    stamps = vals[:, 0] / 1e9
    _check_times(path, stamps, linenos)
    quat_xyzw = vals[:, [5, 6, 7, 4]]
    poses = _poses_from_xyz_quat_xyzw(path, vals[:, 1:4], quat_xyzw, linenos)
    return Trajectory(stamps, poses, str(path))


def detect_format(path: str | Path) -> str:
    """Guess ``tum``, ``kitti`` or ``euroc`` from the extension and the first data line."""
    path = Path(path)
    if path.suffix.lower() == ".csv":
        return "euroc"
    rows = _data_rows(path, _read_lines(path))
    if not rows:
        raise TrajectoryError(path, "no poses found (file is empty or has only comments)")
    lineno, parts = rows[0]
    if len(parts) == 12:
        return "kitti"
    if len(parts) == 8:
        return "tum"
    raise TrajectoryError(
        path,
        f"cannot detect the trajectory format: line {lineno} has {len(parts)} values; "
        "expected 8 (TUM: timestamp tx ty tz qx qy qz qw) or 12 (KITTI: 3x4 matrix)",
    )


def read_trajectory(
    path: str | Path, fmt: str = "auto", times_path: str | Path | None = None
) -> Trajectory:
    """Read a trajectory in any supported format.

    ``fmt="auto"``: ``.csv`` is EuRoC ground truth, otherwise 12 columns is KITTI and 8 is
    TUM. ``times_path`` (KITTI only) gives the pose times.
    """
    path = Path(path)
    if fmt not in FORMATS:
        raise TrajectoryError(path, f"unknown trajectory format {fmt!r}; use one of {FORMATS}")
    if fmt == "auto":
        fmt = detect_format(path)
    if times_path is not None and fmt != "kitti":
        raise TrajectoryError(
            path, f"a times file ({times_path}) only applies to KITTI pose files, this is {fmt}"
        )
    if fmt == "kitti":
        return read_kitti(path, times_path)
    if fmt == "euroc":
        return read_euroc_csv(path)
    return read_tum(path)
