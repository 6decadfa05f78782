"""Essential-graph optimisation after a loop closure (ORB-SLAM OptimizeEssentialGraph): SE(3)
for RGB-D / stereo, Sim(3) for monocular maps (``optimize_sim3_pose_graph``).

ORB-SLAM2 optimises Sim3 vertices with the scale fixed for stereo / RGB-D (``_fix_scale``), which
is exactly an SE(3) pose graph, so here every node is a GTSAM ``Pose3`` (``T_wc``) and every edge
a ``BetweenFactorPose3``.  The caller (the SLAM map) builds the edge list - spanning tree, loop
edges, strong covisibility - and the relative measurements from the *uncorrected* poses, and
passes the loop-corrected poses as the initial estimate, as ORB-SLAM does.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import gtsam
import numpy as np
from numpy.typing import ArrayLike, NDArray

from semslam.backend.gtsam_utils import lm_params, poses_from_rows
from semslam.backend.sim3 import sim3_parts
from semslam.geometry.se3 import invert

Array = NDArray[np.float64]

_FIXED_SIGMA = 1e-9


class PoseGraphFailed(RuntimeError):
    """GTSAM could not solve the pose graph; the caller keeps its initial poses and counts it."""


def optimize_pose_graph(
    poses_wc: Array,
    edges: NDArray[np.intp],
    measurements: Array,
    information: ArrayLike | None = None,
    fixed: Sequence[int] | NDArray[np.intp] = (0,),
    iterations: int = 20,
) -> Array:
    """Optimised (K, 4, 4) ``T_wc`` poses of a pose graph.

    ``edges[e] = (i, j)`` with measurement ``T_i_j = inv(T_wi) @ T_wj``.  ``information`` is
    either (E, 6, 6) matrices (GTSAM's Pose3 tangent order: rotation then translation) or (E,)
    scalar weights meaning ``w * I``; None is all ones (ORB-SLAM's ``matLambda`` is the identity).
    ``fixed`` nodes (ORB-SLAM: the loop keyframe) are held by a tight prior (sigma 1e-9) and
    returned verbatim; nodes that no edge touches are returned unchanged.

    ORB-SLAM runs g2o LM with 20 iterations and an initial lambda of 1e-16 (practically
    Gauss-Newton); GTSAM's LM keeps its default damping schedule and stops at convergence.
    """
    poses_wc = np.asarray(poses_wc, dtype=np.float64)
    edges = np.asarray(edges, dtype=np.intp).reshape(-1, 2)
    measurements = np.asarray(measurements, dtype=np.float64).reshape(-1, 4, 4)
    n_e = edges.shape[0]
    fixed_idx = np.unique(np.asarray(fixed, dtype=np.intp).reshape(-1))

    graph = gtsam.NonlinearFactorGraph()
    add = graph.push_back
    BF = gtsam.BetweenFactorPose3
    P3 = gtsam.Pose3
    info = None if information is None else np.asarray(information, dtype=np.float64)
    if info is not None and info.ndim == 3:
        for (i, j), T, L in zip(edges.tolist(), measurements, info.reshape(n_e, 6, 6)):
            add(BF(i, j, P3(T), gtsam.noiseModel.Gaussian.Information(L)))
    else:
        w = np.ones(n_e) if info is None else np.broadcast_to(info, (n_e,))
        levels, idx = np.unique(w, return_inverse=True)
        models = [gtsam.noiseModel.Isotropic.Precision(6, float(x)) for x in levels]
        for (i, j), T, li in zip(edges.tolist(), measurements, idx.tolist()):
            add(BF(i, j, P3(T), models[li]))

    return _solve(graph, poses_wc, edges, fixed_idx, 6, P3, gtsam.PriorFactorPose3,
                  lambda result, keys: poses_from_rows(gtsam.utilities.extractPose3(result)), iterations)


def _solve(graph: gtsam.NonlinearFactorGraph, poses_wc: Array, edges: NDArray[np.intp], fixed_idx: NDArray[np.intp],
           dim: int, value_of: Callable[[Array], Any], prior_factor: Callable[..., Any],
           read: Callable[[gtsam.Values, NDArray[np.intp]], Array], iterations: int) -> Array:
    """The fixed nodes' tight priors, the initial values of the nodes an edge touches, GTSAM's
    LM; the optimised ``T_wc`` (or Sim(3)) of those nodes, the others and the fixed ones as given."""
    used = np.zeros(poses_wc.shape[0], bool)
    used[edges.reshape(-1)] = True
    prior = gtsam.noiseModel.Isotropic.Sigma(dim, _FIXED_SIGMA)
    for k in fixed_idx[used[fixed_idx]].tolist():
        graph.push_back(prior_factor(k, value_of(poses_wc[k]), prior))

    keys = np.flatnonzero(used)
    values = gtsam.Values()
    for k in keys.tolist():
        values.insert(k, value_of(poses_wc[k]))
    params = lm_params(iterations)
    params.setRelativeErrorTol(1e-10)
    try:
        result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    except RuntimeError as exc:
        raise PoseGraphFailed(str(exc).strip()[:200]) from exc

    out = poses_wc.copy()
    out[keys] = read(result, keys)
    out[fixed_idx] = poses_wc[fixed_idx]
    return out


def _to_similarity3(S: Array) -> gtsam.Similarity3:
    """GTSAM's ``Similarity3`` of our ``S = [[s R, t], [0, 1]]`` (``x -> s R x + t``).
    GTSAM's acts as ``x -> s (R x + t')``, so ``t' = t / s``."""
    R, t, s = sim3_parts(S)
    return gtsam.Similarity3(gtsam.Rot3(R), np.ascontiguousarray(t / s), s)


def _from_similarity3(S: gtsam.Similarity3) -> Array:
    """Our 4x4 ``[[s R, t], [0, 1]]`` of a GTSAM ``Similarity3``."""
    s = float(S.scale())
    out = np.eye(4)
    out[:3, :3] = s * S.rotation().matrix()
    out[:3, 3] = s * np.asarray(S.translation(), dtype=np.float64)
    return out


def optimize_sim3_pose_graph(
    poses_wc: Array,
    edges: NDArray[np.intp],
    measurements: Array,
    information: ArrayLike | None = None,
    fixed: Sequence[int] | NDArray[np.intp] = (0,),
    iterations: int = 20,
) -> Array:
    """Optimised (K, 4, 4) ``S_wc`` similarities of a Sim(3) pose graph (monocular maps).

    The Sim(3) form of :func:`optimize_pose_graph`, as ORB-SLAM's OptimizeEssentialGraph with
    ``bFixScale`` false (VertexSim3Expmap nodes, EdgeSim3 edges, identity information): each
    node is ``S_wc = [[s R, t], [0, 1]]`` (``x_w = s R x_c + t``), ``edges[e] = (i, j)`` with
    measurement ``S_i_j = inv(S_wi) @ S_wj``; ``information`` is (E,) scalar weights
    (``w * I`` on GTSAM's 7-d tangent) or None for all ones. A loop edge measured after the
    loop's Sim(3) correction and tree edges measured before it disagree in scale along the
    loop; the optimiser spreads that scale correction over the graph. ``fixed`` nodes are
    held by a tight prior (sigma 1e-9) and returned verbatim; nodes no edge touches are
    returned unchanged.
    """
    poses_wc = np.asarray(poses_wc, dtype=np.float64)
    edges = np.asarray(edges, dtype=np.intp).reshape(-1, 2)
    measurements = np.asarray(measurements, dtype=np.float64).reshape(-1, 4, 4)
    n_e = edges.shape[0]
    fixed_idx = np.unique(np.asarray(fixed, dtype=np.intp).reshape(-1))

    graph = gtsam.NonlinearFactorGraph()
    w = np.ones(n_e) if information is None else np.broadcast_to(np.asarray(information, dtype=np.float64), (n_e,))
    levels, idx = np.unique(w, return_inverse=True)
    models = [gtsam.noiseModel.Isotropic.Precision(7, float(x)) for x in levels]
    for (i, j), S, li in zip(edges.tolist(), measurements, idx.tolist()):
        graph.push_back(gtsam.BetweenFactorSimilarity3(i, j, _to_similarity3(S), models[li]))

    return _solve(graph, poses_wc, edges, fixed_idx, 7, _to_similarity3, gtsam.PriorFactorSimilarity3,
                  lambda result, keys: np.array([_from_similarity3(result.atSimilarity3(k)) for k in keys.tolist()],
                                                np.float64).reshape(-1, 4, 4),
                  iterations)


def correct_points_with_poses(points_w: Array, ref_index: NDArray[np.intp], poses_before: Array,
                              poses_after: Array) -> Array:
    """Move each map point rigidly with its reference keyframe (``T_wc`` before -> after).

    ``X' = T_wc_after[r] @ inv(T_wc_before[r]) @ X``: the point keeps its coordinates in its
    reference camera, as ORB-SLAM2 does after the essential-graph optimisation.  Points with
    ``ref_index < 0`` are left where they are.
    """
    points_w = np.asarray(points_w, dtype=np.float64).reshape(-1, 3)
    ref = np.asarray(ref_index, dtype=np.intp).reshape(-1)
    D = np.asarray(poses_after, dtype=np.float64) @ invert(poses_before)  # (K, 4, 4) world motion
    ok = ref >= 0
    out = points_w.copy()
    r = ref[ok]
    out[ok] = np.einsum("pij,pj->pi", D[r, :3, :3], points_w[ok]) + D[r, :3, 3]
    return out
