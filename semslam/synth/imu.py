"""A simulated IMU on the rendered rig (issue 42): what an ADIS16448 on the body would read.

The body (IMU) frame B carries the left camera at ``T_bc`` (EuRoC's cam0 ``T_BS``), so its
pose is ``T_WB(t) = T_WC(t) @ inv(T_bc)`` for the render's camera path ``T_WC(t)``
(``Renderer.poses_at``, seconds from the first frame). The exact readings are
differentiated from that path, in B:

* gyroscope: ``w_B = vee(R_WB^T dR_WB/dt)``, the log of ``R_WB(t-h)^T R_WB(t+h)`` over ``2h``;
* accelerometer (specific force): ``a_B = R_WB^T (p_WB'' - g_W)`` with ``g_W = (0, 0, -9.81)``
  (world z is up, ``synth/camera_motion.py``), so at rest it reads ``R_WB^T (0, 0, +9.81)``;

with central differences of step :data:`DIFF_STEP_S`: their error (rounding, ~1e-7 m/s^2;
truncation, ~1e-9 rad/s) is far below the sensor's noise, except for a sample that falls on
one of ``fast_turns``' C1 kinks (where a glance starts: the angular acceleration jumps), off
by up to ~1e-3 rad/s there. The recording starts :data:`LEAD_S` before the first frame,
while the camera is still at rest (the paths are constant for t < 0; ``static``'s
sub-millimetre tremor goes on), and ends at least :data:`TAIL_S` after the last, so that
every frame lies inside it.

The noisy readings follow the continuous-time model of Kalibr / EuRoC / ORB-SLAM3
(``core.imu.ImuNoise``), discretised at the rate ``f``: ``reading_k = exact_k + b_k + n_k``
with white noise ``n_k ~ N(0, (sigma_c sqrt(f))^2)`` and the bias a random walk,
``b_{k+1} = b_k + N(0, (sigma_rw / sqrt(f))^2)``, from a seeded constant start drawn uniformly
in +-:data:`GYRO_BIAS0` rad/s and +-:data:`ACC_BIAS0` m/s^2 per axis (turn-on biases of the
order a MEMS IMU like the ADIS16448 shows, and what EuRoC's ground truth biases reach).
Each component has its own random stream, so a longer render's IMU starts with the
shorter one's, sample for sample.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from semslam.core.imu import ADIS16448, GRAVITY, ImuCalibration, ImuNoise, ImuSamples, ImuStream
from semslam.geometry.se3 import invert

#: T_WC of the left camera at times in seconds from the first frame (``Renderer.poses_at``).
PoseFn = Callable[[NDArray[np.float64]], NDArray[np.float64]]

LEAD_S = 0.5  # recording starts this long before the first frame (camera at rest)
TAIL_S = 0.05  # ... and ends at least this long after the last one
DIFF_STEP_S = 1e-4  # central-difference step for the angular velocity and acceleration
GYRO_BIAS0 = 0.01  # rad/s: the initial gyroscope bias is uniform in +- this, per axis
ACC_BIAS0 = 0.1  # m/s^2: the initial accelerometer bias is uniform in +- this, per axis
IMU_STREAM = 53  # random stream of the IMU noise (others: synth/render.py, imaging.py, ...)
GRAVITY_W = np.array([0.0, 0.0, -GRAVITY])


@dataclass(frozen=True)
class SimulatedImu:
    """A simulated recording: ``samples`` (absolute times, like the frames' stamps), ``t_rel``
    the same times in seconds from the first frame, and the true biases of each sample
    (zero for an exact stream, whose ``calibration.noise`` is still the sensor's)."""

    t_rel: NDArray[np.float64]
    samples: ImuSamples
    gyro_bias: NDArray[np.float64]
    acc_bias: NDArray[np.float64]
    calibration: ImuCalibration
    noisy: bool

    @property
    def stream(self) -> ImuStream:
        return ImuStream(self.samples, self.calibration)

    def biases_at(self, t_rel: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The true (gyro, acc) biases ``(M, 3)`` at times in seconds from the first frame,
        linear between samples (the random walk's value at a frame)."""
        t = np.asarray(t_rel, np.float64)
        interp = [np.stack([np.interp(t, self.t_rel, b[:, j]) for j in range(3)], axis=1)
                  for b in (self.gyro_bias, self.acc_bias)]
        return interp[0], interp[1]


def sample_times(frames: int, fps: float, rate_hz: float = ADIS16448.rate_hz) -> NDArray[np.float64]:
    """Sample times (seconds from the first frame) of a recording at ``rate_hz`` on a grid
    through t = 0: from :data:`LEAD_S` before the first frame to at least :data:`TAIL_S`
    after the last (frame ``frames - 1`` at ``(frames - 1) / fps``)."""
    first = -round(LEAD_S * rate_hz)
    last = math.ceil(((frames - 1) / fps + TAIL_S) * rate_hz - 1e-9)
    return np.arange(first, last + 1) / rate_hz


def body_poses_at(poses_at: PoseFn, t_bc: NDArray[np.float64]) -> PoseFn:
    """T_WB at any time from the camera's T_WC (``x_B = T_bc x_C``)."""
    t_cb = invert(t_bc)
    return lambda times: poses_at(np.asarray(times, np.float64)) @ t_cb


def exact_readings(poses_at: PoseFn, t_bc: NDArray[np.float64], t_rel: NDArray[np.float64]
                   ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Noiseless, bias-free (gyro, acc) ``(N, 3)`` in B at ``t_rel`` (seconds from the first frame)."""
    t = np.asarray(t_rel, np.float64)
    h = DIFF_STEP_S
    body = body_poses_at(poses_at, t_bc)
    behind, now, ahead = body(t - h), body(t), body(t + h)
    rel = np.swapaxes(behind[:, :3, :3], 1, 2) @ ahead[:, :3, :3]  # R_WB(t-h)^T R_WB(t+h)
    gyro = _so3_log(rel) / (2 * h)
    p_dd = (ahead[:, :3, 3] - 2 * now[:, :3, 3] + behind[:, :3, 3]) / h**2
    acc = np.einsum("nji,nj->ni", now[:, :3, :3], p_dd - GRAVITY_W)  # R_WB^T (p'' - g)
    return gyro, acc


def simulate_imu(poses_at: PoseFn, t_bc: NDArray[np.float64], frames: int, fps: float, start_time: float,
                 seed: int, noisy: bool = True, noise: ImuNoise = ADIS16448) -> SimulatedImu:
    """The IMU recording of a render: exact readings plus, with ``noisy``, the seeded biases
    and white noise of ``noise`` (see the module's docstring); ``noisy=False`` (a render's
    ``SynthConfig.noise=False``) gives the exact, bias-free stream."""
    t_rel = sample_times(frames, fps, noise.rate_hz)
    gyro, acc = exact_readings(poses_at, t_bc, t_rel)
    n = len(t_rel)
    b_g, b_a = np.zeros((n, 3)), np.zeros((n, 3))
    if noisy:
        b_g, b_a, n_g, n_a = _noise(seed, t_rel, noise)
        gyro, acc = gyro + b_g + n_g, acc + b_a + n_a
    samples = ImuSamples(start_time + t_rel, gyro, acc)
    return SimulatedImu(t_rel, samples, b_g, b_a, ImuCalibration(noise, np.array(t_bc, np.float64)), noisy)


def exact_imu(poses_at: PoseFn, t_bc: NDArray[np.float64], frames: int, fps: float, start_time: float,
              noise: ImuNoise = ADIS16448) -> SimulatedImu:
    """The noiseless, bias-free recording (for tests and ``noise=False`` renders)."""
    return simulate_imu(poses_at, t_bc, frames, fps, start_time, seed=0, noisy=False, noise=noise)


def initial_biases(seed: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The seeded constant (gyro, acc) biases the random walks start from."""
    b_g = np.random.default_rng([seed, IMU_STREAM, 0]).uniform(-GYRO_BIAS0, GYRO_BIAS0, 3)
    b_a = np.random.default_rng([seed, IMU_STREAM, 1]).uniform(-ACC_BIAS0, ACC_BIAS0, 3)
    return b_g, b_a


def _noise(seed: int, t_rel: NDArray[np.float64], noise: ImuNoise
           ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """(gyro bias, acc bias, gyro white noise, acc white noise), each ``(N, 3)``. One stream
    per component, drawn from the first sample on, so the draws do not depend on the length."""
    n, rate = len(t_rel), noise.rate_hz

    def draw(k: int) -> NDArray[np.float64]:
        return np.random.default_rng([seed, IMU_STREAM, k]).standard_normal((n, 3))

    b_g0, b_a0 = initial_biases(seed)
    walk_g = np.cumsum(draw(2), axis=0) * (noise.gyro_random_walk / math.sqrt(rate))
    walk_a = np.cumsum(draw(3), axis=0) * (noise.acc_random_walk / math.sqrt(rate))
    # The walk starts at the first sample: b_0 is the drawn constant itself.
    b_g = b_g0 + walk_g - walk_g[0]
    b_a = b_a0 + walk_a - walk_a[0]
    n_g = draw(4) * (noise.gyro_noise_density * math.sqrt(rate))
    n_a = draw(5) * (noise.acc_noise_density * math.sqrt(rate))
    return b_g, b_a, n_g, n_a


def _so3_log(rot: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rotation vectors of ``(N, 3, 3)`` rotations of less than pi (atan2 keeps small angles
    exact, where arccos of the trace would lose half the digits)."""
    v = 0.5 * np.stack([rot[:, 2, 1] - rot[:, 1, 2], rot[:, 0, 2] - rot[:, 2, 0], rot[:, 1, 0] - rot[:, 0, 1]],
                       axis=1)  # sin(angle) * axis
    s = np.linalg.norm(v, axis=1)
    c = (np.trace(rot, axis1=1, axis2=2) - 1.0) / 2.0
    angle = np.arctan2(s, c)
    scale = np.where(s > 1e-12, angle / np.maximum(s, 1e-300), 1.0)
    return v * scale[:, None]
