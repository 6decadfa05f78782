"""The body's velocity and the IMU biases re-estimated on a window of recent tracked frames:
a GTSAM graph of ``CombinedImuFactor`` between consecutive frames (bias random walk
included), the tracked poses as priors, and the last estimate as a prior on the window's
first velocity and bias (a fixed-lag smoother whose marginal is approximated by the last
estimate's spread: the window slides a frame at a time, so it is seen many times).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import gtsam
import numpy as np
from numpy.typing import NDArray

from semslam.backend.imu_preintegration import bias_from, imu_params, predict, preintegrate_chain
from semslam.core.imu import ImuNoise, ImuSamples

Array = NDArray[np.float64]

#: A tracked pose's spread as a prior (rotation rad, translation m; GTSAM's Pose3 tangent order).
POSE_SIGMAS = np.array([0.003, 0.003, 0.003, 0.005, 0.005, 0.005])
#: The last estimate as a prior on the window's first velocity and bias.
VELOCITY_PRIOR_MPS = 0.1
GYRO_BIAS_PRIOR = 0.001
ACC_BIAS_PRIOR = 0.01
#: A bridge's priors: the start velocity as the window knows it (~1-2 cm/s), the biases
#: about the estimate (the accelerometer's as loose as a short initialisation leaves it).
BRIDGE_VELOCITY = 0.02
BRIDGE_ACC_BIAS = 0.05
BRIDGE_GYRO_BIAS = 0.002


@dataclass(frozen=True)
class WindowEstimate:
    velocities: Array  # (N, 3), one per window frame
    gyro_bias: Array  # at the newest frame
    acc_bias: Array
    #: The solution's squared normalised residuals per residual dimension (~1 when the poses
    #: and the readings agree; large when a pose is wrong or the readings do not fit).
    chi2_per_dim: float


def _x(i: int) -> int:
    return gtsam.symbol("x", i)


def _v(i: int) -> int:
    return gtsam.symbol("v", i)


def _b(i: int) -> int:
    return gtsam.symbol("b", i)


@lru_cache(maxsize=16)
def _zero_biases(n: int) -> gtsam.Values:
    """Keys b0..b(n-1) at the zero bias (never modified: ``_biases`` retracts a copy)."""
    values = gtsam.Values()
    for i in range(n):
        values.insert(_b(i), gtsam.imuBias.ConstantBias())
    return values


def _biases(n: int, bias: gtsam.imuBias.ConstantBias) -> gtsam.Values:
    """Keys b0..b(n-1) all at ``bias``: the zero biases retracted by it (a bias retracts by
    adding, so exactly ``bias``), as inserting a bias through ``Values.insert`` costs ~30 us
    of overload dispatch each, twenty times this."""
    delta = gtsam.VectorValues()
    vec = bias.vector()
    for i in range(n):
        delta.insert(_b(i), vec)
    return _zero_biases(n).retract(delta)


def _imu_chain(times: Array, samples: ImuSamples, noise: ImuNoise, gravity_w: Array,
               bias: gtsam.imuBias.ConstantBias, v_first: Array, velocity_sigma: float, acc_bias_sigma: float,
               gyro_bias_sigma: float) -> tuple[gtsam.NonlinearFactorGraph, list[gtsam.PreintegratedCombinedMeasurements]]:
    """A graph of ``CombinedImuFactor`` between consecutive ``times`` (keys x/v/b per frame),
    with priors on the first velocity and bias; and the preintegrations it was built from."""
    graph = gtsam.NonlinearFactorGraph()
    pims = preintegrate_chain(imu_params(noise, gravity_w), [bias], samples, times)[0]
    for i, pim in enumerate(pims, start=1):
        graph.add(gtsam.CombinedImuFactor(_x(i - 1), _v(i - 1), _x(i), _v(i), _b(i - 1), _b(i), pim))
    graph.add(gtsam.PriorFactorVector(_v(0), np.asarray(v_first, dtype=np.float64),
                                      gtsam.noiseModel.Isotropic.Sigma(3, velocity_sigma)))
    graph.add(gtsam.PriorFactorConstantBias(_b(0), bias, gtsam.noiseModel.Diagonal.Sigmas(
        np.array([acc_bias_sigma] * 3 + [gyro_bias_sigma] * 3))))
    return graph, pims


def refine_window(times: Array, T_wb: Array, samples: ImuSamples, noise: ImuNoise, gravity_w: Array,
                  v_first: Array, gyro_bias: Array, acc_bias: Array) -> WindowEstimate:
    """Velocities at ``times`` (body poses ``T_wb``, N >= 2) and the biases, starting from
    (and weakly held to) the first frame's velocity ``v_first`` and the given biases."""
    n = len(times)
    bias0 = bias_from(gyro_bias, acc_bias)
    graph, _ = _imu_chain(times, samples, noise, gravity_w, bias0, v_first, VELOCITY_PRIOR_MPS,
                          ACC_BIAS_PRIOR, GYRO_BIAS_PRIOR)
    values = gtsam.Values()
    values.insert(_biases(n, bias0))
    pose_noise = gtsam.noiseModel.Diagonal.Sigmas(POSE_SIGMAS)
    v = np.asarray(v_first, dtype=np.float64).copy()
    for i in range(n):
        pose = gtsam.Pose3(np.ascontiguousarray(T_wb[i]))
        graph.add(gtsam.PriorFactorPose3(_x(i), pose, pose_noise))
        values.insert(_x(i), pose)
        if i > 0:
            dt = times[i] - times[i - 1]
            v = (T_wb[i, :3, 3] - T_wb[i - 1, :3, 3]) / dt if dt > 0 else v
        values.insert(_v(i), v)
    result = gtsam.LevenbergMarquardtOptimizer(graph, values, gtsam.LevenbergMarquardtParams()).optimize()
    vel = np.array([result.atVector(_v(i)) for i in range(n)])
    b = result.atConstantBias(_b(n - 1))
    dims = 6 * n + 15 * (n - 1) + 9
    return WindowEstimate(vel, np.asarray(b.gyroscope()), np.asarray(b.accelerometer()),
                          2.0 * graph.error(result) / dims)


