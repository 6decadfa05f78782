"""SDF-SLAM's data correction (IV-A): global and local.

The paper gives one paragraph for it: global optimisation "randomly selects key frames and
performs camera pose estimation on the two key frames to establish a constraint relationship
and to further optimize the camera pose information"; local ("partial") optimisation unifies
"the feature point world coordinates of the second frame and the first frame ... according to
the feature point matching pairs". What is built here, and the choices the paper leaves open:

* Global: keyframe pairs at least two apart (consecutive ones are already constrained by
  tracking) are sampled at random among those whose current poses could overlap (camera
  centres within a distance, optical axes within an angle), newest keyframes first; each
  pair is matched and solved by the same PnP-RANSAC as tracking (``sdf_slam_pnp``), and a pair
  with enough inliers becomes an edge of an SE(3) pose graph (``backend.pose_graph``, GTSAM)
  next to the tracking edges, keyframe 0 fixed. Edges weigh their inlier count / 100. SE(3),
  not Sim(3): a depth network gives metric scale, which is the point of the method.
* Local: every keypoint with depth of a keyframe belongs to one feature track (it inherits
  the track of the previous keyframe's keypoint it matches, else starts one); a track's world
  position is the MEDIAN (per coordinate) of its observations' back-projections through their
  keyframes' current poses: with two observations the mean, and one bad predicted depth among
  three or more cannot pull it. Tracking takes these positions as the reference's 3D points.
  With ``min_parallax_deg`` > 0 (the preset's 2 degrees; ours, the paper gives no rule) a track
  whose rays spread at least that much takes their least-squares intersection instead (the
  point nearest to all of its keyframes' rays: multi-view geometry, which does not inherit a
  depth network's distortion of the room), unless that lands outside 0.6-1.6x the median's
  range (a wrong match, a near-degenerate ray set).

Not in the paper, and kept apart from it (``sdf_slam.depth_alignment``): the fit of a frame's
predicted depth to the map's depth of the same points (``fit_depth_alignment``), so that a
depth network whose scale and contrast wander between views does not hand each keyframe its own.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from semslam.backend.pose_graph import optimize_pose_graph
from semslam.core.protocols import Matcher
from semslam.geometry.se3 import invert, rotation_angle
from semslam.slam.trackers.sdf_slam_pnp import PnpSettings, solve_pnp

Array = NDArray[np.float64]


@dataclass
class ViewFeatures:
    """A frame's keypoints as tracking and correction use them: undistorted pixels,
    descriptors and, where the depth source gave a usable depth, camera-frame 3D points."""

    xy: Array
    descriptors: NDArray[np.generic]
    pts_c: Array
    has_depth: NDArray[np.bool_]

    def __len__(self) -> int:
        return len(self.xy)


# ------------------------------------------------------------------------------------ local
def group_median(keys: NDArray[np.intp], values: Array) -> tuple[NDArray[np.intp], Array]:
    """Per distinct key, the per-column median of its rows of ``values`` (N, D): the keys
    sorted and their medians, vectorised (one lexsort per column)."""
    keys = np.asarray(keys, np.intp)
    values = np.asarray(values, np.float64).reshape(len(keys), -1)
    uniq, count = np.unique(keys, return_counts=True)
    start = np.concatenate(([0], np.cumsum(count)[:-1]))
    lo, hi = start + (count - 1) // 2, start + count // 2
    out = np.empty((len(uniq), values.shape[1]))
    for c in range(values.shape[1]):
        v = values[np.lexsort((values[:, c], keys)), c]
        out[:, c] = 0.5 * (v[lo] + v[hi])
    return uniq, out


#: A triangulated track is kept only within this factor of its median position's range.
TRIANGULATION_RANGE_BOUNDS = (0.6, 1.6)


#: Rays spreading less than this (degrees) are taken as parallel: no intersection.
MIN_SPREAD_DEG = 0.01


def intersect_rays(group: NDArray[np.intp], n_groups: int, origins: Array, directions: Array
                   ) -> tuple[Array, Array]:
    """Per group of rays (``group[k]`` in 0..n_groups-1; unit ``directions``), the point with
    the least summed squared distance to its rays, and the rays' spread in degrees: twice the
    largest angle between a ray and the group's mean direction (for two rays, their angle).
    Groups of one ray have spread 0; they and parallel rays (spread < ``MIN_SPREAD_DEG``) get
    a point of NaN."""
    M = np.eye(3)[None] - directions[:, :, None] * directions[:, None, :]  # projects off the ray
    A = np.zeros((n_groups, 3, 3))
    np.add.at(A, group, M)
    b = np.zeros((n_groups, 3))
    np.add.at(b, group, np.einsum("nij,nj->ni", M, origins))
    mean = np.zeros((n_groups, 3))
    np.add.at(mean, group, directions)
    mean /= np.maximum(np.linalg.norm(mean, axis=1, keepdims=True), 1e-12)
    angle = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", directions, mean[group]), -1.0, 1.0)))
    spread = np.zeros(n_groups)
    np.maximum.at(spread, group, 2.0 * angle)
    spread[np.bincount(group, minlength=n_groups) < 2] = 0.0  # one ray: 0, not rounding noise
    points = np.full((n_groups, 3), np.nan)
    solvable = spread >= MIN_SPREAD_DEG
    points[solvable] = np.linalg.solve(A[solvable], b[solvable][:, :, None])[:, :, 0]
    return points, spread


class TrackTable:
    """Feature tracks over keyframes: observations (keyframe, camera-frame point) per track."""

    def __init__(self) -> None:
        self._kf: list[NDArray[np.intp]] = []
        self._track: list[NDArray[np.intp]] = []
        self._pc: list[Array] = []
        self.n_tracks = 0
        self._cache: tuple[NDArray[np.intp], NDArray[np.intp], Array] | None = None

    def add(self, kf_index: int, pts_c: Array, tracks: NDArray[np.intp]) -> NDArray[np.intp]:
        """Observations of keyframe ``kf_index``; a track id < 0 starts a new track. Returns
        the track id of every row."""
        tracks = np.asarray(tracks, np.intp).copy()
        new = tracks < 0
        tracks[new] = self.n_tracks + np.arange(int(new.sum()))
        self.n_tracks += int(new.sum())
        self._kf.append(np.full(len(tracks), kf_index, np.intp))
        self._track.append(tracks)
        self._pc.append(np.asarray(pts_c, np.float64).reshape(-1, 3))
        self._cache = None
        return tracks

    def _all(self) -> tuple[NDArray[np.intp], NDArray[np.intp], Array]:
        if self._cache is None:
            if not self._kf:
                self._cache = (np.zeros(0, np.intp), np.zeros(0, np.intp), np.zeros((0, 3)))
            else:
                self._cache = (np.concatenate(self._kf), np.concatenate(self._track), np.concatenate(self._pc))
        return self._cache

    def observations(self) -> tuple[NDArray[np.intp], NDArray[np.intp], Array]:
        """(keyframe index, track id, camera-frame point) of every observation."""
        return self._all()

    def positions(self, poses_wc: Array, tracks: NDArray[np.intp] | None = None, min_parallax_deg: float = 0.0
                  ) -> tuple[NDArray[np.intp], Array]:
        """(track ids, world positions): the median of each track's back-projections through
        ``poses_wc[keyframe index]``, or where its rays spread at least ``min_parallax_deg``
        (> 0) their intersection (see the module doc); only ``tracks`` when given (all tracks
        otherwise)."""
        kf, tr, pc = self._all()
        if tracks is not None:
            keep = np.isin(tr, tracks)
            kf, tr, pc = kf[keep], tr[keep], pc[keep]
        P = poses_wc[kf]
        rays = np.einsum("nij,nj->ni", P[:, :3, :3], pc)
        origins = P[:, :3, 3]
        ids, pos = group_median(tr, rays + origins)
        if min_parallax_deg <= 0.0 or len(ids) == 0:
            return ids, pos
        group = np.searchsorted(ids, tr)
        rays /= np.maximum(np.linalg.norm(rays, axis=1, keepdims=True), 1e-12)
        crossing, spread = intersect_rays(group, len(ids), origins, rays)
        centre = np.zeros((len(ids), 3))
        np.add.at(centre, group, origins)
        centre /= np.bincount(group, minlength=len(ids))[:, None]
        take = np.flatnonzero(spread >= min_parallax_deg)
        ratio = (np.linalg.norm(crossing[take] - centre[take], axis=1)
                 / np.maximum(np.linalg.norm(pos[take] - centre[take], axis=1), 1e-9))
        lo, hi = TRIANGULATION_RANGE_BOUNDS
        take = take[(ratio > lo) & (ratio < hi)]
        pos[take] = crossing[take]
        return ids, pos


# ------------------------------------------------------------------------------------ global
@dataclass
class Edge:
    """``T_i_j = inv(T_wi) @ T_wj`` between keyframe indices, with a scalar weight."""

    i: int
    j: int
    T_ij: Array
    weight: float
    kind: str  # "tracking" or "pair"


def candidate_pairs(poses_wc: Array, tried: set[tuple[int, int]], newest: int, n: int, rng: np.random.Generator,
                    max_distance: float, max_angle_deg: float, min_gap: int = 2) -> list[tuple[int, int]]:
    """Up to ``n`` untried keyframe pairs (i < j, j - i >= ``min_gap``) whose cameras could
    see the same scene: pairs with one of the ``newest`` last keyframes first, each group in
    random order."""
    k = len(poses_wc)
    if k < min_gap + 1 or n <= 0:
        return []
    i, j = np.triu_indices(k, min_gap)
    centre = poses_wc[:, :3, 3]
    axis = poses_wc[:, :3, 2]
    near = np.linalg.norm(centre[i] - centre[j], axis=1) <= max_distance
    cos = np.clip(np.einsum("ij,ij->i", axis[i], axis[j]), -1.0, 1.0)
    near &= np.degrees(np.arccos(cos)) <= max_angle_deg
    pairs = [(int(a), int(b)) for a, b in zip(i[near], j[near]) if (int(a), int(b)) not in tried]
    recent = [p for p in pairs if p[1] >= k - newest]
    older = [p for p in pairs if p[1] < k - newest]
    rng.shuffle(recent)
    rng.shuffle(older)
    return (recent + older)[:n]


def match_views(query: ViewFeatures, train: ViewFeatures, matcher: Matcher, max_distance: float,
                ratio: float) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Brute-force matches of ``query`` keypoints to ``train`` keypoints that have depth."""
    with_depth = np.flatnonzero(train.has_depth)
    if len(with_depth) < 2 or len(query) == 0:
        return np.zeros(0, np.intp), np.zeros(0, np.intp)
    qi, ti, _ = matcher.match_brute_force(query.descriptors, train.descriptors[with_depth], max_distance, ratio)
    return qi, with_depth[ti]


