"""A depth network's depth as a checked prior for a monocular map (issue 40: SDF-SLAM's SDFCNN
as a source of scale that can only help).

Monocular geometry comes first: the map starts from two views and grows by triangulation, as
ORB-SLAM's monocular mode. The predicted depth then does three things, each behind a test that
drops it where it disagrees with the geometry:

* **Metric initialisation.** The two-view map (median depth 1) is scaled by the median ratio of
  predicted to triangulated depths when those ratios agree (a small robust spread over enough
  points); otherwise the map keeps the two-view scale. A network with the right structure and
  a wrong scale (or a constant depth in front of a wall) only changes the map's units, which a
  monocular map does not have anyway.
* **A running scale.** Each keyframe's map points give ``log(map depth / predicted depth)``;
  their median over the keyframes whose ratios agree is the map's scale in the network's
  units (``exp`` of it is 1 for a metric map when the network is metric).
* **A weak depth prior in local BA.** For the keypoints of a keyframe that passed its check,
  the predicted depth times the running scale enters the bundle adjustment as the virtual right
  coordinate an RGB-D observation has (``u_R = u - bf / z``), with a virtual ``bf`` chosen so
  that one pixel of that residual is the prior's uncertainty in inverse depth (``sigma`` of the
  relative depth at the map's median depth). Keyframes whose ratios scatter, whose median
  moved away from the running scale, or whose ratios do not explain the variation of the
  map's depths (a constant or shuffled depth) get no prior; neither do keypoints far from
  their keyframe's median. A network that is wrong everywhere is then refused everywhere.

Choices not in the paper (SDF-SLAM uses its depth as a measurement): the test thresholds
follow the spread of a good network on the project's renders (relative depth errors of
10-20 %) with a wide margin; the residual in inverse depth is what RGB-D ORB-SLAM uses for a
sensor's depth.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from semslam.config import DepthConfig

#: Robust spread of log ratios: 1.4826 x MAD is sigma for normal errors.
MAD_TO_SIGMA = 1.4826
#: Fewest points for a scale (the initial pair, one keyframe).
MIN_POINTS = 30


@dataclass(frozen=True)
class LogRatios:
    """``log(map depth / predicted depth)`` over points: median, robust spread and count, and
    the robust spread of the map's own log depths (what the prediction has to explain)."""

    median: float
    spread: float
    n: int
    depth_spread: float = 0.0

    def disagreement(self, max_spread: float) -> str | None:
        """None when the ratios agree on one scale, else why not."""
        if self.n < MIN_POINTS:
            return "too few depths"
        if self.spread > max_spread:
            return "ratios scatter"
        return None

    def explains_structure(self, max_unexplained: float) -> bool:
        """Whether the prediction explains the depths' variation, not only their scale: the
        ratios scatter much less than the depths (a constant or a shuffled depth scatters as
        much, or more; in front of a flat wall nothing can be told apart, so nothing is)."""
        return self.spread <= max_unexplained * self.depth_spread

    @staticmethod
    def of(map_depth: NDArray[np.floating], predicted: NDArray[np.floating]) -> tuple["LogRatios", NDArray[np.float64]]:
        """The statistics and the per-point log ratios (NaN where either depth is missing)."""
        ok = (map_depth > 0) & (predicted > 0) & np.isfinite(predicted)
        r = np.full(len(map_depth), np.nan)
        r[ok] = np.log(map_depth[ok] / predicted[ok])
        v = r[ok]
        if v.size == 0:
            return LogRatios(float("nan"), float("inf"), 0), r
        med = float(np.median(v))
        return LogRatios(med, _robust_spread(v), int(v.size), _robust_spread(np.log(map_depth[ok]))), r


def _robust_spread(v: NDArray[np.float64]) -> float:
    return float(MAD_TO_SIGMA * np.median(np.abs(v - np.median(v))))


