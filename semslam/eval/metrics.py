"""Trajectory error metrics: absolute trajectory error (ATE) and relative pose error (RPE).

Definitions follow Sturm et al., "A Benchmark for the Evaluation of RGB-D SLAM Systems"
(IROS 2012), and the numbers match evo 1.38 (``evo_ape`` / ``evo_rpe``) to floating-point
rounding for the same settings:

* association: :func:`semslam.io.association.associate` (evo's nearest-time sync);
* alignment: Umeyama on positions, applied to the estimate (SE(3) or Sim(3));
* ATE: ``||p_est_aligned - p_gt||`` per associated pose (evo ``--pose_relation trans_part``);
* RPE: ``E_ij = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)``, translational error ``||trans(E)||`` in
  metres, rotational error ``angle(E)`` in degrees (evo ``angle_deg``). Pairs ``(i, j)`` are
  chosen on the (aligned) estimate unless ``pairs_from_reference``: consecutive or all
  pairs ``delta`` frames apart, or ``delta`` metres of travelled path apart, as evo does.
  ``delta_unit="seconds"`` (not in evo) follows TUM ``evaluate_rpe.py --fixed_delta``: for
  every pose ``i`` the pose ``j`` whose stamp is closest to ``t_i + delta``; pairs ending on
  the last pose are dropped (there the target time may lie past the end), as are
  ``j <= i`` (delta shorter than half a frame). ``all_pairs`` has no effect in seconds.
* statistics: rmse, mean, median, std (population), min, max, sse, like evo's
  ``StatisticsType``.

Everything here is a pure function of arrays/trajectories: no file access.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from semslam.errors import EvalError
from semslam.io.association import associate
from semslam.geometry.alignment import apply_sim3, sim3_matrix, umeyama
from semslam.geometry.se3 import invert
from semslam.core.trajectory import Trajectory

Array = NDArray[np.float64]
IntArray = NDArray[np.intp]

STAT_NAMES = ("rmse", "mean", "median", "std", "min", "max", "sse")
ALIGN_MODES = ("se3", "sim3", "none")
DELTA_UNITS = ("frames", "seconds", "meters")
MIN_POSES = 3


def error_stats(errors: ArrayLike) -> dict[str, float]:
    """Summary statistics of an error array, named as evo's ``StatisticsType`` values."""
    e = np.asarray(errors, dtype=np.float64).reshape(-1)
    if e.size == 0:
        raise EvalError("no errors to summarise (empty error array)")
    sq = e * e
    return {
        "rmse": float(np.sqrt(np.mean(sq))),
        "mean": float(np.mean(e)),
        "median": float(np.median(e)),
        "std": float(np.std(e)),
        "min": float(np.min(e)),
        "max": float(np.max(e)),
        "sse": float(np.sum(sq)),
    }


@dataclass
class AteResult:
    """Absolute trajectory error of an estimate against ground truth.

    ``errors[k]`` is the position error (metres) of associated pose ``k`` at
    ``timestamps[k]`` (estimate clock); ``aligned`` holds the associated estimate poses after
    alignment and ``gt`` the associated ground-truth poses. The alignment maps estimate
    coordinates to ground truth: ``p -> scale * rotation @ p + translation``.
    """

    stats: dict[str, float]
    errors: Array
    timestamps: Array
    aligned: Trajectory
    gt: Trajectory
    rotation: Array
    translation: Array
    scale: float
    align: str
    n_associated: int
    idx_gt: IntArray = field(repr=False)
    idx_est: IntArray = field(repr=False)

    @property
    def transform(self) -> Array:
        """The alignment as a 4x4 similarity matrix ``[[s R, t], [0, 1]]``."""
        return sim3_matrix(self.rotation, self.translation, self.scale)

    @property
    def rmse(self) -> float:
        return self.stats["rmse"]


@dataclass
class RpeResult:
    """Relative pose error over pose pairs.

    ``pairs[k] = (i, j)`` index the associated poses (``idx_gt`` / ``idx_est`` map them back
    to the input trajectories); ``timestamps[k]`` is the estimate stamp of ``j`` (as evo
    reports it). Translational errors are in metres, rotational errors in degrees.
    """

    trans_stats: dict[str, float]
    trans_errors: Array
    rot_stats: dict[str, float]
    rot_errors: Array
    pairs: IntArray
    timestamps: Array
    delta: float
    delta_unit: str
    all_pairs: bool
    align: str
    rotation: Array
    translation: Array
    scale: float
    n_associated: int
    idx_gt: IntArray = field(repr=False)
    idx_est: IntArray = field(repr=False)


# --------------------------------------------------------------------------------------
# shared steps


def _names(gt: Trajectory, est: Trajectory) -> tuple[str, str]:
    return (gt.name or "ground truth", est.name or "estimate")