def pair_constraint(view_i: ViewFeatures, view_j: ViewFeatures, matcher: Matcher, max_distance: float, ratio: float,
                    K: Array, settings: PnpSettings) -> tuple[Array, int] | None:
    """``T_i_j`` (camera j in camera i) by PnP of keyframe i's depth-backed points against
    keyframe j's keypoints, and the inlier count; None when it does not hold."""
    qi, ti = match_views(view_j, view_i, matcher, max_distance, ratio)
    T_j_i, inl = solve_pnp(view_i.pts_c[ti], view_j.xy[qi], K, settings)
    if T_j_i is None:
        return None
    return invert(T_j_i), int(inl.sum())


@dataclass(frozen=True)
class DepthAlignment:
    """``z_map = exp(log_scale) * z_predicted ** power``: how a frame's predicted depth is
    brought to the map's (``power`` 1 for a pure scale)."""

    power: float = 1.0
    log_scale: float = 0.0

    def apply(self, z: NDArray[np.floating]) -> NDArray[np.floating]:
        """Aligned depths; zeros (no depth) stay zero."""
        z = np.asarray(z)
        positive = z > 0
        out = np.zeros_like(z)
        out[positive] = np.exp(self.log_scale + self.power * np.log(z[positive]))
        return out


#: A fitted ratio or power outside these is taken for a failure (wrong pose, broken depth map).
SCALE_BOUNDS = (0.5, 2.0)
POWER_BOUNDS = (0.4, 1.5)


