"""DDL-SLAM's multi-view check (Algorithm 1) in a monocular form: no depth, two-view geometry.

The RGB-D check (``multiview.py``) projects reference keypoints with their depth and looks
for the current depth in front of them. A monocular camera has no depth, but a static
point still obeys the geometry between two views with known poses, and a moving one does
not:

- **epipolar distance**: a current keypoint matched to a keypoint of a reference keyframe
  (both hold the same map point: tracking's matches) must lie on that keypoint's epipolar
  line, ``F = K^-T [t]x R K^-1``
  from the two tracked poses. ORB-SLAM's ``ORBmatcher::CheckDistEpipolarLine`` accepts a
  pair within ``3.84 sigma^2`` (chi-square, 1 DoF, the current keypoint's level); a point
  that moved across its epipolar line by more than the gate is a dynamic seed;
- **reprojection error**: the map point, triangulated from the keyframes, projected into
  the reference keyframe must land on the keypoint it was seen at there within
  ``5.991 sigma^2`` (2 DoF, ORB-SLAM's test in ``Optimizer::PoseOptimization``): a point
  that moved along its epipolar line and was re-triangulated (or fused) where the current
  frame sees it fails this one. Its residual in the current frame is pose optimisation's
  own test and is left to it.

Which pairs: tracking's matches (a current keypoint and a keyframe's keypoint holding the
same map point: free, and a mover tracking follows is what pulls the pose), and, against
the ``SEARCH_REFS`` best references, a descriptor search of the current keypoints tracking
left unmatched among the reference's keypoints that hold a map point (nearest neighbour
within ORB-SLAM's ``th_low``, Lowe's ratio ``SEARCH_RATIO``): on walking_box a carried box
is mostly not matched by tracking, yet its keypoints would be triangulated into the map.
A search over all keypoints cost 15 ms per keyframe on two cores (OpenCV brute force,
1000 x 1000 ORB descriptors, cross check) and its mismatches flagged 5-8 % of the static
pairs; the unmatched-to-triangulated search with ratio 0.6: 1.5-4 ms, 2 % (0.8: 10-13 %).

Both gates are widened by ``GATE`` (the poses are estimates, not ground truth). Seeds
are then grown into regions without depth: the image is cut into ``CELL_PX`` cells and a
cell where at least ``min_seeds`` tested points are dynamic and make at least
``min_dynamic_ratio`` of its tested points is moving, with its neighbours that hold a
dynamic seed (DDL-SLAM grows over depth-continuous regions instead).

A reference keyframe whose baseline to the current frame is under ``MIN_BASELINE_RATIO``
of its median scene depth is skipped: with (nearly) no translation the epipolar lines are
undefined and moving points look static. Which keyframes: the best-overlapping ones,
preferring those ``multiview_min_age_s`` old (``multiview.pick_references``).

Pure functions of arrays (vectorised numpy), and ``mono_views`` reading the frame and
keyframes through protocols.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.config import DynamicsConfig
from semslam.core.types import FeatureSpec, Keypoints
from semslam.dynamics.multiview import reference_keyframes
from semslam.geometry.camera import PinholeCamera

#: Chi-square 95 % for one (epipolar distance) and two (reprojection) degrees of freedom.
CHI2_1DOF = 3.84
CHI2_2DOF = 5.991
#: Both gates are this many times ORB-SLAM's: the two poses carry their own error.
GATE = 4.0
#: Region cells, pixels.
CELL_PX = 40
#: A reference view with a baseline below this fraction of its median scene depth is skipped.
MIN_BASELINE_RATIO = 0.02
#: The descriptor search runs against this many references (the best first), with this ratio.
SEARCH_REFS = 2
SEARCH_RATIO = 0.6


@dataclass(frozen=True)
class MonoView:
    """One posed view: keypoints (as detected ``pix`` and undistorted ``xy``), their
    pyramid level, the map point each holds (``point_id``, -1 where none: any id shared by
    the views, a store row) and its world position (NaN where none)."""

    T_cw: NDArray[np.float64]
    pix: NDArray[np.float64]
    xy: NDArray[np.float64]
    octave: NDArray[np.int32]
    point_id: NDArray[np.intp]
    points_w: NDArray[np.float64]
    descriptors: NDArray[np.uint8] | NDArray[np.float32] | None = None


@dataclass
class MonoTested:
    """Current keypoints tested against the reference views: index, dynamic flag (each
    keypoint counted once per reference it was matched in)."""

    index: NDArray[np.intp]
    dynamic: NDArray[np.bool_]


def relative_pose(T_cur: NDArray[np.float64], T_ref: NDArray[np.float64]
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(R, t): reference camera -> current camera."""
    R = T_cur[:3, :3] @ T_ref[:3, :3].T
    return R, T_cur[:3, 3] - R @ T_ref[:3, 3]


