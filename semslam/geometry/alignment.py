"""Least-squares similarity alignment of point sets (Umeyama 1991).

Used to express an estimated trajectory in the ground-truth frame before computing ATE.
The result matches evo's ``geometry.umeyama_alignment`` (same equations, same reflection
handling), so ATE numbers agree with evo.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from semslam.errors import EvalError

Array = NDArray[np.float64]


class AlignmentError(EvalError, ValueError):
    """The points do not determine an alignment (too few, colinear, not finite)."""


def umeyama(src: ArrayLike, dst: ArrayLike, with_scale: bool) -> tuple[Array, Array, float]:
    """Rotation ``R``, translation ``t`` and scale ``s`` minimising ``||dst - (s R src + t)||``.

    ``src`` and ``dst`` are corresponding points ``(N, 3)``. With ``with_scale=False`` the
    scale is fixed to 1 (SE(3) alignment). ``R`` is always a proper rotation (det +1): a
    reflection would fit mirrored data better but is not a camera motion.

    Raises :class:`AlignmentError` (an ``EvalError``) for fewer than 3 points or colinear
    points, where the rotation about the line is undetermined.
    """
    x = np.asarray(src, dtype=np.float64)
    y = np.asarray(dst, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 3 or x.shape != y.shape:
        raise AlignmentError(
            f"alignment needs two (N, 3) point arrays of equal shape, got {x.shape} and {y.shape}"
        )
    n = x.shape[0]
    if n < 3:
        raise AlignmentError(f"alignment needs at least 3 corresponding points, got {n}")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        raise AlignmentError("alignment input contains nan or inf")

    mean_x = x.mean(axis=0)
    mean_y = y.mean(axis=0)
    xc = x - mean_x
    yc = y - mean_y
    var_x = float(np.sum(xc * xc)) / n  # eq. 36
    cov = yc.T @ xc / n  # eq. 38: sum of (y_i - mu_y)(x_i - mu_x)^T / n

    u, d, vt = np.linalg.svd(cov)
    # Rank < 2 means the points (either set) lie on a line or collapse to a point: the
    # rotation about that line is arbitrary. The test is relative so it does not depend on
    # units (evo compares with machine epsilon in absolute terms).
    if d[0] <= 0.0 or d[1] <= d[0] * 1e-12:
        raise AlignmentError(
            f"cannot align {n} points: they are colinear or coincide (degenerate covariance)"
        )

    sign = np.ones(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0.0:
        sign[2] = -1.0  # eq. 43: keep a right-handed rotation
    rot = (u * sign) @ vt  # eq. 40
    scale = float(np.sum(d * sign) / var_x) if with_scale else 1.0  # eq. 42
    trans = mean_y - scale * rot @ mean_x  # eq. 41
    return rot, trans, scale


def sim3_matrix(rot: ArrayLike, trans: ArrayLike, scale: float = 1.0) -> Array:
    """4x4 similarity ``[[s R, t], [0, 1]]``."""
    m = np.eye(4)
    m[:3, :3] = scale * np.asarray(rot, dtype=np.float64)
    m[:3, 3] = np.asarray(trans, dtype=np.float64)
    return m


def apply_sim3(poses: ArrayLike, rot: ArrayLike, trans: ArrayLike, scale: float = 1.0) -> Array:
    """Apply ``x -> s R x + t`` to camera-to-world poses ``(N, 4, 4)``.

    Positions become ``s R p + t`` and orientations ``R R_wc``; the result stays a rigid
    pose (the scale only acts on positions), as evo's ``align(correct_scale=True)`` does.
    """
    p = np.asarray(poses, dtype=np.float64)
    r = np.asarray(rot, dtype=np.float64)
    out = np.zeros_like(p)
    out[..., :3, :3] = r @ p[..., :3, :3]
    out[..., :3, 3] = (scale * p[..., :3, 3]) @ r.T + np.asarray(trans, dtype=np.float64)
    out[..., 3, 3] = 1.0
    return out