class DepthPrior:
    """The checks and the running scale, shared by tracking (initialisation) and local
    mapping (each keyframe's check, the BA residuals). Thread-safe."""

    def __init__(self, config: DepthConfig) -> None:
        self.sigma = config.prior_sigma
        self.max_spread = config.prior_max_spread
        self.max_jump = config.prior_max_jump
        self.max_unexplained = config.prior_max_unexplained
        self._lock = threading.Lock()
        self._kf_ratios: list[float] = []  # accepted keyframes' median log ratios
        self._map_depths: list[float] = []  # their median map depths
        self._spreads: list[float] = []  # their ratios' robust spreads
        self._prior_kfs = 0  # keyframes given a prior
        self.metric_init: bool | None = None  # None: not tried
        self.initial_scale = float("nan")
        self.refused: dict[str, int] = {}

    # ---------------------------------------------------------------- initialisation
    def initial_map_scale(self, triangulated: NDArray[np.floating], predicted: NDArray[np.floating]) -> float | None:
        """The factor that makes a two-view map (depths ``triangulated`` in the first keyframe)
        metric, or None when the predicted depths disagree with it."""
        stats, _ = LogRatios.of(np.asarray(triangulated, float), np.asarray(predicted, float))
        why = stats.disagreement(self.max_spread)
        with self._lock:
            self.metric_init = why is None
            if why is not None:
                self._count(f"initial pair: {why}")
                return None
            self.initial_scale = float(np.exp(-stats.median))
            return self.initial_scale

    # ---------------------------------------------------------------- keyframes
    def check_keyframe(self, map_depth: NDArray[np.floating], predicted: NDArray[np.floating]
                       ) -> NDArray[np.float32]:
        """The prior for one keyframe's keypoints: ``predicted`` times the running scale where
        the keyframe and the keypoint pass the checks, 0 elsewhere. ``map_depth`` is each
        keypoint's map point depth in the keyframe (0 without a point)."""
        predicted = np.asarray(predicted, float)
        stats, r = LogRatios.of(np.asarray(map_depth, float), predicted)
        out = np.zeros(len(predicted), np.float32)
        why = stats.disagreement(self.max_spread)
        with self._lock:
            if why is None and self._kf_ratios and abs(stats.median - float(np.median(self._kf_ratios))) > self.max_jump:
                why = "scale jumped"
            if why is not None:
                self._count(f"keyframe: {why}")
                return out
            # The scale is measured on every keyframe whose ratios agree; the prior on depths
            # needs the structure explained too.
            self._kf_ratios.append(stats.median)
            scale = float(np.median(self._kf_ratios))
            if not stats.explains_structure(self.max_unexplained):
                self._count("keyframe: structure not explained")
                return out
            self._prior_kfs += 1
            self._map_depths.append(float(np.median(np.asarray(map_depth)[np.isfinite(r)])))
            self._spreads.append(stats.spread)
        # Keypoints whose own ratio is far from the keyframe's lose the prior; keypoints
        # without a map point yet keep it (the keyframe as a whole agreed).
        far = np.isfinite(r) & (np.abs(r - stats.median) > 3.0 * max(stats.spread, 0.05))
        good = (predicted > 0) & np.isfinite(predicted) & ~far
        out[good] = predicted[good] * np.exp(scale)
        return out

    def map_scaled(self, scale: float) -> None:
        """The map was multiplied by ``scale`` (the IMU made it metric): the running scale
        and the depths it keeps move with it."""
        with self._lock:
            self._kf_ratios = [r + float(np.log(scale)) for r in self._kf_ratios]
            self._map_depths = [d * scale for d in self._map_depths]

    # ---------------------------------------------------------------- bundle adjustment
    def virtual_bf(self) -> float:
        """``bf`` that makes one pixel of the right-coordinate residual one sigma of relative
        depth at the map's median depth (in map units): ``prior_sigma``, or the network's own
        error statistics (the accepted keyframes' median spread of ratios) when larger."""
        with self._lock:
            depth = float(np.median(self._map_depths)) if self._map_depths else 1.0
            sigma = max(self.sigma, float(np.median(self._spreads))) if self._spreads else self.sigma
        return depth / sigma

    def virtual_right(self, u: NDArray[np.float64], prior_depth: NDArray[np.floating], bf: float) -> NDArray[np.float64]:
        """``u - bf / z`` where there is a prior, -1 (none) elsewhere."""
        z = np.asarray(prior_depth, float)
        return np.where(z > 0, u - bf / np.maximum(z, 1e-9), -1.0)

    # ---------------------------------------------------------------- report
    def _count(self, reason: str) -> None:
        self.refused[reason] = self.refused.get(reason, 0) + 1

    def stats(self) -> dict[str, object]:
        """``stats.json`` counters: whether the map started metric, the running scale (map
        depth / predicted depth), keyframes with a prior and why others had none."""
        with self._lock:
            scale = float(np.exp(np.median(self._kf_ratios))) if self._kf_ratios else None
            return {"depth_prior_metric_init": self.metric_init,
                    "depth_prior_scale": scale,
                    "depth_prior_keyframes": self._prior_kfs,
                    "depth_prior_refused": dict(self.refused)}