def bridge(times: Array, T_wb_start: Array, v_start: Array, T_wb_end: Array, samples: ImuSamples,
           noise: ImuNoise, gravity_w: Array, gyro_bias: Array, acc_bias: Array) -> Array:
    """Body poses at ``times`` (N >= 3) between two tracked ones, the first (with its
    velocity) at ``times[0]`` and the last at ``times[-1]``: the readings' path held at both
    ends (a smoother's answer for frames the IMU posed alone, where the path carried forward
    from the start drifts with any error in its velocity or biases). With the start's
    velocity known, where the path must end tells how far off the accelerometer's bias is:
    the bias is free about the given one (``BRIDGE_ACC_BIAS``), the start velocity held
    to the window's accuracy (``BRIDGE_VELOCITY``)."""
    n = len(times)
    bias = bias_from(gyro_bias, acc_bias)
    graph, pims = _imu_chain(times, samples, noise, gravity_w, bias, v_start, BRIDGE_VELOCITY,
                             BRIDGE_ACC_BIAS, BRIDGE_GYRO_BIAS)
    values = gtsam.Values()
    values.insert(_biases(n, bias))
    pose_noise = gtsam.noiseModel.Diagonal.Sigmas(POSE_SIGMAS)
    graph.add(gtsam.PriorFactorPose3(_x(0), gtsam.Pose3(np.ascontiguousarray(T_wb_start)), pose_noise))
    graph.add(gtsam.PriorFactorPose3(_x(n - 1), gtsam.Pose3(np.ascontiguousarray(T_wb_end)), pose_noise))
    T, v = np.asarray(T_wb_start, dtype=np.float64), np.asarray(v_start, dtype=np.float64)
    for i in range(n):
        if i > 0:  # the readings carried forward: where the solver starts
            T, v = predict(pims[i - 1], T, v, bias)
        values.insert(_x(i), gtsam.Pose3(np.ascontiguousarray(T)))
        values.insert(_v(i), v)
    result = gtsam.LevenbergMarquardtOptimizer(graph, values, gtsam.LevenbergMarquardtParams()).optimize()
    return np.array([result.atPose3(_x(i)).matrix() for i in range(n)])