def _associate_and_align(
    gt: Trajectory, est: Trajectory, align: str, max_diff: float, offset: float
) -> tuple[Trajectory, Trajectory, Array, Array, float, IntArray, IntArray]:
    """Associate by time, check there is enough overlap, align the estimate."""
    if align not in ALIGN_MODES:
        raise EvalError(f"unknown alignment {align!r}; use one of {', '.join(ALIGN_MODES)}")
    if not max_diff >= 0:
        raise EvalError(f"max_diff must be >= 0 seconds, got {max_diff}")
    gt_name, est_name = _names(gt, est)
    idx_gt, idx_est = associate(gt.timestamps, est.timestamps, max_diff, offset)
    n = len(idx_gt)
    if n < MIN_POSES:
        raise EvalError(
            f"only {n} poses of {est_name} ({len(est)} poses, "
            f"t={_span(est.timestamps)}) associate with {gt_name} ({len(gt)} poses, "
            f"t={_span(gt.timestamps)}) within max_diff={max_diff} s; need at least "
            f"{MIN_POSES}. Are both files from the same sequence and time base?"
        )
    gt_m = gt.select(idx_gt)
    est_m = est.select(idx_est)
    rot, trans, scale = np.eye(3), np.zeros(3), 1.0
    if align != "none":
        rot, trans, scale = umeyama(est_m.positions, gt_m.positions, with_scale=align == "sim3")
        est_m = Trajectory(
            est_m.timestamps, apply_sim3(est_m.poses, rot, trans, scale), est_m.name
        )
    return gt_m, est_m, rot, trans, scale, idx_gt, idx_est


def _span(t: Array) -> str:
    if len(t) == 0:
        return "empty"
    return f"{t[0]:.3f}..{t[-1]:.3f}"


# --------------------------------------------------------------------------------------
# ATE


def ate(
    gt: Trajectory,
    est: Trajectory,
    align: str = "se3",
    max_diff: float = 0.02,
    offset: float = 0.0,
) -> AteResult:
    """Absolute trajectory error (translation part) after associating and aligning.

    ``align``: ``"se3"`` (rigid, for stereo/RGB-D), ``"sim3"`` (also scale, for monocular)
    or ``"none"``. ``max_diff``: association window in seconds; ``offset`` is added to the
    estimate's stamps before associating.
    """
    gt_m, est_m, rot, trans, scale, idx_gt, idx_est = _associate_and_align(
        gt, est, align, max_diff, offset
    )
    diff = est_m.positions - gt_m.positions
    errors = np.sqrt(np.einsum("ij,ij->i", diff, diff))
    return AteResult(
        stats=error_stats(errors),
        errors=errors,
        timestamps=est_m.timestamps.copy(),
        aligned=est_m,
        gt=gt_m,
        rotation=rot,
        translation=trans,
        scale=scale,
        align=align,
        n_associated=len(idx_gt),
        idx_gt=idx_gt,
        idx_est=idx_est,
    )


# --------------------------------------------------------------------------------------
# RPE pair selection (pure functions of poses / stamps)


def pairs_by_frames(n: int, delta: int, all_pairs: bool = False) -> IntArray:
    """Index pairs ``delta`` frames apart: consecutive ``(0, d), (d, 2d), ...`` or all."""
    if all_pairs:
        i = np.arange(max(n - delta, 0))
        return np.stack([i, i + delta], axis=1).astype(np.intp)
    ids = np.arange(0, n, delta)
    return np.stack([ids[:-1], ids[1:]], axis=1).astype(np.intp)


def pairs_by_path(
    positions: ArrayLike, delta: float, tol: float = 0.0, all_pairs: bool = False
) -> IntArray:
    """Index pairs ``delta`` metres of travelled path apart.

    Consecutive mode: walk the path and close a pair each time the distance travelled since
    the pair's start reaches ``delta`` (the next pair starts there). All-pairs mode: for
    every start ``i`` the later pose whose path distance from ``i`` is closest to ``delta``,
    kept if within ``tol``.
    """
    p = np.asarray(positions, dtype=np.float64)
    steps = np.linalg.norm(p[:-1] - p[1:], axis=1)
    if not all_pairs:
        ids = [0]
        travelled = 0.0
        for k, step in enumerate(steps.tolist(), start=1):
            travelled += step
            if travelled >= delta:
                ids.append(k)
                travelled = 0.0
        a = np.asarray(ids, dtype=np.intp)
        return np.stack([a[:-1], a[1:]], axis=1)
    dist = np.concatenate(([0.0], np.cumsum(steps)))
    out = []
    # Only poses whose distance is within tol (plus slack for rounding) can be the best
    # candidate of an accepted pair, so search that window instead of all later poses.
    slack = tol + 1e-9 * (1.0 + abs(delta) + float(dist[-1]))
    lo_all = np.searchsorted(dist, dist + delta - slack, side="left")
    hi_all = np.searchsorted(dist, dist + delta + slack, side="right")
    for i in range(len(dist) - 1):
        lo = max(int(lo_all[i]), i + 1)
        hi = int(hi_all[i])
        if hi <= lo:
            continue
        gap = np.abs((dist[lo:hi] - dist[i]) - delta)
        k = int(np.argmin(gap))
        if gap[k] > tol:
            continue
        # Poses outside the window are further than tol from delta, so this first minimum
        # is also the first minimum over all later poses.
        out.append((i, lo + k))
    return np.asarray(out, dtype=np.intp).reshape(-1, 2)


