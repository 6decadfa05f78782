"""Two-view initialisation of a monocular map, as ORB-SLAM3's ``TwoViewReconstruction``.

From matched (undistorted) pixels of two views, with no depth: the relative pose ``T_21``
(view 1 to view 2, ``|t| = 1``) and the points triangulated in view 1's frame, or the reason
why the two views cannot give a map that can be trusted (too little parallax, pure rotation,
an ambiguous decomposition). Pure functions of arrays.

What follows ORB-SLAM3 (``src/TwoViewReconstruction.cc``), and where:

- ``Reconstruct``: one set of 8-match samples (``iterations`` of them) shared by a homography
  and a fundamental-matrix RANSAC; the model is picked by ``R_H = S_H / (S_H + S_F)`` (the
  threshold: see below).
- ``Normalize``, ``ComputeH21``, ``ComputeF21``: the normalised 4/8-point DLTs, here batched
  over all samples with numpy.
- ``CheckHomography`` / ``CheckFundamental``: symmetric transfer and epipolar distances, chi2
  gates 5.991 (H, 2 DoF) and 3.841 (F, 1 DoF, scored against 5.991 so both scores are on one
  scale), ``sigma = 1`` px; each view's term scores on its own.
- ``ReconstructH``: Faugeras' 8 motion hypotheses (own code of the published decomposition;
  OpenCV's ``decomposeHomographyMat`` gives 4 of them, the tests check they are among ours).
- ``ReconstructF``: ``E = K^T F K`` and its 4 ``(R, t)`` (OpenCV's ``decomposeEssentialMat``).
- ``CheckRT``: triangulate (OpenCV's linear DLT), keep finite points in front of both views
  (points of parallax under ~0.36 deg are exempt from the depth test, as they easily flip),
  reprojection error under ``4 sigma^2`` in both views; count them, and their parallax.
- Acceptance, as ORB-SLAM3: F needs one clear winner (no other hypothesis above 0.7 of the
  best), H a second best under 0.75 of the best; at least ``min_triangulated`` (50) and 90 %
  of the model's inliers good; parallax over 1 deg.
- Not here: ORB-SLAM3's ``Tracking::MonocularInitialization`` asks for 100 matches before
  trying and retries with the next frame; the caller does that.

What is added, each measured against the synthetic scenes and fr2_desk of the tests:

- Model re-fits: after RANSAC the best model is re-fitted on its inliers (F by the same DLT, H
  by OpenCV's least squares with Levenberg-Marquardt) while the score rises.
- E refined before its decomposition: the Sampson error over ``(R, t)`` (5 DoF) from F's
  first hypothesis and from each of H's (2 distinct essential matrices), the best score kept;
  the 4 hypotheses of the refined E are then checked as ORB-SLAM checks F's. An 8-point F is
  not an essential matrix: decomposed as is, it left too few good points on 3-4 of 12
  synthetic scenes and failed 7 of the 10 fr2_desk pairs that succeed with the refinement; from
  F's start alone, near-planar renders at 1-2 deg of parallax ended 40-110 deg off.
  (ORB-SLAM refines the initial map with a global BA afterwards.)
- Uniqueness on the F route, since the refinement would hide F's degeneracy on a plane (ORB-SLAM
  relies on the raw F's decomposition failing there): a plane's two motions are both optima of
  the refined E with scores within ~4 %; F is refused (``planar``) when a motion over 15 deg
  away scores 0.95 of the best, and the homography route decides instead when ``R_H`` is over
  ORB-SLAM2's 0.40.
- The pose from H is not refined with the Sampson error: on a plane that cost leaves the
  translation direction free by degrees (measured 8 deg from the truth at 0.5 px).

The parallax that gates is ORB-SLAM's: the 51st-largest parallax angle of the good points
(``min(50, n-1)`` in their ascending cosines), i.e. "at least ~50 points seen at over 1 deg";
the median parallax is reported beside it.

Model selection: ``R_H > 0.50`` (ORB-SLAM3). With ORB-SLAM's scores a plane gives R_H = 0.41
at 1 px of noise per view and 0.48 at 0.5 px (closed form and measured, see the tests): F's 1-D
distances score higher than H's 2-D ones for the same fit, so a plane goes to F, is found not
unique there, and goes to H at ORB-SLAM2's 0.40. The renders' rooms at 1-2 deg of parallax score
0.41-0.47 (a wall fills much of the view): with 0.40 alone they went to H, whose decomposition
has no clear winner, until 28-41 frames; with 0.50 and F they initialise at frames 19-26. General
scenes score 0.13-0.21, fr2_desk 0.28-0.46 where it initialises.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

Array = NDArray[np.float64]

#: Chi-square 95 % gates for 2 and 1 degrees of freedom (ORB-SLAM's th and thScore).
CHI2_2DOF = 5.991
CHI2_1DOF = 3.841
#: Below this cosine of parallax (0.36 deg) a point counts as triangulated; above it a point
#: may sit behind a camera and still count as good (ORB-SLAM's CheckRT).
COS_LOW_PARALLAX = 0.99998

# Reasons a reconstruction is refused (stats count them).
TOO_FEW_MATCHES = "too_few_matches"
NO_MODEL = "no_model"
DEGENERATE_HOMOGRAPHY = "degenerate_homography"
AMBIGUOUS = "ambiguous"
TOO_FEW_TRIANGULATED = "too_few_triangulated"
LOW_PARALLAX = "low_parallax"
PLANAR = "planar"
REASONS = (TOO_FEW_MATCHES, NO_MODEL, DEGENERATE_HOMOGRAPHY, AMBIGUOUS, TOO_FEW_TRIANGULATED,
           LOW_PARALLAX, PLANAR)

#: Re-fits of the RANSAC's best model on its inliers (stopping when the score stops rising).
REFITS = 5

HOMOGRAPHY = "homography"
FUNDAMENTAL = "fundamental"


@dataclass(frozen=True)
class TwoViewParams:
    """ORB-SLAM3's constants (``TwoViewReconstruction(K, sigma=1, iterations=200)`` and
    ``Reconstruct``'s ``minParallax = 1``, ``minTriangulated = 50``)."""

    sigma: float = 1.0
    iterations: int = 200
    ratio_h: float = 0.50
    min_parallax_deg: float = 1.0
    min_triangulated: int = 50
    min_good_fraction: float = 0.9
    refine: bool = True
    #: ORB-SLAM2's R_H threshold, used when F's motion is not unique (see ``reconstruct``).
    ratio_h_fallback: float = 0.40
    #: F's motion is refused (``planar``) when a distinct motion (translation directions over
    #: ``distinct_deg`` apart, up to sign) scores at least this share of the best's score.
    #: Measured (1 px, 400 matches): the plane's two motions 0.96-1.0 of each other; the
    #: renders' wrong optima 0.91-0.99 at 1-2 deg of parallax (refused: wait a frame).
    min_unique_share: float = 0.95
    distinct_deg: float = 15.0


