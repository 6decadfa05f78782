"""IMU preintegration on GTSAM (``PreintegratedCombinedMeasurements``) between two times.

GTSAM integrates a reading over a time step as constant. Readings come at their own times,
not at the frames', so each step here is the stretch between two consecutive readings
clipped to [t0, t1], integrated with the mean of the readings linearly interpolated at the
stretch's two ends (ORB-SLAM3's ``IntegrateNewMeasurement`` averages consecutive readings
the same way): second-order accurate where holding one reading is first-order.

Poses are the IMU (body) frame's in the world, ``T_wb``; the camera's is ``T_wb @ T_bc``.
Gravity is a vector in the world frame (the map's frame need not be gravity-aligned).
"""

from __future__ import annotations

import gtsam
import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from semslam.core.imu import ImuNoise, ImuSamples

Array = NDArray[np.float64]

#: Integration (position from velocity) noise, GTSAM's usual small value: the model is exact.
INTEGRATION_SIGMA = 1e-4


def imu_params(noise: ImuNoise, gravity_w: Array) -> gtsam.PreintegrationCombinedParams:
    """GTSAM's parameters: continuous-time noise densities squared (GTSAM discretises them
    by the step), bias random walks, and gravity in the world frame."""
    p = gtsam.PreintegrationCombinedParams(np.asarray(gravity_w, dtype=np.float64).reshape(3, 1))
    eye = np.eye(3)
    p.setGyroscopeCovariance(noise.gyro_noise_density**2 * eye)
    p.setAccelerometerCovariance(noise.acc_noise_density**2 * eye)
    p.setIntegrationCovariance(INTEGRATION_SIGMA**2 * eye)
    p.setBiasOmegaCovariance(noise.gyro_random_walk**2 * eye)
    p.setBiasAccCovariance(noise.acc_random_walk**2 * eye)
    return p


def bias_from(gyro: Array, acc: Array) -> gtsam.imuBias.ConstantBias:
    return gtsam.imuBias.ConstantBias(np.asarray(acc, dtype=np.float64), np.asarray(gyro, dtype=np.float64))


def preintegrate(params: gtsam.PreintegrationCombinedParams, bias: gtsam.imuBias.ConstantBias,
                 samples: ImuSamples, t0: float, t1: float) -> gtsam.PreintegratedCombinedMeasurements:
    """The readings' preintegration from ``t0`` to ``t1``; ``samples`` should bracket the
    span (readings outside it only serve the interpolation at its ends)."""
    return preintegrate_chain(params, [bias], samples, np.array([t0, t1], dtype=np.float64))[0][0]


def preintegrate_chain(params: gtsam.PreintegrationCombinedParams, biases: list[gtsam.imuBias.ConstantBias],
                       samples: ImuSamples, times: Array) -> list[list[gtsam.PreintegratedCombinedMeasurements]]:
    """``preintegrate`` between each pair of consecutive ``times`` (increasing), at each of
    ``biases``: one list of pairs per bias, the same numbers. The steps are interpolated and
    turned for the whole chain at once (per pair, those numpy calls cost more than GTSAM's
    integration), then integrated once per bias."""
    times = np.asarray(times, dtype=np.float64)
    out: list[list[gtsam.PreintegratedCombinedMeasurements]] = [[] for _ in biases]
    if len(times) < 2:
        return out
    if len(samples) == 0:
        for pims, b in zip(out, biases):
            pims.extend(gtsam.PreintegratedCombinedMeasurements(params, b) for _ in range(len(times) - 1))
        return out
    # Each pair's knots (its ends and the readings strictly inside), all pairs end to end.
    lo = np.searchsorted(samples.t, times[:-1], "right")
    hi = np.maximum(np.searchsorted(samples.t, times[1:], "left"), lo)
    counts = hi - lo + 2
    knots = np.concatenate([np.concatenate([[t0], samples.t[i0:i1], [t1]])
                            for t0, t1, i0, i1 in zip(times[:-1], times[1:], lo, hi)])
    g, a = interpolate_readings(samples, knots)
    ends = np.cumsum(counts)
    step = np.ones(len(knots) - 1, dtype=bool)
    step[ends[:-1] - 1] = False  # no step from one pair's last knot to the next pair's first
    dts = np.diff(knots)[step]
    gm, am = 0.5 * (g[:-1] + g[1:])[step], 0.5 * (a[:-1] + a[1:])[step]
    # GTSAM rotates a step's acceleration by the step's starting orientation; given in the
    # step's middle orientation instead (turned back by half the step's rotation), the
    # velocity and position are second-order accurate too (first-order otherwise: 4 mm
    # per second at 200 Hz on a 0.3 rad/s turn).
    am = Rotation.from_rotvec(gm * (0.5 * dts)[:, None]).apply(am)
    first = np.concatenate([[0], np.cumsum(counts - 1)])
    for i, (t0, t1) in enumerate(zip(times[:-1], times[1:])):
        ks = [k for k in range(first[i], first[i + 1]) if dts[k] > 1e-9] if t1 > t0 else []
        for pims, b in zip(out, biases):
            pim = gtsam.PreintegratedCombinedMeasurements(params, b)
            for k in ks:
                pim.integrateMeasurement(am[k], gm[k], float(dts[k]))
            pims.append(pim)
    return out


def interpolate_readings(samples: ImuSamples, times: Array) -> tuple[Array, Array]:
    """Gyro and accelerometer readings linearly interpolated at ``times`` (held beyond the ends)."""
    g = np.stack([np.interp(times, samples.t, samples.gyro[:, k]) for k in range(3)], axis=1)
    a = np.stack([np.interp(times, samples.t, samples.acc[:, k]) for k in range(3)], axis=1)
    return g, a


def predict(pim: gtsam.PreintegratedCombinedMeasurements, T_wb: Array, v_w: Array,
            bias: gtsam.imuBias.ConstantBias) -> tuple[Array, Array]:
    """The body's pose and velocity at the end of ``pim`` from those at its start."""
    state = pim.predict(gtsam.NavState(gtsam.Pose3(np.ascontiguousarray(T_wb)), np.asarray(v_w, dtype=np.float64)),
                        bias)
    return np.asarray(state.pose().matrix()), np.asarray(state.velocity())


class ImuBuffer:
    """The recent readings a tracker has received, for preintegrating between any two recent
    times (frames', keyframes'). Readings older than ``horizon_s`` before the newest go."""

    def __init__(self, horizon_s: float = 30.0) -> None:
        self.horizon_s = horizon_s
        self._parts: list[ImuSamples] = []
        self._samples = ImuSamples.empty()
        self._dirty = False

    def add(self, samples: ImuSamples | None) -> None:
        if samples is not None and len(samples):
            self._parts.append(samples)
            self._dirty = True

    @property
    def samples(self) -> ImuSamples:
        if self._dirty:
            merged = ImuSamples.concatenate([self._samples, *self._parts])
            self._parts = []
            keep = merged.t >= merged.t[-1] - self.horizon_s
            self._samples = ImuSamples(merged.t[keep], merged.gyro[keep], merged.acc[keep])
            self._dirty = False
        return self._samples

    def covers(self, t0: float, t1: float) -> bool:
        """Readings at or before ``t0`` and at or after ``t1``... or close enough: a reading
        within one step of either end (the last frame's time may sit just past the newest)."""
        s = self.samples
        if len(s) < 2:
            return False
        step = float(np.median(np.diff(s.t[-min(len(s), 50):])))
        return s.t[0] <= t0 + step and s.t[-1] >= t1 - step

    def window(self, t0: float, t1: float) -> ImuSamples:
        return self.samples.bracketing(t0, t1)