def pairs_by_time(stamps: ArrayLike, delta: float) -> IntArray:
    """TUM ``evaluate_rpe.py --fixed_delta`` pairs for a delta in seconds.

    For every ``i``, ``j`` is the pose with the stamp closest to ``t_i + delta`` (earlier
    stamp on ties). Pairs with ``j`` the last pose (target possibly past the end) or
    ``j <= i`` are dropped.
    """
    t = np.asarray(stamps, dtype=np.float64)
    n = len(t)
    target = t + delta
    up = np.minimum(np.searchsorted(t, target, side="left"), n - 1)
    low = np.maximum(up - 1, 0)
    j = np.where(np.abs(t[low] - target) <= np.abs(t[up] - target), low, up)
    i = np.arange(n)
    keep = (j != n - 1) & (j > i)
    return np.stack([i[keep], j[keep]], axis=1).astype(np.intp)


def relative_errors(gt_poses: ArrayLike, est_poses: ArrayLike, pairs: ArrayLike) -> Array:
    """RPE matrices ``E = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)`` for index pairs ``(K, 2)``."""
    q = np.asarray(gt_poses, dtype=np.float64)
    p = np.asarray(est_poses, dtype=np.float64)
    ij = np.asarray(pairs, dtype=np.intp).reshape(-1, 2)
    q_rel = invert(q[ij[:, 0]]) @ q[ij[:, 1]]
    p_rel = invert(p[ij[:, 0]]) @ p[ij[:, 1]]
    return invert(q_rel) @ p_rel


def rotation_angles_deg(rot: ArrayLike) -> Array:
    """Rotation angles in degrees of ``(K, 3, 3)`` matrices, robust near 0 and 180 degrees.

    Goes through the nearest unit quaternion (scipy), which also tolerates the slightly
    non-orthonormal matrices of real files, the same way evo does.
    """
    r = np.asarray(rot, dtype=np.float64).reshape(-1, 3, 3)
    if len(r) == 0:
        return np.zeros(0)
    return np.rad2deg(Rotation.from_matrix(r).magnitude())


# --------------------------------------------------------------------------------------
# RPE


def rpe(
    gt: Trajectory,
    est: Trajectory,
    delta: float = 1,
    delta_unit: str = "frames",
    align: str = "none",
    max_diff: float = 0.02,
    offset: float = 0.0,
    all_pairs: bool = False,
    rel_delta_tol: float = 0.1,
    pairs_from_reference: bool = False,
) -> RpeResult:
    """Relative pose error (translation in metres and rotation in degrees).

    ``delta`` in ``delta_unit`` (``frames``, ``meters`` or ``seconds``) sets the pair
    spacing; ``all_pairs`` uses overlapping pairs from every pose instead of consecutive
    ones (meters: accepted within ``rel_delta_tol * delta``). Pairs are chosen on the
    aligned estimate, or on the ground truth with ``pairs_from_reference``. ``align``
    defaults to ``"none"`` as in evo_rpe: SE(3) alignment does not change RPE, Sim(3) does
    (it fixes a monocular estimate's scale).
    """
    if delta_unit not in DELTA_UNITS:
        raise EvalError(f"unknown delta unit {delta_unit!r}; use one of {', '.join(DELTA_UNITS)}")
    if not (np.isfinite(delta) and delta > 0):
        raise EvalError(f"RPE delta must be a positive number, got {delta}")
    if delta_unit == "frames" and float(delta) != int(delta):
        raise EvalError(f"RPE delta in frames must be a whole number, got {delta}")
    gt_m, est_m, rot, trans, scale, idx_gt, idx_est = _associate_and_align(
        gt, est, align, max_diff, offset
    )
    basis = gt_m if pairs_from_reference else est_m
    if delta_unit == "frames":
        pairs = pairs_by_frames(len(basis), int(delta), all_pairs)
    elif delta_unit == "meters":
        pairs = pairs_by_path(basis.positions, float(delta), float(delta) * rel_delta_tol, all_pairs)
    else:
        pairs = pairs_by_time(basis.timestamps, float(delta))
    if len(pairs) == 0:
        gt_name, est_name = _names(gt, est)
        raise EvalError(
            f"RPE delta = {delta} {delta_unit} gives no pose pairs on the {len(basis)} "
            f"associated poses of {est_name} and {gt_name}; use a smaller delta"
        )
    e = relative_errors(gt_m.poses, est_m.poses, pairs)
    t_err = np.sqrt(np.einsum("ki,ki->k", e[:, :3, 3], e[:, :3, 3]))
    r_err = rotation_angles_deg(e[:, :3, :3])
    return RpeResult(
        trans_stats=error_stats(t_err),
        trans_errors=t_err,
        rot_stats=error_stats(r_err),
        rot_errors=r_err,
        pairs=pairs,
        timestamps=est_m.timestamps[pairs[:, 1]].copy(),
        delta=float(delta),
        delta_unit=delta_unit,
        all_pairs=all_pairs,
        align=align,
        rotation=rot,
        translation=trans,
        scale=scale,
        n_associated=len(idx_gt),
        idx_gt=idx_gt,
        idx_est=idx_est,
    )