@dataclass(frozen=True, eq=False)
class TwoViewResult:
    """What :func:`reconstruct` found. When ``ok`` is False, ``reason`` says why and the pose
    and points are not to be used (``R`` identity, ``t`` zero, nothing triangulated).

    ``points`` is ``(N, 3)`` in view 1's frame with NaN rows where ``triangulated`` is False;
    ``inliers`` are the chosen model's; ``n_good`` the good-point counts of each hypothesis
    checked (8 for H, 4 for F; empty before decomposition)."""

    ok: bool
    reason: str
    model: str
    score_h: float
    score_f: float
    ratio_h: float
    R: Array = field(default_factory=lambda: np.eye(3))
    t: Array = field(default_factory=lambda: np.zeros(3))
    points: Array = field(default_factory=lambda: np.zeros((0, 3)))
    triangulated: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, bool))
    inliers: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, bool))
    parallax_deg: float = 0.0
    parallax_orb_deg: float = 0.0
    n_good: tuple[int, ...] = ()

    @property
    def T_21(self) -> Array:
        """View 1 to view 2, 4x4."""
        T = np.eye(4)
        T[:3, :3] = self.R
        T[:3, 3] = self.t
        return T


# --------------------------------------------------------------------------------------
# model estimation and scoring


def normalise_points(uv: Array) -> tuple[Array, Array]:
    """Points moved to zero mean and unit mean absolute deviation per axis, and the 3x3
    transform that does it (ORB-SLAM's ``Normalize``)."""
    mean = uv.mean(axis=0)
    dev = np.abs(uv - mean).mean(axis=0)
    s = 1.0 / np.where(dev > 0, dev, 1.0)
    T = np.array([[s[0], 0.0, -mean[0] * s[0]], [0.0, s[1], -mean[1] * s[1]], [0.0, 0.0, 1.0]])
    return (uv - mean) * s, T