def fundamental(R: NDArray[np.float64], t: NDArray[np.float64], K: NDArray[np.float64]) -> NDArray[np.float64]:
    """``F`` with ``x_cur^T F x_ref = 0`` for a static point (pixels, homogeneous)."""
    tx = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
    Kinv = np.linalg.inv(K)
    return Kinv.T @ tx @ R @ Kinv


def epipolar_distance(x_cur: NDArray[np.float64], x_ref: NDArray[np.float64], F: NDArray[np.float64]
                      ) -> NDArray[np.float64]:
    """Pixel distance of each ``x_cur`` to the epipolar line ``F x_ref`` (inf where the line
    is undefined)."""
    h_ref = np.column_stack([x_ref, np.ones(len(x_ref))])
    lines = h_ref @ F.T  # (a, b, c) per reference point, in the current image
    num = np.abs(lines[:, 0] * x_cur[:, 0] + lines[:, 1] * x_cur[:, 1] + lines[:, 2])
    den = np.hypot(lines[:, 0], lines[:, 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(den > 1e-12, num / den, np.inf)


def reprojection_error(points_w: NDArray[np.float64], T_cw: NDArray[np.float64], camera: PinholeCamera,
                       xy: NDArray[np.float64]) -> NDArray[np.float64]:
    """Pixel distance between the projections of ``points_w`` and ``xy`` (inf behind the camera)."""
    pc = points_w @ T_cw[:3, :3].T + T_cw[:3, 3]
    z = pc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = camera.fx * pc[:, 0] / z + camera.cx
        v = camera.fy * pc[:, 1] / z + camera.cy
        err = np.hypot(u - xy[:, 0], v - xy[:, 1])
    return np.where(z > 1e-6, err, np.inf)


def match_views(cur: NDArray[np.intp], ref: NDArray[np.intp]) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Keypoints of two views holding the same map point (ids, -1 = none): (current
    indices, reference indices)."""
    ic = np.flatnonzero(cur >= 0)
    ir = np.flatnonzero(ref >= 0)
    _, a, b = np.intersect1d(cur[ic], ref[ir], assume_unique=False, return_indices=True)
    return ic[a], ir[b]


def search_unmatched(cur: MonoView, ref: MonoView, spec: FeatureSpec) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Current keypoints without a map point matched by descriptor to reference keypoints
    with one (nearest within ``spec.th_low``, ratio ``SEARCH_RATIO`` to the second):
    (current indices, reference indices)."""
    none = (np.zeros(0, np.intp), np.zeros(0, np.intp))
    qi = np.flatnonzero(cur.point_id < 0)
    ti = np.flatnonzero(ref.point_id >= 0)
    if cur.descriptors is None or ref.descriptors is None or len(qi) == 0 or len(ti) < 2:
        return none
    norm = cv2.NORM_HAMMING if spec.distance == "hamming" else cv2.NORM_L2
    knn = cv2.BFMatcher(norm).knnMatch(np.ascontiguousarray(cur.descriptors[qi]),
                                       np.ascontiguousarray(ref.descriptors[ti]), k=2)
    m = np.array([(a.queryIdx, a.trainIdx, a.distance, b.distance) for a, b in (p for p in knn if len(p) == 2)],
                 np.float64).reshape(-1, 4)
    keep = (m[:, 2] <= spec.th_low) & (m[:, 2] < SEARCH_RATIO * m[:, 3])
    return qi[m[keep, 0].astype(np.intp)], ti[m[keep, 1].astype(np.intp)]


def check_against(cur: MonoView, ref: MonoView, camera: PinholeCamera, spec: FeatureSpec,
                 search: bool = False) -> MonoTested:
    """Test the keypoints ``cur`` shares with one reference view and (``search``) those a
    descriptor search pairs (module doc); empty when the baseline is too short for the
    epipolar geometry to tell."""
    empty = MonoTested(np.zeros(0, np.intp), np.zeros(0, bool))
    R, t = relative_pose(cur.T_cw, ref.T_cw)
    has_pt = np.isfinite(ref.points_w[:, 0])
    if has_pt.any():
        zr = ref.points_w[has_pt] @ ref.T_cw[2, :3] + ref.T_cw[2, 3]
        zr = zr[zr > 0]
        if len(zr) and np.linalg.norm(t) < MIN_BASELINE_RATIO * float(np.median(zr)):
            return empty
    ic, ir = match_views(cur.point_id, ref.point_id)
    n_shared = len(ic)
    if search:
        sc, sr = search_unmatched(cur, ref, spec)
        ic, ir = np.concatenate([ic, sc]), np.concatenate([ir, sr])
    if len(ic) == 0:
        return empty
    scales2 = spec.pyramid.scales**2
    sigma2 = scales2[np.clip(cur.octave[ic], 0, spec.n_levels - 1)]
    d_epi = epipolar_distance(cur.xy[ic], ref.xy[ir], fundamental(R, t, camera.K))
    dynamic = d_epi**2 > GATE * CHI2_1DOF * sigma2
    # Shared points: the map point against the keyframe's own observation of it.
    sh = slice(0, n_shared)
    err = reprojection_error(ref.points_w[ir[sh]], ref.T_cw, camera, ref.xy[ir[sh]])
    dynamic[sh] |= err**2 > GATE * CHI2_2DOF * scales2[np.clip(ref.octave[ir[sh]], 0, spec.n_levels - 1)]
    # Searched pairs: the keyframe's map point against the current keypoint.
    se = slice(n_shared, None)
    err = reprojection_error(ref.points_w[ir[se]], cur.T_cw, camera, cur.xy[ic[se]])
    dynamic[se] |= err**2 > GATE * CHI2_2DOF * sigma2[se]
    return MonoTested(ic, dynamic)


def grow_cells(pix: NDArray[np.float64], dynamic: NDArray[np.bool_], shape: tuple[int, int],
               params: DynamicsConfig = DynamicsConfig(), cell_px: int = CELL_PX) -> NDArray[np.bool_]:
    """Moving pixels from tested points (``pix``, ``dynamic``): cells with at least
    ``min_seeds`` dynamic points making ``min_dynamic_ratio`` of their tested points, and
    their neighbours holding a dynamic point."""
    h, w = shape
    gh, gw = -(-h // cell_px), -(-w // cell_px)
    cu = np.clip((pix[:, 0] // cell_px).astype(np.intp), 0, gw - 1)
    cv = np.clip((pix[:, 1] // cell_px).astype(np.intp), 0, gh - 1)
    cell = cv * gw + cu
    tested = np.bincount(cell, minlength=gh * gw).reshape(gh, gw)
    ndyn = np.bincount(cell, weights=dynamic.astype(float), minlength=gh * gw).reshape(gh, gw)
    core = (ndyn >= params.min_seeds) & (ndyn >= params.min_dynamic_ratio * tested)
    if not core.any():
        return np.zeros(shape, bool)
    near = cv2.dilate(core.view(np.uint8), np.ones((3, 3), np.uint8)).view(bool)
    cells = core | (near & (ndyn > 0))
    big = np.kron(cells, np.ones((cell_px, cell_px), bool))
    return np.ascontiguousarray(big[:h, :w])


def mono_multiview(cur: MonoView, refs: Sequence[MonoView], camera: PinholeCamera, spec: FeatureSpec,
                   shape: tuple[int, int], params: DynamicsConfig = DynamicsConfig()
                   ) -> tuple[NDArray[np.bool_], MonoTested]:
    """(moving mask, the tests behind it) of the current view against the reference views."""
    tests = [check_against(cur, r, camera, spec, search=k < SEARCH_REFS) for k, r in enumerate(refs)]
    index = np.concatenate([t.index for t in tests]) if tests else np.zeros(0, np.intp)
    dynamic = np.concatenate([t.dynamic for t in tests]) if tests else np.zeros(0, bool)
    mask = grow_cells(cur.pix[index], dynamic, shape, params)
    return mask, MonoTested(index, dynamic)


# ---------------------------------------------------------------------------- from the map
class _Store(Protocol):
    pos: NDArray[np.float64]
    bad: NDArray[np.bool_]


class _Slots(Protocol):
    @property
    def rows(self) -> NDArray[np.intp]: ...

    @property
    def store(self) -> _Store | None: ...


class PosedFeatures(Protocol):
    """What a view is read from: a tracked frame or a keyframe (``slam.orb``)."""

    T_cw: NDArray[np.float64] | None
    keypoints: Keypoints
    xy: NDArray[np.float64]
    points: _Slots


class MonoKeyframe(PosedFeatures, Protocol):
    bad: bool
    timestamp: float

    def best_covisibles(self, n: int) -> Sequence["MonoKeyframe"]: ...


def view_of(f: PosedFeatures) -> MonoView:
    """A frame's or keyframe's keypoints and the positions of the good map points they hold."""
    assert f.T_cw is not None
    rows = np.asarray(f.points.rows)
    pts = np.full((len(rows), 3), np.nan)
    ok = rows >= 0
    store = f.points.store
    if store is not None:
        ok[ok] = ~store.bad[rows[ok]]
        pts[ok] = store.pos[rows[ok]]
    else:
        ok[:] = False
    kp = f.keypoints
    return MonoView(f.T_cw, np.asarray(kp.xy, np.float64), np.asarray(f.xy, np.float64), kp.octave,
                    np.where(ok, rows, -1).astype(np.intp), pts, kp.descriptors)


def mono_views(cur: PosedFeatures, ref: MonoKeyframe, now: float, n: int, min_age_s: float
               ) -> tuple[MonoView, list[MonoView]]:
    """The current frame's view and the ``n`` reference keyframes' (``multiview.reference_views``'
    choice: best overlap with ``ref``'s covisibility, old enough first)."""
    return view_of(cur), [view_of(k) for k in reference_keyframes(ref, now, n, min_age_s)]
