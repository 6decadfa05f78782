"""A tracked frame: features with depth, their map points and the pose being estimated
(built per sensor by ``slam/orb/frame_builders.py``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from semslam.core.types import Keypoints
from semslam.features.keypoint_grid import KeypointGrid
from semslam.geometry.camera import PinholeCamera
from semslam.frontend.keypoint_depth import sample_depth
from semslam.slam.orb.map import KeyFrame, PointSlots, PointStore


@dataclass(eq=False)
class FrameState:
    index: int
    timestamp: float
    keypoints: Keypoints
    xy: NDArray[np.float64]
    depth: NDArray[np.float32]
    ur: NDArray[np.float64]
    points: PointSlots  # MapPoint | None per keypoint, with their store rows
    outlier: NDArray[np.bool_]
    T_cw: NDArray[np.float64] | None = None
    ref_kf: KeyFrame | None = None
    bow: Any = None
    featvec: dict[int, Any] | None = None
    # Monocular with a depth network as a prior: its depth at each keypoint (0: none);
    # None otherwise. Never a measurement (slam/orb/depth_prior.py).
    prior_depth: NDArray[np.float32] | None = None
    _grid: KeypointGrid | None = field(default=None, repr=False)
    # Undistorted keypoints and their depths as extracted, kept by the first to_middle_row.
    _raw_xy: NDArray[np.float64] | None = field(default=None, repr=False)
    _raw_depth: NDArray[np.float32] | None = field(default=None, repr=False)

    def __len__(self) -> int:
        return len(self.keypoints)

    def to_middle_row(self, velocity_cw: NDArray[np.float64], frame_dt_s: float, readout_s: float,
                      camera: PinholeCamera, bf: float, depth_img: NDArray[np.float32] | None = None) -> None:
        """Move the keypoints (and their depths) to the middle row's capture time, for a
        rolling-shutter camera moving at ``velocity_cw`` per ``frame_dt_s``. Starts from the raw
        keypoints each time, so a better velocity can redo it. With ``depth_img`` (a global
        depth frame at the middle row's time) the depths are read where the keypoints land."""
        from semslam.geometry.rolling_shutter import (row_time_fraction, to_middle_row,
                                                      to_middle_row_with_depth_image)

        if self._raw_xy is None:
            self._raw_xy, self._raw_depth = self.xy, self.depth
        raw = self._raw_xy
        frac = row_time_fraction(self.keypoints.xy[:, 1], int(round(camera.image_size[1])), readout_s, frame_dt_s)
        if depth_img is None:
            xy, z = to_middle_row(raw, self._raw_depth, frac, velocity_cw, camera)
        else:
            xy, z = to_middle_row_with_depth_image(raw, frac, velocity_cw, camera,
                                                   lambda uv: sample_depth(depth_img, camera.distort_points(uv)))
        self.xy, self.depth = xy, z.astype(np.float32)
        self.ur = np.where(self.depth > 0, xy[:, 0] - bf / np.maximum(self.depth, 1e-6), -1.0)
        self._grid = None

    @property
    def raw_xy(self) -> NDArray[np.float64]:
        """Undistorted keypoints where the image shows them (before any rolling-shutter move)."""
        return self.xy if self._raw_xy is None else self._raw_xy

    def drop(self, keep: NDArray[np.bool_]) -> None:
        """Remove keypoints (e.g. found dynamic after tracking) and everything indexed by them."""
        idx = np.nonzero(keep)[0]
        self.keypoints = self.keypoints.subset(idx)
        self.xy, self.depth, self.ur = self.xy[idx], self.depth[idx], self.ur[idx]
        if self.prior_depth is not None:
            self.prior_depth = self.prior_depth[idx]
        if self._raw_xy is not None:
            self._raw_xy, self._raw_depth = self._raw_xy[idx], self._raw_depth[idx]
        self.points = PointSlots([self.points[i] for i in idx.tolist()])
        self.outlier = self.outlier[idx]
        self.bow = self.featvec = None
        self._grid = None

    def grid(self, width: float, height: float) -> KeypointGrid:
        """The keypoints in ORB-SLAM's 64 x 48 grid over the image (built once)."""
        if self._grid is None:
            self._grid = KeypointGrid(self.xy, self.keypoints.octave, width, height)
        return self._grid

    def clear_points(self) -> None:
        self.points = PointSlots([None] * len(self))

    def matched_indices(self, store: PointStore) -> NDArray[np.intp]:
        """Keypoints with a good map point."""
        return self.points.good(store)

    def free_mask(self, store: PointStore) -> NDArray[np.bool_]:
        """Keypoints without a (good, observed) map point."""
        rows = self.points.rows
        free = rows < 0
        r = rows[~free]
        free[~free] = store.bad[r] | (store.n_kf_obs[r] == 0)
        return free

    def world_points(self, idx: NDArray[np.intp], camera: PinholeCamera) -> NDArray[np.float64]:
        """World positions of keypoints ``idx`` from their depth and the frame pose."""
        assert self.T_cw is not None
        pc = camera.backproject(self.xy[idx], self.depth[idx])
        r, t = self.T_cw[:3, :3], self.T_cw[:3, 3]
        return (pc - t) @ r