def _null_vectors(A: Array) -> Array:
    """Right singular vectors of the smallest singular value of each ``(..., m, 9)`` system,
    as ``(..., 3, 3)`` matrices."""
    _, _, vt = np.linalg.svd(A)
    return vt[..., -1, :].reshape(A.shape[:-2] + (3, 3))


def homography_dlt(p1: Array, p2: Array) -> Array:
    """``H`` with ``p2 ~ H p1`` from ``(..., m, 2)`` correspondences, m >= 4 (ORB-SLAM's
    ``ComputeH21``: two DLT rows per match, no normalisation here)."""
    u1, v1, u2, v2 = p1[..., 0], p1[..., 1], p2[..., 0], p2[..., 1]
    zero, one = np.zeros_like(u1), np.ones_like(u1)
    r1 = np.stack([zero, zero, zero, -u1, -v1, -one, v2 * u1, v2 * v1, v2], axis=-1)
    r2 = np.stack([u1, v1, one, zero, zero, zero, -u2 * u1, -u2 * v1, -u2], axis=-1)
    A = np.concatenate([r1, r2], axis=-2)
    return _null_vectors(A)


def fundamental_dlt(p1: Array, p2: Array) -> Array:
    """``F`` with ``p2^T F p1 = 0`` from ``(..., m, 2)`` correspondences, m >= 8, rank 2
    enforced (ORB-SLAM's ``ComputeF21``)."""
    u1, v1, u2, v2 = p1[..., 0], p1[..., 1], p2[..., 0], p2[..., 1]
    A = np.stack([u2 * u1, u2 * v1, u2, v2 * u1, v2 * v1, v2, u1, v1, np.ones_like(u1)], axis=-1)
    F = _null_vectors(A)
    u, w, vt = np.linalg.svd(F)
    w[..., 2] = 0.0
    return u @ (w[..., :, None] * vt)


def _homogeneous(uv: Array) -> Array:
    return np.column_stack([uv, np.ones(len(uv))])


def _score(chi2: Array, gate: float, bonus: float) -> tuple[Array, Array]:
    """Per-view score terms ``bonus - chi2`` where ``chi2 <= gate`` (NaN fails) and which
    pass."""
    ok = chi2 <= gate  # NaN compares False: a point mapped to infinity is an outlier
    return np.where(ok, bonus - chi2, 0.0), ok


def score_homography(H21: Array, uv1: Array, uv2: Array, sigma: float = 1.0) -> tuple[Array, Array]:
    """ORB-SLAM's ``CheckHomography`` for ``(..., 3, 3)`` homographies: the score (sum over both
    transfer directions of ``5.991 - chi2`` where that direction passes) and the inliers (both
    pass), shapes ``(...)`` and ``(..., N)``."""
    x1, x2 = _homogeneous(uv1), _homogeneous(uv2)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        H12 = _safe_inverse(H21)
        inv_s2 = 1.0 / sigma**2
        p21 = np.einsum("...ij,nj->...ni", H21, x1)
        e2 = ((p21[..., :2] / p21[..., 2:3] - uv2) ** 2).sum(-1) * inv_s2
        p12 = np.einsum("...ij,nj->...ni", H12, x2)
        e1 = ((p12[..., :2] / p12[..., 2:3] - uv1) ** 2).sum(-1) * inv_s2
    s1, ok1 = _score(e1, CHI2_2DOF, CHI2_2DOF)
    s2, ok2 = _score(e2, CHI2_2DOF, CHI2_2DOF)
    return (s1 + s2).sum(-1), ok1 & ok2


