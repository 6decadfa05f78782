"""The IMU as a pose prior (``imu.use``, on by default, with an input that has one).

Before the inertial initialisation the prior only collects: readings, and the tracked
frames' body poses. Once ``imu.init_s`` seconds are tracked, gravity's direction in the
map, the velocities and the biases come from those poses (``backend/inertial_init.py``;
with stereo or RGB-D the scale is known, so a slow or still start works), refined twice on
the longer history (``imu.refine_first_s``, ``imu.refine_second_s``). From then on:

* ``predict``: the last frame's pose and velocity carried to this frame by the readings
  between them (GTSAM preintegration): the pose the features are searched from, where the
  constant velocity model guesses; with its covariance (``imu.pose_prior``: tracking's pose
  optimisation is held near it, ORB-SLAM3's inertial tracking with velocity and biases
  marginalised) and the covariance of the motion alone (tracking links keyframes by it for
  local BA, ``slam/orb/inertial_links.py``);
* ``correct`` after the local map: a frame whose features did not track (black, blurred,
  covered, a crowd) keeps the IMU's pose for at most ``imu.max_blind_s`` since the last
  tracked one (counted in ``imu_only_frames``), then tracking is lost as without an IMU;
* ``camera_motion``: the camera's angular rate at a frame's time (the gyro) and its centre's
  velocity, for the rolling-shutter prior (``imu.rolling_shutter``);
* ``update``: the velocity carried on by the readings, and every ``imu.window_step_s``
  velocity and biases re-estimated on the last ``imu.window_s`` of tracked frames
  (``backend/inertial_window.py``).

Frames posed by the IMU alone make no keyframes, but with ``imu.keyframe_every_s`` (opt-in)
as tracking's temporal condition asks (not monocular, not black frames). The map starts in
the first camera's frame; the initialisation and each refinement rotate it about its origin
so gravity points down its z axis (``imu.gravity_aligned``; the smallest rotation, so the yaw
gravity does not show is kept), through tracking's ``align_map``, which moves the map,
tracking's state and every prior's kept positions (this one's ``map_aligned``), as
ORB-SLAM3's ``ApplyScaledRotation``.

Monocular-inertial: the map's scale is one more unknown of the initialisation and its
refinements (``initialise(..., scaled=...)``), with its relative spread (how well the motion
showed it): the first one under ``imu.max_scale_spread`` is applied (ORB-SLAM3 waits for enough
acceleration likewise), solutions tried every half ``init_s`` until then. With
``imu.provisional_scale_spread`` above that, a first, provisional scale shown that well is
applied, so the IMU predicts and bridges from then on, and replaced by each better shown one
until one is sure (opt-in: it dead-reckons on biases from little motion). Each accepted one scales the
map with the same ``align_map``; the sure scale is refined at doubling intervals and
corrected the same way (ORB-SLAM3 refines it in its VI-BA and its scale refinements).
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from semslam.backend.imu_preintegration import ImuBuffer, bias_from, imu_params, preintegrate
from semslam.backend.imu_preintegration import predict as imu_predict
from semslam.backend.inertial_init import initialise
from semslam.backend.inertial_window import bridge, refine_window
from semslam.config.schema import ImuConfig
from semslam.core.imu import ImuCalibration, ImuNoise
from semslam.core.types import Frame
from semslam.geometry.se3 import invert
from semslam.slam.orb.map_alignment import gravity_rotation
from semslam.slam.orb.motion_priors.base import (
    CameraMotion, Correction, FrameImages, FrameOutcome, MotionState, PosePrediction, PriorDefaults, Stage, TrackerOps,
)

if TYPE_CHECKING:
    from semslam.slam.orb.frame_state import FrameState

Array = NDArray[np.float64]
log = logging.getLogger(__name__)

#: Frames an initialisation or refinement solves over, at most (spread over its span).
MAX_INIT_FRAMES = 30
#: Frames a monocular scale is solved over, at most: a free scale costs the solver more
#: (0.2 s at 10 frames, 0.7 s at 20; it runs in the tracking thread).
MAX_SCALE_FRAMES = 12
#: Solutions refused as the poses and the readings disagreeing (a frame posed wrong, a
#: blurred turn): an initialisation or refinement whose normalised residuals' RMS is above
#: MAX_INIT_RMS (consistent ones: 0.3), a window whose chi2 per dimension is above
#: MAX_WINDOW_CHI2 (consistent: below 1).
MAX_INIT_RMS = 2.0
MAX_WINDOW_CHI2 = 4.0
#: The gyroscope bias's spread after the window's estimate (rad/s): ten times what a second of
#: EuRoC's ADIS16448 readings shows (1.7e-4 rad/s/sqrt(Hz)).
GYRO_BIAS_SPREAD = 2e-3
#: The gyro readings a frame's angular rate is read from (the last ones before its time):
#: six at 200 Hz, enough for a line through a turn that speeds up, short enough to be one.
GYRO_RATE_WINDOW_S = 0.03


def configured_noise(calibration: ImuNoise, cfg: ImuConfig) -> ImuNoise:
    """The calibration's noise with the config's non-zero overrides."""
    overrides = {k: getattr(cfg, k) for k in ("gyro_noise_density", "acc_noise_density", "gyro_random_walk",
                                              "acc_random_walk") if getattr(cfg, k) > 0}
    return replace(calibration, **overrides)


@dataclass(frozen=True)
class _Prediction:
    """The IMU's pose and velocity for one frame."""

    timestamp: float
    T_wb: Array
    v_w: Array
    T_cw: Array


