"""Conversions between the numpy conventions of semslam and GTSAM objects.

semslam keeps camera poses as 4x4 ``T_cw`` (world -> camera, ORB-SLAM's Tcw), while GTSAM's
camera factors (``GenericStereoFactor3D``, ``GenericProjectionFactorCal3_S2``) expect the camera
pose in the world, ``T_wc``.  All conversions live here so the direction is decided once.

Keys are plain integers (poses ``0..K-1``, points ``K..K+P-1``) rather than ``gtsam.Symbol``: small
integers survive the float64 key arrays of ``gtsam.utilities.insertProjectionFactors`` exactly, and
``Values`` iterates them in index order, so ``utilities.extractPose3``/``extractPoint3`` return
rows in our array order without a Python loop.
"""

from __future__ import annotations

from functools import lru_cache

import gtsam
import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

#: chi2 quantiles (95 %) used by ORB-SLAM for 2-DoF (monocular) and 3-DoF (stereo) residuals.
CHI2_MONO = 5.991
CHI2_STEREO = 7.815


def pose3_from_matrix(T: Array) -> gtsam.Pose3:
    """``gtsam.Pose3`` from a 4x4 matrix (same transform, no inversion)."""
    return gtsam.Pose3(np.ascontiguousarray(T, dtype=np.float64))


def matrix_from_pose3(p: gtsam.Pose3) -> Array:
    """4x4 matrix of a ``gtsam.Pose3``."""
    return np.asarray(p.matrix(), dtype=np.float64)


def poses_from_rows(rows: Array) -> Array:
    """(N, 4, 4) poses from the (N, 12) rows of ``gtsam.utilities.extractPose3``.

    GTSAM writes each row as the 3x3 rotation row-major followed by the translation.
    """
    rows = np.asarray(rows, dtype=np.float64).reshape(-1, 12)
    out = np.zeros((rows.shape[0], 4, 4))
    out[:, :3, :3] = rows[:, :9].reshape(-1, 3, 3)
    out[:, :3, 3] = rows[:, 9:]
    out[:, 3, 3] = 1.0
    return out


def stereo_calibration(fx: float, fy: float, cx: float, cy: float,
                       bf: float) -> gtsam.Cal3_S2Stereo:
    """``Cal3_S2Stereo`` for the virtual RGB-D stereo rig: baseline = bf / fx (uR = uL - bf / z)."""
    return gtsam.Cal3_S2Stereo(float(fx), float(fy), 0.0, float(cx), float(cy),
                               float(bf) / float(fx))


def mono_calibration(fx: float, fy: float, cx: float, cy: float) -> gtsam.Cal3_S2:
    """``Cal3_S2`` without skew."""
    return gtsam.Cal3_S2(float(fx), float(fy), 0.0, float(cx), float(cy))


@lru_cache(maxsize=256)
def obs_noise(dim: int, inv_sigma2: float, robust: bool) -> gtsam.noiseModel.Base:
    """Isotropic noise of information ``inv_sigma2`` on a ``dim``-residual, Huber-wrapped if robust.

    Cached: there are only as many distinct ``inv_sigma2`` as pyramid octaves, so building one
    model per observation would be pure overhead.  The Huber threshold is ORB-SLAM's
    sqrt(chi2_95 %) for the residual dimension, applied to the whitened residual norm exactly as
    g2o's ``RobustKernelHuber`` is applied to sqrt(chi2).
    """
    base = gtsam.noiseModel.Isotropic.Sigma(dim, float(1.0 / np.sqrt(inv_sigma2)))
    if not robust:
        return base
    delta = float(np.sqrt(CHI2_STEREO if dim == 3 else CHI2_MONO))
    return gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(delta), base)


def lm_params(max_iterations: int, tight: bool = False) -> gtsam.LevenbergMarquardtParams:
    """LM parameters; ``tight`` drives convergence to numerical precision (reference solves)."""
    p = gtsam.LevenbergMarquardtParams()
    p.setMaxIterations(int(max_iterations))
    if tight:
        p.setRelativeErrorTol(1e-15)
        p.setAbsoluteErrorTol(1e-15)
    return p