def score_fundamental(F21: Array, uv1: Array, uv2: Array, sigma: float = 1.0) -> tuple[Array, Array]:
    """ORB-SLAM's ``CheckFundamental``: squared distances to the epipolar lines in both views,
    gated at 3.841 but scored against 5.991 (so a fundamental inlier is worth as much as a
    homography one that fits as well)."""
    x1, x2 = _homogeneous(uv1), _homogeneous(uv2)
    inv_s2 = 1.0 / sigma**2
    with np.errstate(divide="ignore", invalid="ignore"):
        l2 = np.einsum("...ij,nj->...ni", F21, x1)  # lines in view 2
        num2 = (l2 * x2).sum(-1)
        e2 = num2**2 / (l2[..., 0] ** 2 + l2[..., 1] ** 2) * inv_s2
        l1 = np.einsum("...ji,nj->...ni", F21, x2)  # lines in view 1
        num1 = (l1 * x1).sum(-1)
        e1 = num1**2 / (l1[..., 0] ** 2 + l1[..., 1] ** 2) * inv_s2
    s1, ok1 = _score(e1, CHI2_1DOF, CHI2_2DOF)
    s2, ok2 = _score(e2, CHI2_1DOF, CHI2_2DOF)
    return (s1 + s2).sum(-1), ok1 & ok2


def _safe_inverse(M: Array) -> Array:
    """Inverses of ``(..., 3, 3)`` matrices, NaN for singular ones (a degenerate sample must
    score zero, not stop the RANSAC)."""
    det = np.linalg.det(M)
    good = np.isfinite(det) & (np.abs(det) > 1e-300)
    out = np.full(M.shape, np.nan)
    if np.any(good):
        out[good] = np.linalg.inv(M[good])
    return out


def sample_sets(n: int, iterations: int, rng: np.random.Generator) -> NDArray[np.intp]:
    """``(iterations, 8)`` indices, 8 distinct matches per set (ORB-SLAM draws one list of
    sets and gives it to both models)."""
    keys = rng.random((iterations, n))
    return np.argpartition(keys, 7, axis=1)[:, :8]


@dataclass(frozen=True, eq=False)
class ModelFit:
    matrix: Array
    score: float
    inliers: NDArray[np.bool_]


def _best_fit(matrices: Array, scorer: Callable[..., tuple[Array, Array]], uv1: Array, uv2: Array, sigma: float) -> ModelFit:
    scores, inl = scorer(matrices, uv1, uv2, sigma)
    scores = np.where(np.isfinite(scores), scores, 0.0)
    i = int(np.argmax(scores))
    return ModelFit(matrices[i], float(scores[i]), inl[i])


def find_homography(uv1: Array, uv2: Array, sets: NDArray[np.intp], sigma: float = 1.0,
                    refine: bool = True) -> ModelFit:
    """ORB-SLAM's ``FindHomography`` on the given sample sets (normalised 8-point DLT, best
    score wins), then optionally a re-fit on the inliers kept if it scores no worse."""
    n1, T1 = normalise_points(uv1)
    n2, T2 = normalise_points(uv2)
    Hn = homography_dlt(n1[sets], n2[sets])
    H = np.linalg.inv(T2) @ Hn @ T1
    best = _best_fit(H, score_homography, uv1, uv2, sigma)
    for _ in range(REFITS if refine else 0):
        if best.inliers.sum() < 8:
            break
        # OpenCV's least-squares fit on the inliers (DLT, then Levenberg-Marquardt on the
        # transfer error): more accurate than the algebraic DLT alone.
        Hr, _ = cv2.findHomography(uv1[best.inliers], uv2[best.inliers], 0)
        if Hr is None:
            break
        again = _best_fit(Hr[None], score_homography, uv1, uv2, sigma)
        if again.score <= best.score:
            break
        best = again
    return best


def find_fundamental(uv1: Array, uv2: Array, sets: NDArray[np.intp], sigma: float = 1.0,
                     refine: bool = True) -> ModelFit:
    """ORB-SLAM's ``FindFundamental`` on the same sample sets, with the same optional re-fit."""
    n1, T1 = normalise_points(uv1)
    n2, T2 = normalise_points(uv2)
    F = T2.T @ fundamental_dlt(n1[sets], n2[sets]) @ T1
    best = _best_fit(F, score_fundamental, uv1, uv2, sigma)
    for _ in range(REFITS if refine else 0):
        if best.inliers.sum() < 8:
            break
        Fr = T2.T @ fundamental_dlt(n1[best.inliers], n2[best.inliers]) @ T1
        again = _best_fit(Fr[None], score_fundamental, uv1, uv2, sigma)
        if again.score <= best.score:
            break
        best = again
    return best


# --------------------------------------------------------------------------------------
# motion hypotheses


