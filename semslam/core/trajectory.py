"""Timestamped camera-to-world poses: what every tracker returns and every reader gives
(``io.trajectory`` reads and writes the files)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]


@dataclass(eq=False)  # arrays: element-wise == would be ambiguous, compare explicitly
class Trajectory:
    """Timestamped camera-to-world poses.

    ``timestamps`` is float64 ``(N,)`` in seconds (frame indices for KITTI files without a
    times file); ``poses`` is ``(N, 4, 4)``. ``name`` (usually the file path) is only used
    to make error messages name the file.
    """

    timestamps: Array
    poses: Array
    name: str = ""

    def __post_init__(self) -> None:
        self.timestamps = np.asarray(self.timestamps, dtype=np.float64).reshape(-1)
        self.poses = np.asarray(self.poses, dtype=np.float64)
        if self.poses.ndim != 3 or self.poses.shape[1:] != (4, 4):
            raise ValueError(f"poses must have shape (N, 4, 4), got {self.poses.shape}")
        if self.poses.shape[0] != self.timestamps.shape[0]:
            raise ValueError(
                f"{self.timestamps.shape[0]} timestamps for {self.poses.shape[0]} poses"
            )

    def __len__(self) -> int:
        return int(self.timestamps.shape[0])

    @classmethod
    def from_poses(cls, stamped: list[tuple[float, Array]], name: str = "") -> Trajectory:
        """From ``(timestamp, T_wc)`` pairs; an empty list gives an empty trajectory."""
        if not stamped:
            return cls(np.zeros(0), np.zeros((0, 4, 4)), name)
        return cls(np.array([t for t, _ in stamped]), np.stack([T for _, T in stamped]), name)

    @property
    def positions(self) -> Array:
        """Camera centres in the world frame, ``(N, 3)``."""
        return self.poses[:, :3, 3]

    def select(self, indices: ArrayLike) -> Trajectory:
        """A new trajectory with only the poses at ``indices`` (copies the data)."""
        idx = np.asarray(indices, dtype=np.intp)
        return Trajectory(self.timestamps[idx].copy(), self.poses[idx].copy(), self.name)
