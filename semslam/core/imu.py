"""IMU readings and calibration: plain values shared by the readers (io/), the renders
(synth/), preintegration (backend/) and tracking (slam/).

Conventions are EuRoC's and ORB-SLAM3's: the IMU frame is the body frame B; gyroscope in
rad/s and accelerometer (specific force, gravity included: at rest it reads +9.81 up) in
m/s^2, both in B; noise densities are continuous-time (per sqrt(Hz)) as Kalibr and
EuRoC's ``imu0/sensor.yaml`` give them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

#: Standard gravity (m/s^2), as GTSAM's ``MakeSharedU`` default and ORB-SLAM3's IMU_GRAVITY_VALUE.
GRAVITY = 9.81


@dataclass(frozen=True)
class ImuNoise:
    """Continuous-time noise of an IMU, as Kalibr / EuRoC ``sensor.yaml`` / ORB-SLAM3 settings."""

    gyro_noise_density: float  # rad / s / sqrt(Hz)
    acc_noise_density: float  # m / s^2 / sqrt(Hz)
    gyro_random_walk: float  # rad / s^2 / sqrt(Hz)
    acc_random_walk: float  # m / s^3 / sqrt(Hz)
    rate_hz: float = 200.0


#: EuRoC's ADIS16448 (its ``imu0/sensor.yaml``), what ``semslam synth --imu`` simulates.
ADIS16448 = ImuNoise(gyro_noise_density=1.6968e-04, acc_noise_density=2.0e-03,
                     gyro_random_walk=1.9393e-05, acc_random_walk=3.0e-03, rate_hz=200.0)


@dataclass(frozen=True)
class ImuCalibration:
    """The IMU's noise and where the (left) camera sits on it: ``T_bc`` maps a point in the
    camera frame into the IMU (body) frame, x_B = T_bc x_C (ORB-SLAM3's ``IMU.T_b_c1``;
    EuRoC's cam0 ``T_BS`` when imu0's is the identity)."""

    noise: ImuNoise
    T_bc: NDArray[np.float64] = field(default_factory=lambda: np.eye(4))


@dataclass(frozen=True)
class ImuSamples:
    """IMU readings in time order: ``t`` (N,) seconds, ``gyro`` and ``acc`` (N, 3) in B."""

    t: NDArray[np.float64]
    gyro: NDArray[np.float64]
    acc: NDArray[np.float64]

    def __len__(self) -> int:
        return len(self.t)

    def between(self, t0: float, t1: float) -> ImuSamples:
        """The samples with ``t0 < t <= t1``: consecutive frames' lists neither overlap nor
        leave a gap (a preintegrator holds the last reading of one list into the next)."""
        lo, hi = np.searchsorted(self.t, t0, "right"), np.searchsorted(self.t, t1, "right")
        return ImuSamples(self.t[lo:hi], self.gyro[lo:hi], self.acc[lo:hi])

    def last_at(self, t: float) -> ImuSamples:
        """The last sample with time <= t (none if the recording starts later)."""
        hi = int(np.searchsorted(self.t, t, "right"))
        return ImuSamples(self.t[max(hi - 1, 0):hi], self.gyro[max(hi - 1, 0):hi], self.acc[max(hi - 1, 0):hi])

    def bracketing(self, t0: float, t1: float) -> ImuSamples:
        """The samples in [t0, t1] plus the last one before t0 and the first one after t1,
        so that an integration from t0 to t1 can hold each reading over its interval."""
        lo = max(int(np.searchsorted(self.t, t0, "right")) - 1, 0)
        hi = min(int(np.searchsorted(self.t, t1, "left")) + 1, len(self.t))
        return ImuSamples(self.t[lo:hi], self.gyro[lo:hi], self.acc[lo:hi])

    def gyro_rate_at(self, t: float, window_s: float) -> NDArray[np.float64] | None:
        """The angular rate (rad/s, in B) at time ``t`` from the readings of the last
        ``window_s`` before it: a straight line fitted per axis and read at ``t`` (a turn
        speeding up is read where it is, not where the window's mean lags behind); the mean
        of two readings, the one reading alone; None without any."""
        lo, hi = np.searchsorted(self.t, t - window_s, "left"), np.searchsorted(self.t, t, "right")
        ts, gyro = self.t[lo:hi], self.gyro[lo:hi]
        if len(ts) == 0:
            return None
        if len(ts) < 3:
            return gyro.mean(axis=0)
        _, intercept = np.polyfit(ts - t, gyro, 1)
        return np.asarray(intercept, np.float64)

    @staticmethod
    def empty() -> ImuSamples:
        return ImuSamples(np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)))

    @staticmethod
    def concatenate(parts: list[ImuSamples]) -> ImuSamples:
        if not parts:
            return ImuSamples.empty()
        return ImuSamples(np.concatenate([p.t for p in parts]), np.concatenate([p.gyro for p in parts]),
                          np.concatenate([p.acc for p in parts]))


@dataclass(frozen=True)
class ImuStream:
    """A sequence's whole IMU recording and its calibration (what a reader attaches to a
    sequence; each frame then carries the samples since the frame before)."""

    samples: ImuSamples
    calibration: ImuCalibration
