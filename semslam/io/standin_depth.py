"""Stand-in depth sources for monocular runs, until (and beside) a depth network.

Neither is a monocular result, and neither is to be reported as one:

* ``ground_truth_depth`` - an ORACLE: the sequence's own ``depth/`` images (TUM layout:
  ``depth.txt`` next to ``rgb/``), read even when the sequence is read as monocular
  (``sensor: mono`` reads TUM folders without depth). It tests the monocular tracker with
  perfect depth: what the tracker would do with a perfect depth network, an upper bound.
* ``constant_depth`` - every pixel at 2 m: lets a monocular image folder that has no depth
  at all run end to end (the plumbing), with a wrong structure and so wrong poses.
* ``scaled_depth`` / ``shuffled_depth`` - DELIBERATELY WRONG depth networks for robustness
  tests of a depth prior (``depth.use: prior``): the sequence's depth times 2 (right shape,
  wrong scale), or its valid pixels randomly permuted within each image (right distribution,
  no structure).

The monocular ``sdf`` preset names its depth network (``sdfcnn``) instead.
"""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from semslam.config import DepthConfig
from semslam.core.types import Frame
from semslam.errors import DataError
from semslam.io.images import read_depth
from semslam.io.sequence import ListEntry, read_file_list

#: TUM depth images: metres x 5000 (semslam's renders write the same).
TUM_DEPTH_SCALE = 5000.0
#: Nearest depth image within this many seconds of the colour image (TUM associate.py).
MAX_DIFF_S = 0.02


class GroundTruthDepth:
    """ORACLE for tests and ablations: the depth image stored with the sequence, found by
    the colour image's timestamp in the ``depth.txt`` beside its ``rgb/`` folder."""

    def __init__(self, depth_scale: float = TUM_DEPTH_SCALE, max_diff: float = MAX_DIFF_S) -> None:
        self.depth_scale = depth_scale
        self.max_diff = max_diff
        self._lists: dict[Path, tuple[NDArray[np.float64], list[ListEntry]]] = {}
        self._lock = threading.Lock()  # the reader and tracking may both ask

    def depth(self, frame: Frame) -> NDArray[np.float32] | None:
        if frame.depth is not None:  # read as RGB-D: the same images
            return frame.depth
        if frame.rgb_path is None:
            raise DataError("frame", "ground_truth_depth needs the frame's image path (frames from a sequence folder)")
        stamps, entries = self._depth_list(Path(frame.rgb_path).parent.parent)
        k = int(np.argmin(np.abs(stamps - frame.timestamp)))
        if abs(stamps[k] - frame.timestamp) >= self.max_diff:
            raise DataError(frame.rgb_path, f"ground_truth_depth: no depth image within {self.max_diff} s "
                                            f"of t={frame.timestamp:.6f}")
        depth = read_depth(entries[k].path, self.depth_scale)
        if depth.shape != frame.rgb.shape[:2]:
            raise DataError(entries[k].path, f"depth is {depth.shape[1]}x{depth.shape[0]} but rgb is "
                                             f"{frame.rgb.shape[1]}x{frame.rgb.shape[0]}")
        return depth

    def _depth_list(self, root: Path) -> tuple[NDArray[np.float64], list[ListEntry]]:
        with self._lock:
            if root not in self._lists:
                listing = root / "depth.txt"
                if not listing.is_file():
                    raise DataError(listing, "file not found: the ground_truth_depth oracle reads the sequence's "
                                             "depth images (TUM layout); a folder without depth needs a depth network")
                entries = read_file_list(listing)
                self._lists[root] = (np.array([e.timestamp for e in entries]), entries)
            return self._lists[root]


class ConstantDepth:
    """PLUMBING stand-in: every pixel at ``metres`` (a fronto-parallel plane), so a folder
    with no depth runs end to end; its poses are not a measurement of anything."""

    def __init__(self, metres: float = 2.0) -> None:
        self.metres = float(metres)

    def depth(self, frame: Frame) -> NDArray[np.float32]:
        return np.full(frame.rgb.shape[:2], self.metres, np.float32)


class ScaledDepth:
    """WRONG ON PURPOSE: the sequence's depth times ``factor``."""

    def __init__(self, factor: float = 2.0) -> None:
        self.factor = float(factor)
        self._truth = GroundTruthDepth()

    def depth(self, frame: Frame) -> NDArray[np.float32]:
        return (self._truth.depth(frame) * self.factor).astype(np.float32)


class ShuffledDepth:
    """WRONG ON PURPOSE: the sequence's valid depths randomly permuted within each image
    (seeded by the frame's timestamp, so a run is repeatable)."""

    def __init__(self) -> None:
        self._truth = GroundTruthDepth()

    def depth(self, frame: Frame) -> NDArray[np.float32]:
        depth = self._truth.depth(frame).copy()
        valid = np.flatnonzero(depth > 0)
        rng = np.random.default_rng(int(round(frame.timestamp * 1e6)) % 2**32)
        depth.flat[valid] = depth.flat[rng.permutation(valid)]
        return depth


def create_ground_truth(cfg: DepthConfig) -> GroundTruthDepth:
    """Registry factory of depth source ``ground_truth_depth``."""
    return GroundTruthDepth()


def create_constant(cfg: DepthConfig) -> ConstantDepth:
    """Registry factory of depth source ``constant_depth``."""
    return ConstantDepth()


def create_scaled(cfg: DepthConfig) -> ScaledDepth:
    """Registry factory of depth source ``scaled_depth``."""
    return ScaledDepth()


def create_shuffled(cfg: DepthConfig) -> ShuffledDepth:
    """Registry factory of depth source ``shuffled_depth``."""
    return ShuffledDepth()