def decompose_homography(H21: Array, K: Array) -> tuple[list[Array], list[Array]] | None:
    """Faugeras' 8 ``(R, t)`` hypotheses (``|t| = 1``) of the calibrated homography
    ``K^-1 H K`` (ORB-SLAM's ``ReconstructH``), or None when two singular values coincide (a
    pure rotation, or a degenerate H: the decomposition is then undefined)."""
    A = np.linalg.inv(K) @ H21 @ K
    U, d, Vt = np.linalg.svd(A)
    s = np.linalg.det(U) * np.linalg.det(Vt)
    d1, d2, d3 = d
    if d1 / d2 < 1.00001 or d2 / d3 < 1.00001:
        return None
    den = d1 * d1 - d3 * d3
    x1 = np.sqrt((d1 * d1 - d2 * d2) / den)
    x3 = np.sqrt((d2 * d2 - d3 * d3) / den)
    root = np.sqrt((d1 * d1 - d2 * d2) * (d2 * d2 - d3 * d3))
    rotations, translations = [], []
    for e1, e3 in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
        # d' = +d2: rotation about the second axis by theta, translation (x1, 0, -x3).
        st, ct = e1 * e3 * root / ((d1 + d3) * d2), (d2 * d2 + d1 * d3) / ((d1 + d3) * d2)
        Rp = np.array([[ct, 0.0, -st], [0.0, 1.0, 0.0], [st, 0.0, ct]])
        rotations.append(s * U @ Rp @ Vt)
        translations.append(U @ np.array([e1 * x1, 0.0, -e3 * x3]) * (d1 - d3))
    for e1, e3 in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
        # d' = -d2: a reflection-like Rp (still a rotation), translation (x1, 0, x3).
        sp, cp = e1 * e3 * root / ((d1 - d3) * d2), (d1 * d3 - d2 * d2) / ((d1 - d3) * d2)
        Rp = np.array([[cp, 0.0, sp], [0.0, -1.0, 0.0], [sp, 0.0, -cp]])
        rotations.append(s * U @ Rp @ Vt)
        translations.append(U @ np.array([e1 * x1, 0.0, e3 * x3]) * (d1 + d3))
    translations = [t / np.linalg.norm(t) for t in translations]
    return rotations, translations


def decompose_essential(E: Array) -> tuple[list[Array], list[Array]]:
    """The 4 ``(R, t)`` of an essential matrix (ORB-SLAM's ``DecomposeE``: two rotations,
    ``±t``)."""
    R1, R2, t = cv2.decomposeEssentialMat(E)
    t = t.ravel() / np.linalg.norm(t)
    return [R1, R2, R1, R2], [t, t, -t, -t]


@dataclass(frozen=True, eq=False)
class RTCheck:
    """One hypothesis checked: how many good points, which are triangulated (good and seen
    with parallax), the points, ORB-SLAM's parallax statistic and the median (degrees)."""

    n_good: int
    triangulated: NDArray[np.bool_]
    points: Array
    parallax_orb_deg: float
    parallax_median_deg: float