def _place_at(cur: "FrameState", pred: _Prediction) -> None:
    """The frame at the IMU's predicted pose, its matches (to a pose it lost) dropped."""
    cur.clear_points()
    cur.outlier[:] = False
    cur.T_cw = pred.T_cw.copy()


def spaced(times: Array, step: float) -> NDArray[np.intp]:
    """Indices of ``times`` (increasing) about ``step`` apart, always keeping the newest."""
    keep = [len(times) - 1]
    for i in range(len(times) - 2, -1, -1):
        if times[keep[-1]] - times[i] >= step - 1e-9:
            keep.append(i)
    return np.array(keep[::-1], dtype=np.intp)


class InertialPrior(PriorDefaults):
    """See the module docstring."""

    name = "inertial"

    def __init__(self, cfg: ImuConfig, calibration: ImuCalibration,
                 align_map: Callable[[Array, float], None] | None = None, monocular: bool = False,
                 keyframe_min_depth_points: int = 250) -> None:
        self.cfg = cfg
        # A frame the IMU posed alone makes a keyframe (its points from depth at the IMU's
        # pose) only with this many keypoints with a depth: as many as start an RGB-D map.
        self.keyframe_min_depth_points = keyframe_min_depth_points
        # Tracking's: moves the map (gravity down z, a monocular map's scale). Without it the
        # map keeps the first camera's frame (a monocular map needs it for its scale).
        self.align_map = align_map
        # A monocular map: its scale is estimated too.
        self.monocular = monocular
        if monocular and align_map is None:
            raise ValueError("a monocular map's IMU needs the map's align_map to make it metric")
        self.noise = configured_noise(calibration.noise, cfg)
        self.T_bc = np.asarray(calibration.T_bc, dtype=np.float64)
        self.T_cb = invert(self.T_bc)
        self.buffer = ImuBuffer(horizon_s=cfg.refine_window_s + cfg.max_blind_s + 5.0)
        # Visually tracked frames: (timestamp, T_wb, the body's velocity as estimated then or None).
        self.history: deque[tuple[float, Array, Array | None]] = deque()
        self.gravity: Array | None = None
        self.gyro_bias = np.zeros(3)
        self.acc_bias = np.zeros(3)
        self.velocity: Array | None = None  # the body's, at the last frame
        self.init_time: float | None = None
        self.refined = 0  # refinements since the initialisation (monocular: since the scale was sure)
        self.last_solve_t = -np.inf
        # Monocular: the applied scale's relative spread (inf: none yet), and when it first
        # was under imu.max_scale_spread (a provisional one is replaced by better ones).
        self.scale_spread = np.inf
        self.sure_time: float | None = None
        self.last_window_t = -np.inf
        self.blind_since: float | None = None  # the last visually tracked frame's time, while blind
        self._pred: _Prediction | None = None
        # While blind: the last tracked frame's (timestamp, T_wb, velocity), and the frames
        # posed since as (timestamp, their entry in tracking's trajectory or None).
        self._blind_start: tuple[float, Array, Array] | None = None
        self._last_tracked: tuple[float, Array, Array] | None = None
        self._blind: list[tuple[float, int | None]] = []
        self.n_bridged = 0
        self.n_weak = 0  # tracked frames left out of the estimation (another prior's pose, few matches)
        self.n_refused = 0  # initialisations, refinements and windows refused as inconsistent
        self._retry_at = -np.inf
        self._map_id = 0  # the map the estimates are in (its frame)
        #: Stretches posed by the IMU alone: [first frame's time, last frame's time, frames].
        self.spans: list[list[float]] = []
        self.n_imu_only = 0
        self.n_local_map_searches = 0  # frames whose local map was searched from the IMU's pose
        self.n_blind_lost = 0
        self.n_inits = 0
        self.n_refinements = 0
        self.init_frame = -1
        self.init_after_s = -1.0  # seconds from the first tracked frame to the first initialisation
        self.first_tracked_t: float | None = None
        self.n_scale_unsure = 0  # monocular solutions refused as the scale's spread was too wide
        #: Monocular: every scale applied to the map, (time, factor, relative spread).
        self.scales: list[tuple[float, float, float]] = []
        #: Every rotation to gravity applied to the map, (time, degrees).
        self.alignments: list[tuple[float, float]] = []

    # ------------------------------------------------------------------ poses
    def _body(self, T_cw: Array) -> Array:
        return invert(T_cw) @ self.T_cb

    def _camera(self, T_wb: Array) -> Array:
        return invert(T_wb @ self.T_bc)

    def camera_motion(self, frame: Frame, T_cw_last: Array | None) -> CameraMotion | None:
        """The camera's motion at the frame's time, in its frame: the angular rate from the
        frame's gyro readings less the gyro bias as estimated so far, and once initialised the
        centre's velocity (the body's, as the prior carries it, plus the turn about the
        lever arm), turned into the camera by the last frame's pose ``T_cw_last`` (None: not
        tracked, no velocity). None without readings, or with ``imu.rolling_shutter`` off:
        what a rolling shutter's rows are moved by."""
        if not self.cfg.rolling_shutter or frame.imu is None:
            return None
        rate = frame.imu.gyro_rate_at(frame.timestamp, GYRO_RATE_WINDOW_S)
        if rate is None:
            return None
        rate_b = rate - self.gyro_bias
        rate_c = self.T_cb[:3, :3] @ rate_b
        if self.velocity is None or self.gravity is None or T_cw_last is None:
            return CameraMotion(rate_c)
        lever_arm = self.T_cb[:3, :3] @ np.cross(rate_b, self.T_bc[:3, 3])  # R_cw R_wb = R_cb
        return CameraMotion(rate_c, T_cw_last[:3, :3] @ self.velocity + lever_arm)

    def _aligned_body(self, T_wb: Array, rotation: Array, scale: float) -> Array:
        """A body pose after the map moved by ``x' = scale * rotation @ x``: its camera centre
        moves so, the metric lever arm between camera and body does not scale."""
        out = T_wb.copy()
        out[:3, :3] = rotation @ T_wb[:3, :3]
        out[:3, 3] = scale * rotation @ self._centres(T_wb[None])[0] - out[:3, :3] @ self.T_bc[:3, 3]
        return out

    def map_aligned(self, rotation: Array, scale: float) -> None:
        """Poses, velocities (metric already: only turned) and gravity into the moved map."""
        def turned(v: Array | None) -> Array | None:
            return None if v is None else rotation @ v

        self.history = deque((t, self._aligned_body(T, rotation, scale), turned(v)) for t, T, v in self.history)
        if self._last_tracked is not None:
            t, T, v = self._last_tracked
            self._last_tracked = (t, self._aligned_body(T, rotation, scale), rotation @ v)
        if self._blind_start is not None:
            t, T, v = self._blind_start
            self._blind_start = (t, self._aligned_body(T, rotation, scale), rotation @ v)
        self.velocity = turned(self.velocity)
        self.gravity = turned(self.gravity)

    def _centres(self, T_wb: Array) -> Array:
        """The camera centres of body poses (N, 4, 4): what a monocular map's scale multiplies."""
        return T_wb[:, :3, 3] + T_wb[:, :3, :3] @ self.T_bc[:3, 3]

    # ------------------------------------------------------------------ the prior's steps
    def predict(self, state: MotionState, images: FrameImages) -> PosePrediction | None:
        self._pred = None
        last, t1 = state.last, images.frame.timestamp
        if self.gravity is None or self.velocity is None or last is None or last.T_cw is None or not state.tracked:
            return None
        t0 = last.timestamp
        if t1 <= t0 or not self.buffer.covers(t0, t1):
            return None
        bias = bias_from(self.gyro_bias, self.acc_bias)
        pim = preintegrate(imu_params(self.noise, self.gravity), bias, self.buffer.window(t0, t1), t0, t1)
        T_wb, v_w = imu_predict(pim, self._body(last.T_cw), self.velocity, bias)
        self._pred = _Prediction(t1, T_wb, v_w, self._camera(T_wb))
        since = self.blind_since if self.blind_since is not None else t0
        preint_cov = pim.preintMeasCov()
        motion = self._motion_covariance(preint_cov, t1 - t0)
        if not self.cfg.pose_prior:
            return PosePrediction(self._pred.T_cw.copy(), motion_covariance=motion)
        floor = np.diag([np.deg2rad(self.cfg.pose_prior_rotation_deg) ** 2] * 3
                        + [self.cfg.pose_prior_translation_m ** 2] * 3)
        return PosePrediction(self._pred.T_cw.copy(), floor + self._motion_covariance(preint_cov, t1 - since), motion)

    def _motion_covariance(self, preint_cov: Array, dt: float) -> Array:
        """The spread of the motion the IMU predicts over ``dt`` seconds, on (rotation,
        translation) of the camera pose, isotropic per block (so the same in the body's, the
        camera's and the world's frame): the biases' and the velocity's spreads over ``dt``
        and the preintegration's own (GTSAM's covariance, rotation then position)."""
        rot = (GYRO_BIAS_SPREAD * dt) ** 2 + np.trace(preint_cov[:3, :3]) / 3
        trans = (self.cfg.velocity_sigma_m_s * dt) ** 2 + np.trace(preint_cov[3:6, 3:6]) / 3
        return np.diag([rot] * 3 + [trans] * 3)

    def correct(self, stage: Stage, state: MotionState, cur: "FrameState", tracked: bool,
                images: FrameImages, ops: TrackerOps) -> Correction | None:
        if stage is Stage.FEATURES:
            self.buffer.add(images.frame.imu)
            return None
        pred = self._pred
        if tracked or pred is None or pred.timestamp != cur.timestamp or state.last is None:
            return None
        if stage is Stage.MATCHED:
            return self._search_local_map(cur, pred)
        since = self.blind_since if self.blind_since is not None else state.last.timestamp
        if cur.timestamp - since > self.cfg.max_blind_s:
            self.n_blind_lost += 1
            return None
        self.blind_since = since
        _place_at(cur, pred)
        self.n_imu_only += 1
        return Correction(True, posed=True)

    def _search_local_map(self, cur: "FrameState", pred: _Prediction) -> Correction | None:
        """The frame after one the IMU posed alone, whose features were dropped, so the motion
        model had nothing to match, and the reference keyframe found too few: the local map
        is searched from the IMU's pose instead (ORB-SLAM3 tracks the local map from its IMU
        prediction while recently lost). A frame lost after a tracked one is left to the
        other priors (a blurred turn's coast) and then posed by the IMU."""
        if not self.cfg.local_map_recovery or self.blind_since is None:
            return None
        _place_at(cur, pred)
        self.n_local_map_searches += 1
        return Correction(True)

    def keyframe_wanted(self, state: MotionState, cur: "FrameState", ops: TrackerOps,
                        orb_slam_wants: Callable[[], bool]) -> bool:
        """With ``imu.keyframe_every_s`` set (opt-in; else never), a frame posed by the IMU
        alone makes a keyframe when tracking's decision wants one (with no matches, only its
        temporal condition does), as ORB-SLAM3 inserts keyframes while recently lost: its
        keypoints with depth become points at the IMU's pose, so a view the map never had gets
        mapped and the next frames track on it. Not monocular (no depth to place points with)
        and not a frame with too few depths (a black one)."""
        if (self.cfg.keyframe_every_s <= 0 or self.monocular
                or int(np.count_nonzero(cur.depth > 0)) < self.keyframe_min_depth_points):
            return False
        return orb_slam_wants()

    def update(self, outcome: FrameOutcome) -> None:
        t = outcome.frame.timestamp
        pred = self._pred if self._pred is not None and self._pred.timestamp == t else None
        self._pred = None
        ref = outcome.frame.ref_kf
        map_id = ref.map_id if ref is not None else self._map_id
        if outcome.started_map or map_id != self._map_id:
            # A new map (its frame is the new first camera's), a relocalisation into another
            # map, or a merge that moved this one: gravity and the poses kept are in another
            # frame now, so the IMU starts over (its biases seed the next initialisation).
            self.gravity, self.velocity, self.init_time, self.refined = None, None, None, 0
            self.scale_spread, self.sure_time = np.inf, None
            self.history.clear()
            self._blind_start, self._blind, self._last_tracked = None, [], None
            self._map_id = map_id
        if not outcome.tracked:
            self.velocity, self.blind_since, self._blind_start, self._last_tracked = None, None, None, None
            self._blind.clear()
            self.history.clear()
            return
        if outcome.posed_by is self:
            assert pred is not None
            if not self._blind:
                self._blind_start = self._last_tracked
            self._blind.append((t, outcome.recorded_at))
            if len(self._blind) == 1:
                self.spans.append([t, t, 0])
            self.spans[-1][1:] = [t, self.spans[-1][2] + 1]
            self.velocity = pred.v_w
            return
        self.blind_since = None
        if self.first_tracked_t is None:
            self.first_tracked_t = t
        # The frame that started the map is its origin (exact, no inliers counted).
        if outcome.posed_by is not None or (outcome.n_inliers < self.cfg.min_inliers and not outcome.started_map):
            # Posed by another prior (a blurred turn coasted) or on few matches: its pose is
            # too rough to estimate velocity and biases from; the readings carry them on.
            self.velocity = pred.v_w if pred is not None else None
            self.n_weak += 1
        else:
            self._estimate(outcome, pred)
        T_cw = outcome.frame.T_cw
        # Where a blind stretch after this frame starts from (its pose and velocity).
        self._last_tracked = None if self.velocity is None or T_cw is None else (t, self._body(T_cw), self.velocity)

    def _estimate(self, outcome: FrameOutcome, pred: _Prediction | None) -> None:
        """A frame posed by its own features: into the history; a pending blind stretch
        bridged to it; then the initialisation, a refinement or the window, as due."""
        t, T_cw = outcome.frame.timestamp, outcome.frame.T_cw
        assert T_cw is not None
        self.history.append((t, self._body(T_cw), pred.v_w if pred is not None else None))
        if self._blind:
            self._bridge(outcome)
        while t - self.history[0][0] > self.cfg.refine_window_s:
            self.history.popleft()
        if self.gravity is None:
            self._initialise(t, outcome.frame.index)
            return
        self.velocity = pred.v_w if pred is not None else None
        due = self._refinement_at()
        if due is not None and t >= due:
            self._initialise(t, outcome.frame.index, refine=True)
            return
        if self.velocity is None or t - self.last_window_t >= self.cfg.window_step_s:
            self._refine_window(t)

    # ------------------------------------------------------------------ estimation
    def _spaced_history(self, span_s: float, step_s: float) -> tuple[Array, Array, Array | None]:
        """The last ``span_s`` of the history about ``step_s`` apart: times, body poses, and the
        velocity estimated when the first of them came (None if none was)."""
        t_last = self.history[-1][0]
        recent = [(t, T, v) for t, T, v in self.history if t_last - t <= span_s + 1e-9]
        times = np.array([t for t, _, _ in recent])
        poses = np.array([T for _, T, _ in recent])
        idx = spaced(times, step_s)
        return times[idx], poses[idx], recent[int(idx[0])][2]

    def _initialise(self, t: float, index: int, refine: bool = False) -> None:
        """The inertial initialisation once ``init_s`` is tracked (or a refinement); one the
        poses do not fit is refused (tried again ``init_s`` / 2 later; a refinement keeps
        the estimate it would have replaced)."""
        if t - self.history[0][0] < self.cfg.init_s - 1e-9 or t < self._retry_at:
            return
        # A monocular scale needs motion: its first solve takes all the history there is.
        span = self.cfg.refine_window_s if refine or self.monocular else self.cfg.init_s
        # At most ~30 frames: the solve runs in the tracking thread (0.2 s at 30, 0.7 at 100).
        step = max(self.cfg.init_step_s, (t - self.history[0][0]) / MAX_INIT_FRAMES)
        if self.monocular:  # the scale is read in the poses' second differences: see scale_step_s
            step = max(step, self.cfg.scale_step_s, (t - self.history[0][0]) / MAX_SCALE_FRAMES)
        times, poses, _ = self._spaced_history(span, step)
        if len(times) < 3 or not self.buffer.covers(times[0], times[-1]):
            return
        samples = self.buffer.window(times[0], times[-1])
        est = initialise(times, poses, samples, self.noise, self.gyro_bias, self.acc_bias,
                         scaled=self._centres(poses) if self.monocular else None)
        self.last_solve_t = t
        unsure = self.monocular and not est.scale_sigma <= self._scale_spread_accepted()
        log.debug("inertial %s at %.2f s over %.2f s: rms %.2f, scale %.4f (spread %.4f)",
                  "refinement" if refine else "initialisation", t, times[-1] - times[0], est.rms, est.scale,
                  est.scale_sigma)
        if est.rms > MAX_INIT_RMS or unsure:
            self.n_refused += 1
            self.n_scale_unsure += int(unsure and est.rms <= MAX_INIT_RMS)
            if refine:
                self.refined += 1
            else:
                self._retry_at = t + 0.5 * self.cfg.init_s
            return
        self.gravity, self.gyro_bias, self.acc_bias = est.gravity_w, est.gyro_bias, est.acc_bias
        self.velocity = est.velocities[-1]
        self._align(t, est.gravity_w, est.scale if self.monocular else 1.0, est.scale_sigma)
        self.last_window_t = t
        if refine:
            self.refined += 1
            self.n_refinements += 1
        else:
            self.init_time = t
            self.n_inits += 1
            if self.init_frame < 0:
                self.init_frame = index
                self.init_after_s = t - (self.first_tracked_t if self.first_tracked_t is not None else t)
        if self.monocular:
            self.scale_spread = est.scale_sigma
            if self.sure_time is None and est.scale_sigma <= self.cfg.max_scale_spread:
                self.sure_time, self.refined = t, 0  # the doubling schedule starts now

    def _align(self, t: float, gravity: Array, scale: float, scale_sigma: float) -> None:
        """The map rotated to ``gravity`` (and a monocular one scaled): asked of tracking,
        which applies it after the frame and calls ``map_aligned``, which turns this prior's
        state, set in the old frame, with it."""
        if self.align_map is None or not (self.monocular or self.cfg.gravity_aligned):
            return
        rotation = gravity_rotation(gravity) if self.cfg.gravity_aligned else np.eye(3)
        if self.monocular:
            self.scales.append((t, scale, scale_sigma))
        if self.cfg.gravity_aligned:
            self.alignments.append((t, float(np.degrees(Rotation.from_matrix(rotation).magnitude()))))
        self.align_map(rotation, scale)

    def _scale_spread_accepted(self) -> float:
        """The widest relative spread a monocular scale solve may have to be applied: a first,
        provisional scale up to ``imu.provisional_scale_spread`` (the IMU then predicts and
        bridges blackouts in roughly metric units instead of not at all), then only better
        shown ones until one is under ``imu.max_scale_spread``, then only such ones."""
        if self.scale_spread <= self.cfg.max_scale_spread:
            return self.cfg.max_scale_spread
        return min(self.scale_spread, max(self.cfg.provisional_scale_spread, self.cfg.max_scale_spread))

    def _refinement_at(self) -> float | None:
        """When the next refinement is due (None: no more): ``refine_first_s`` and
        ``refine_second_s`` after the initialisation (ORB-SLAM3's two VI-BA refinements); a
        monocular map's scale, which only acceleration shows, every half ``init_s`` while
        provisional, then from the time it was sure ``scale_refine_s`` later and at doubling
        intervals for as long as the map lives (1, 3, 7, 15 s ...: ORB-SLAM3 refines it at 5
        and 15 s, then every 10 s up to 100 s), so a long run spends little on it."""
        if self.init_time is None:
            return None
        if self.monocular:
            if self.sure_time is None:
                return self.last_solve_t + 0.5 * self.cfg.init_s
            return self.sure_time + (2 ** (self.refined + 1) - 1) * self.cfg.scale_refine_s
        if self.refined >= 2:
            return None
        return self.init_time + (self.cfg.refine_first_s if self.refined == 0 else self.cfg.refine_second_s)

    def _refine_window(self, t: float) -> None:
        """Velocity and biases on the last ``window_s`` of tracked frames."""
        if len(self.history) < 2:
            return
        times, poses, v_first = self._spaced_history(self.cfg.window_s, self.cfg.window_step_s)
        if len(times) < 2 or not self.buffer.covers(times[0], times[-1]):
            return
        assert self.gravity is not None
        if v_first is None:  # finite differences of the window's first poses
            v_first = (poses[1, :3, 3] - poses[0, :3, 3]) / max(times[1] - times[0], 1e-6)
        est = refine_window(times, poses, self.buffer.window(times[0], times[-1]), self.noise, self.gravity,
                            v_first, self.gyro_bias, self.acc_bias)
        self.last_window_t = t
        if est.chi2_per_dim > MAX_WINDOW_CHI2:
            self.n_refused += 1
            return
        self.velocity, self.gyro_bias, self.acc_bias = est.velocities[-1], est.gyro_bias, est.acc_bias

    def _bridge(self, outcome: FrameOutcome) -> None:
        """The frames the IMU posed alone, re-posed once the features track again: the
        readings' path between the last tracked frame before and this one (their entries in
        tracking's trajectory, relative to their reference keyframes, are replaced)."""
        start, blind = self._blind_start, self._blind
        self._blind_start, self._blind = None, []
        if start is None or self.gravity is None:
            return
        (t_a, T_a, v_a), (t_b, T_b, _) = start, self.history[-1]
        if not self.buffer.covers(t_a, t_b):
            return
        times = np.array([t_a, *(t for t, _ in blind), t_b])
        poses = bridge(times, T_a, v_a, T_b, self.buffer.window(t_a, t_b), self.noise, self.gravity,
                       self.gyro_bias, self.acc_bias)
        trajectory = outcome.trajectory
        for (t, at), T_wb in zip(blind, poses[1:-1]):
            if at is None or at >= len(trajectory) or trajectory[at][0] != t:
                continue
            ref = trajectory[at][1]
            trajectory[at] = (t, ref, self._camera(T_wb) @ invert(ref.T_cw))
            self.n_bridged += 1

    def counters(self) -> dict[str, Any]:
        return {"imu_initialisations": self.n_inits, "imu_init_frame": self.init_frame,
                "imu_init_after_s": round(self.init_after_s, 3), "imu_refinements": self.n_refinements,
                "imu_only_frames": self.n_imu_only, "imu_local_map_searches": self.n_local_map_searches,
                "imu_only_spans": [list(s) for s in self.spans],
                "imu_bridged_frames": self.n_bridged, "imu_blind_lost": self.n_blind_lost,
                "imu_weak_frames": self.n_weak, "imu_refused_solutions": self.n_refused,
                **({"imu_scale_unsure": self.n_scale_unsure,
                    "imu_scales": [[round(t, 3), round(f, 5), round(sd, 5)] for t, f, sd in self.scales]}
                   if self.monocular else {}),
                "imu_gravity_alignments": [[round(t, 3), round(deg, 3)] for t, deg in self.alignments],
                "imu_gravity": None if self.gravity is None else [round(float(g), 5) for g in self.gravity],
                "imu_gyro_bias": [round(float(b), 6) for b in self.gyro_bias],
                "imu_acc_bias": [round(float(b), 5) for b in self.acc_bias]}