def fit_depth_alignment(z_map: Array, z_predicted: Array, mode: str, min_points: int) -> DepthAlignment | None:
    """The alignment of predicted depths to the map's depths of the same points: ``scale``,
    the median ratio; ``power``, a line in log depth (least squares, refitted without the
    worst 20 % of residuals), i.e. scale and depth contrast, as monocular-depth evaluation
    aligns predictions (MiDaS fits scale and shift). None with fewer than ``min_points``
    positive pairs or a fit outside ``SCALE_BOUNDS`` / ``POWER_BOUNDS``."""
    z_map = np.asarray(z_map, np.float64)
    z_predicted = np.asarray(z_predicted, np.float64)
    ok = (z_map > 0) & (z_predicted > 0) & np.isfinite(z_map) & np.isfinite(z_predicted)
    if int(ok.sum()) < min_points:
        return None
    log_map, log_pred = np.log(z_map[ok]), np.log(z_predicted[ok])
    if mode == "scale":
        fit = DepthAlignment(1.0, float(np.median(log_map - log_pred)))
    elif mode == "power":
        A = np.stack([log_pred, np.ones_like(log_pred)], axis=1)
        coef = np.linalg.lstsq(A, log_map, rcond=None)[0]
        residual = np.abs(A @ coef - log_map)
        keep = residual <= np.quantile(residual, 0.8)
        coef = np.linalg.lstsq(A[keep], log_map[keep], rcond=None)[0]
        if not POWER_BOUNDS[0] <= coef[0] <= POWER_BOUNDS[1]:
            return None
        fit = DepthAlignment(float(coef[0]), float(coef[1]))
    else:
        raise ValueError(f"depth alignment: expected scale or power, got {mode!r}")
    ratio = float(np.median(fit.apply(z_predicted[ok]) / z_predicted[ok]))
    return fit if SCALE_BOUNDS[0] <= ratio <= SCALE_BOUNDS[1] else None


def relative_motion(T_a: Array, T_b: Array) -> tuple[float, float]:
    """(translation in metres, rotation in degrees) between two ``T_wc`` poses."""
    rel = invert(T_a) @ T_b
    return float(np.linalg.norm(rel[:3, 3])), float(np.degrees(rotation_angle(rel[:3, :3])))


def correct_poses(poses_wc: Array, edges: list[Edge]) -> Array:
    """The keyframe poses after the pose graph of ``edges`` (keyframe 0 fixed); raises
    ``backend.pose_graph.PoseGraphFailed`` when GTSAM cannot solve it."""
    if not edges:
        return poses_wc.copy()
    e = np.array([(x.i, x.j) for x in edges], np.intp)
    T = np.stack([x.T_ij for x in edges])
    w = np.array([x.weight for x in edges])
    return optimize_pose_graph(poses_wc, e, T, w, fixed=(0,))
