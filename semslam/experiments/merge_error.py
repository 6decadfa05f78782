"""How far a run's merges are from the truth on a render (ground truth and depth at hand).

A merge is judged where it matters for the welded maps: how far its ``T12`` (kf camera <-
cand camera, as ``stats.json``'s ``merge_checks`` record it) puts the scene kf sees (kf's
depth image, every ``STEP``-th pixel) from where the true relative pose puts it (median),
and the rotation error. The camera centres' distance would also count the turn-versus-slide
ambiguity of a narrow view (0.9 deg about a scene 3 m away moves the centre 5 cm and the
scene 1 cm). Used by ``tests/test_merge_verification.py`` and
``benchmarks/robustness_split.py``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from semslam.geometry.se3 import invert
from semslam.io.calibration import read_calib_file
from semslam.io.images import read_depth
from semslam.io.sequence import read_file_list
from semslam.core.trajectory import Trajectory
from semslam.io.trajectory import read_tum
from semslam.slam.orb.merge_check import pose_difference, scene_shift

#: A merge further off than this at the weld is wrong (issue 38).
WRONG_M, WRONG_DEG = 0.05, 2.0
#: Pixel step of the depth image sampled for the scene.
STEP = 8
#: Depth units per metre of the renders (TUM's).
DEPTH_SCALE = 5000.0


def true_T12(gt: Trajectory, t_kf: float, t_cand: float) -> NDArray[np.float64]:
    """kf camera <- cand camera from ground truth (nearest poses in time)."""
    def pose(t: float) -> NDArray[np.float64]:
        return gt.poses[int(np.argmin(np.abs(gt.timestamps - t)))]
    return invert(pose(t_kf)) @ pose(t_cand)


def weld_error(seq: Path, t_kf: float, T12: NDArray[np.float64], true: NDArray[np.float64]) -> tuple[float, float]:
    """(metres, degrees): the median distance between where ``T12`` and ``true`` put the
    scene kf sees, and the rotation error."""
    depth = read_file_list(seq / "depth.txt")
    j = int(np.argmin([abs(e.timestamp - t_kf) for e in depth]))
    z = read_depth(depth[j].path, DEPTH_SCALE)[::STEP, ::STEP].astype(np.float64)
    cam = read_calib_file(seq / "calib.txt")
    v, u = np.nonzero(z > 0)
    zz = z[v, u]
    pts = np.stack([(u * STEP - cam.cx) * zz / cam.fx, (v * STEP - cam.cy) * zz / cam.fy, zz], 1)
    return scene_shift(invert(T12), invert(true), pts), pose_difference(T12, true)[1]


def merge_errors(seq: Path, stats: dict[str, Any]) -> list[tuple[float, float]]:
    """(metres, degrees) at the weld of every merge a run made (``stats.json`` of a run on
    the render ``seq``)."""
    gt = read_tum(seq / "groundtruth.txt")
    errors = []
    for c in stats.get("merge_checks", []):
        if c["result"] == "merged":
            T12 = np.array(c["T12"], np.float64).reshape(4, 4)
            errors.append(weld_error(seq, c["kf_time"], T12, true_T12(gt, c["kf_time"], c["cand_time"])))
    return errors


def is_wrong(error: tuple[float, float]) -> bool:
    return error[0] > WRONG_M or error[1] > WRONG_DEG