def check_rt(R: Array, t: Array, uv1: Array, uv2: Array, K: Array, use: NDArray[np.bool_],
             th2: float) -> RTCheck:
    """ORB-SLAM's ``CheckRT``: triangulate the matches ``use`` selects with view 1 at the
    origin and view 2 at ``(R, t)``; a point is good when finite, in front of both views
    (unless its parallax is under 0.36 deg) and reprojected within ``sqrt(th2)`` px in both.
    Good points with parallax are the triangulated ones."""
    n = len(uv1)
    P1 = K @ np.hstack([np.eye(3), np.zeros((3, 1))])
    P2 = K @ np.hstack([R, t.reshape(3, 1)])
    idx = np.flatnonzero(use)
    points = np.full((n, 3), np.nan)
    triangulated = np.zeros(n, bool)
    if len(idx) == 0:
        return RTCheck(0, triangulated, points, 0.0, 0.0)
    Xh = cv2.triangulatePoints(P1, P2, uv1[idx].T.astype(np.float64), uv2[idx].T.astype(np.float64))
    with np.errstate(divide="ignore", invalid="ignore"):
        X1 = (Xh[:3] / Xh[3]).T
        finite = np.all(np.isfinite(X1), axis=1)
        X1 = np.where(finite[:, None], X1, 0.0)
        O2 = -R.T @ t
        r1, r2 = X1, X1 - O2
        cos_par = (r1 * r2).sum(1) / (np.linalg.norm(r1, axis=1) * np.linalg.norm(r2, axis=1))
        X2 = X1 @ R.T + t
        low = ~(cos_par < COS_LOW_PARALLAX)  # NaN cosines count as no parallax
        front = ((X1[:, 2] > 0) & (X2[:, 2] > 0)) | low
        proj1 = X1 @ K.T
        proj2 = X2 @ K.T
        err1 = ((proj1[:, :2] / proj1[:, 2:3] - uv1[idx]) ** 2).sum(1)
        err2 = ((proj2[:, :2] / proj2[:, 2:3] - uv2[idx]) ** 2).sum(1)
    good = finite & front & (err1 <= th2) & (err2 <= th2)
    n_good = int(good.sum())
    tri = good & ~low
    triangulated[idx[tri]] = True
    points[idx[tri]] = X1[tri]
    if n_good == 0:
        return RTCheck(0, triangulated, points, 0.0, 0.0)
    cos_sorted = np.sort(np.clip(cos_par[good], -1.0, 1.0))
    par_orb = float(np.degrees(np.arccos(cos_sorted[min(50, n_good - 1)])))
    par_med = float(np.degrees(np.arccos(np.median(cos_sorted))))
    return RTCheck(n_good, triangulated, points, par_orb, par_med)


def _skew(v: Array) -> Array:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def sampson_residuals(R: Array, t: Array, uv1: Array, uv2: Array, K: Array) -> Array:
    """Signed Sampson distances (pixels) of matches to the epipolar geometry of ``(R, t)``:
    the first-order reprojection error of a match against ``F = K^-T [t]x R K^-1``."""
    Kinv = np.linalg.inv(K)
    F = Kinv.T @ _skew(t) @ R @ Kinv
    x1, x2 = _homogeneous(uv1), _homogeneous(uv2)
    Fx1 = x1 @ F.T
    Ftx2 = x2 @ F
    num = (x2 * Fx1).sum(1)
    den = np.sqrt(Fx1[:, 0] ** 2 + Fx1[:, 1] ** 2 + Ftx2[:, 0] ** 2 + Ftx2[:, 1] ** 2)
    return num / np.where(den > 0, den, np.inf)


def refine_pose(R: Array, t: Array, uv1: Array, uv2: Array, K: Array, sigma: float = 1.0
                ) -> tuple[Array, Array]:
    """``(R, t)`` (``|t| = 1``) minimising the Sampson distances of the matches that agree with
    it, from ``(R, t)``: 5 DoF (a rotation increment and ``t`` on the unit sphere). A Cauchy
    loss over all matches first (outliers fade), then a Huber fit on those within 3 sigma:
    a consensus set taken from the RANSAC model's own gate would be biased towards it.

    Not in ``TwoViewReconstruction``: ORB-SLAM refines the initial map with a global bundle
    adjustment right after (``Tracking::CreateInitialMapMonocular``); this two-view
    equivalent lets the geometry module return a pose as accurate as its matches allow."""
    t = t / np.linalg.norm(t)
    # Two directions orthogonal to t span the sphere's tangent plane.
    _, _, vt = np.linalg.svd(t.reshape(1, 3))
    b1, b2 = vt[1], vt[2]

    def unpack(x: Array) -> tuple[Array, Array]:
        Ri = Rotation.from_rotvec(x[:3]).as_matrix() @ R
        ti = t + x[3] * b1 + x[4] * b2
        return Ri, ti / np.linalg.norm(ti)

    x = np.zeros(5)
    sel = np.ones(len(uv1), bool)
    for loss in ("cauchy", "huber"):
        def fun(x: Array, sel: NDArray[np.bool_] = sel) -> Array:
            return sampson_residuals(*unpack(x), uv1[sel], uv2[sel], K)

        x = least_squares(fun, x, loss=loss, f_scale=sigma, x_scale=1e-2).x
        sel = np.abs(sampson_residuals(*unpack(x), uv1, uv2, K)) < 3.0 * sigma
        if sel.sum() < 8:
            break
    return unpack(x)


@dataclass(frozen=True, eq=False)
class Motion:
    """A refined ``(R, t)`` and its epipolar score (ORB-SLAM's ``CheckFundamental`` of
    ``F = K^-T [t]x R K^-1``)."""

    R: Array
    t: Array
    score: float


def essential_optima(F21: Array, H21: Array, uv1: Array, uv2: Array, K: Array, sigma: float = 1.0
                     ) -> list[Motion]:
    """The Sampson-refined motions reached from F's essential matrix and from each of H's
    motion hypotheses, best score first. Near a plane, F's 8-point estimate is poorly
    determined and one start can end in the wrong one of several optima (measured on renders
    at 1-2 deg of parallax: 110 deg off in translation from F's start alone); H's hypotheses
    start next to the plane's motions, which the score then ranks."""
    R_f, t_f = decompose_essential(K.T @ F21 @ K)
    starts = [(R_f[0], t_f[0])]
    hyp_h = decompose_homography(H21, K)
    essentials = [_unit_essential(R_f[0], t_f[0])]
    for R0, t0 in zip(*hyp_h) if hyp_h is not None else ():
        # H's 8 hypotheses are 2 essential matrices up to sign (the same Sampson cost).
        E = _unit_essential(R0, t0)
        if all(abs(float((E * other).sum())) < 0.9999 for other in essentials):
            essentials.append(E)
            starts.append((R0, t0))
    Kinv = np.linalg.inv(K)
    optima = []
    for R0, t0 in starts:
        R, t = refine_pose(R0, t0, uv1, uv2, K, sigma)
        score, _ = score_fundamental(Kinv.T @ _skew(t) @ R @ Kinv, uv1, uv2, sigma)
        optima.append(Motion(R, t, float(score)))
    return sorted(optima, key=lambda m: -m.score)


def _unit_essential(R: Array, t: Array) -> Array:
    E = _skew(t) @ R
    return E / np.linalg.norm(E)


def unique_motion(optima: list[Motion], min_share: float, distinct_deg: float) -> bool:
    """Whether the best motion is the data's only good one: no other optimum whose translation
    direction is over ``distinct_deg`` away (up to sign: the sign is the cheirality test's)
    scores ``min_share`` of the best. A plane's two motions fit its matches equally (F's route
    cannot tell them apart); ORB-SLAM's ReconstructF asks the same of E's 4 hypotheses."""
    best = optima[0]
    cos_max = np.cos(np.radians(distinct_deg))
    for other in optima[1:]:
        if abs(float(other.t @ best.t)) < cos_max and other.score >= min_share * best.score:
            return False
    return True


# --------------------------------------------------------------------------------------
# reconstruction


def reconstruct(uv1: ArrayLike, uv2: ArrayLike, K: ArrayLike,
                rng_or_seed: np.random.Generator | int | None = 0,
                params: TwoViewParams | None = None) -> TwoViewResult:
    """Relative pose and initial points from matched undistorted pixels ``uv1[i] <-> uv2[i]``
    (``(N, 2)`` each) of two views with intrinsics ``K`` (ORB-SLAM3's
    ``TwoViewReconstruction::Reconstruct``). Always returns a result; check ``ok``."""
    p = params or TwoViewParams()
    rng = rng_or_seed if isinstance(rng_or_seed, np.random.Generator) else np.random.default_rng(rng_or_seed)
    uv1 = np.asarray(uv1, np.float64).reshape(-1, 2)
    uv2 = np.asarray(uv2, np.float64).reshape(-1, 2)
    K = np.asarray(K, np.float64)
    if len(uv1) != len(uv2):
        raise ValueError(f"reconstruct: {len(uv1)} points in view 1 but {len(uv2)} in view 2")
    n = len(uv1)
    empty = dict(points=np.full((n, 3), np.nan), triangulated=np.zeros(n, bool),
                 inliers=np.zeros(n, bool))
    # Fewer matches than the good points required can never initialise.
    if n < max(8, p.min_triangulated):
        return TwoViewResult(False, TOO_FEW_MATCHES, "", 0.0, 0.0, 0.0, **empty)

    sets = sample_sets(n, p.iterations, rng)
    fit_h = find_homography(uv1, uv2, sets, p.sigma, p.refine)
    fit_f = find_fundamental(uv1, uv2, sets, p.sigma, p.refine)
    total = fit_h.score + fit_f.score
    if total <= 0.0:
        return TwoViewResult(False, NO_MODEL, "", fit_h.score, fit_f.score, 0.0, **empty)
    ratio = fit_h.score / total
    use_h = ratio > p.ratio_h
    model = HOMOGRAPHY if use_h else FUNDAMENTAL
    fit = fit_h if use_h else fit_f
    head = dict(model=model, score_h=fit_h.score, score_f=fit_f.score, ratio_h=ratio)
    empty["inliers"] = fit.inliers

    if not use_h:
        if not p.refine:
            hyp = decompose_essential(K.T @ fit.matrix @ K)
        else:
            # The 4 hypotheses share one E: refining it on the essential manifold (from every
            # start, the best optimum) refines E, and the refined E's decomposition is checked
            # as ORB-SLAM checks F's.
            optima = essential_optima(fit_f.matrix, fit_h.matrix, uv1, uv2, K, p.sigma)
            if not unique_motion(optima, p.min_unique_share, p.distinct_deg):
                if ratio <= p.ratio_h_fallback:
                    return TwoViewResult(False, PLANAR, **head, **empty)
                # Near a plane (ORB-SLAM2 would take H here): H's cheirality may tell them apart.
                use_h, model, fit = True, HOMOGRAPHY, fit_h
                head["model"], empty["inliers"] = model, fit.inliers
            else:
                hyp = decompose_essential(_skew(optima[0].t) @ optima[0].R)
    if use_h:
        hyp = decompose_homography(fit.matrix, K)
        if hyp is None:
            return TwoViewResult(False, DEGENERATE_HOMOGRAPHY, **head, **empty)
    th2 = 4.0 * p.sigma**2
    checks = [check_rt(R, t, uv1, uv2, K, fit.inliers, th2) for R, t in zip(*hyp)]
    n_good = tuple(c.n_good for c in checks)
    order = np.argsort(n_good, kind="stable")[::-1]
    best, second = int(order[0]), n_good[order[1]]
    max_good = n_good[best]
    n_in = int(fit.inliers.sum())
    empty["n_good"] = n_good

    # A clear winner: ReconstructF counts hypotheses over 0.7 of the best (only the best may
    # be), ReconstructH wants the second best under 0.75 of it.
    clear = second < 0.75 * max_good if use_h else second <= 0.7 * max_good
    if max_good == 0 or not clear:
        return TwoViewResult(False, AMBIGUOUS, **head, **empty)
    if max_good < max(int(p.min_good_fraction * n_in), p.min_triangulated):
        return TwoViewResult(False, TOO_FEW_TRIANGULATED, **head, **empty)
    c = checks[best]
    if c.parallax_orb_deg < p.min_parallax_deg:
        return TwoViewResult(False, LOW_PARALLAX, **head, **{**empty, "parallax_deg": c.parallax_median_deg,
                                                            "parallax_orb_deg": c.parallax_orb_deg})
    R, t = hyp[0][best], hyp[1][best]
    return TwoViewResult(True, "", **head, R=R, t=t, points=c.points,
                         triangulated=c.triangulated, inliers=fit.inliers,
                         parallax_deg=c.parallax_median_deg, parallax_orb_deg=c.parallax_orb_deg,
                         n_good=n_good)


def normalise_initial_map(points_1: ArrayLike, T_21: ArrayLike) -> tuple[Array, Array, float]:
    """Scale the initial map so that view 1's median scene depth is 1, and the translation of
    ``T_21`` with it (ORB-SLAM3's ``CreateInitialMapMonocular``: ``invMedianDepth = 1 /
    ComputeSceneMedianDepth(2)``). NaN rows (untriangulated) are ignored and kept. Returns the
    points, ``T_21`` and the scale applied; raises ValueError when no point has positive
    median depth (ORB-SLAM resets the initialisation then)."""
    P = np.asarray(points_1, np.float64).reshape(-1, 3)
    T = np.array(T_21, np.float64)
    z = P[:, 2][np.isfinite(P[:, 2])]
    if len(z) == 0:
        raise ValueError("normalise_initial_map: no triangulated point")
    median = float(np.median(z))
    if not median > 0:
        raise ValueError(f"normalise_initial_map: median depth {median} is not positive")
    scale = 1.0 / median
    T[:3, 3] *= scale
    return P * scale, T, scale
