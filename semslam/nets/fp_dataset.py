"""SDF-SLAM's FP dataset (III-B, V-B): Harris corners of one frame mapped into another
frame with the ground-truth poses and depth (eqs. 5-7), on clear and motion-blurred pairs.

Works on any TUM-layout folder with ``groundtruth.txt`` and depth (``semslam synth``
renders, TUM RGB-D, Bonn): frames come from ``io.sequence.TumRgbdSequence`` (rgb/depth
association), the pose of each frame from the ground truth by nearest timestamp
(``io.association.associate``, as evo; frames without a pose within 20 ms are dropped).

A corner of frame i is kept as a correspondence when its depth is valid and smooth
(no depth edge in its 3x3 neighbourhood: a corner on an occluding contour has no single
depth), its transfer lands inside frame j in front of the camera, and frame j's depth
there agrees with the transferred depth (not occluded): |z - z_j| < 3 cm + 2 % of z.

Blur: a linear motion-blur kernel (length ``BLUR_PX`` px, random direction), drawn from a
generator seeded by (seed, pair index) so a "blurred pair" is the same in every run;
both images of a blurred pair are blurred, each with its own kernel.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.errors import DataError
from semslam.eval.feature_eval import lookup_depth, transfer_points
from semslam.geometry.camera import PinholeCamera
from semslam.io.association import associate
from semslam.io.sequence import TumRgbdSequence
from semslam.io.trajectory import read_trajectory

__all__ = ["BLUR_PX", "FPPair", "FPSequence", "blur", "harris_corners", "motion_blur_kernel", "transfer_corners"]

BLUR_PX = (7, 15)  # motion-blur kernel lengths drawn from this range (px)
MAX_GT_DIFF = 0.02  # s, frame <-> ground-truth stamp


def harris_corners(gray: NDArray[np.uint8], max_corners: int = 500, quality: float = 0.01,
                   min_distance: int = 8) -> NDArray[np.float32]:
    """Harris corners (OpenCV ``goodFeaturesToTrack`` with the Harris score, k = 0.04),
    strongest first, at integer pixels (N, 2)."""
    pts = cv2.goodFeaturesToTrack(gray, max_corners, quality, min_distance, blockSize=3,
                                  useHarrisDetector=True, k=0.04)
    return np.zeros((0, 2), np.float32) if pts is None else pts.reshape(-1, 2).astype(np.float32)


def harris_response(gray: NDArray[np.uint8]) -> NDArray[np.float32]:
    """OpenCV's dense Harris response (block 3, Sobel 3, k = 0.04) of a grey image in [0, 1]:
    the score ``harris_corners`` ranks by, for every pixel."""
    return cv2.cornerHarris(gray.astype(np.float32) / 255.0, 3, 3, 0.04)


def motion_blur_kernel(length: int, angle_deg: float) -> NDArray[np.float32]:
    """A normalised line kernel of ``length`` px at ``angle_deg`` (camera shake along a line)."""
    size = int(length) | 1
    k = np.zeros((size, size), np.float32)
    c = size // 2
    d = np.array([np.cos(np.radians(angle_deg)), np.sin(np.radians(angle_deg))])
    for s in np.linspace(-(length - 1) / 2, (length - 1) / 2, 4 * int(length)):
        x, y = c + s * d
        k[int(round(y)), int(round(x))] = 1.0
    return k / k.sum()


def blur(gray: NDArray[np.uint8], rng: np.random.Generator) -> NDArray[np.uint8]:
    """``gray`` with a random motion blur from ``rng`` (length in ``BLUR_PX``)."""
    kernel = motion_blur_kernel(int(rng.integers(BLUR_PX[0], BLUR_PX[1] + 1)), float(rng.uniform(0, 180)))
    return cv2.filter2D(gray, -1, kernel, borderType=cv2.BORDER_REFLECT)


def transfer_corners(xy1: NDArray[np.floating], depth1: NDArray[np.float32], depth2: NDArray[np.float32],
                     camera: PinholeCamera, T_wc1: NDArray[np.float64], T_wc2: NDArray[np.float64]
                     ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """(pixels in frame 2 (N, 2), valid (N,)) for frame 1's corners (module doc's rules)."""
    z1 = lookup_depth(depth1, xy1)
    d = np.where(depth1 > 0, depth1, np.nan).astype(np.float32)
    lo = -cv2.dilate(np.nan_to_num(-d, nan=-1e3), np.ones((3, 3), np.uint8))
    hi = cv2.dilate(np.nan_to_num(d, nan=1e3), np.ones((3, 3), np.uint8))
    smooth = lookup_depth(hi - lo, xy1) < 0.02 + 0.02 * z1
    xy2, z2 = transfer_points(xy1, np.where(z1 > 0, z1, 1.0), camera, T_wc1, T_wc2)
    h, w = depth2.shape
    inside = (z2 > 0) & (xy2[:, 0] >= 0) & (xy2[:, 0] <= w - 1) & (xy2[:, 1] >= 0) & (xy2[:, 1] <= h - 1)
    z_seen = lookup_depth(depth2, np.where(inside[:, None], xy2, -1))
    visible = (z_seen > 0) & (np.abs(z_seen - z2) < 0.03 + 0.02 * z2)
    return xy2, (z1 > 0) & smooth & inside & visible


@dataclass
class FPPair:
    """Frames i and j of one sequence: grey images (blurred if ``blurred``), depth of both,
    frame i's Harris corners ``xy1``, their ground-truth positions ``xy2`` in frame j and
    which of them are valid correspondences, the camera and both camera->world poses."""

    gray1: NDArray[np.uint8]
    gray2: NDArray[np.uint8]
    depth1: NDArray[np.float32]
    depth2: NDArray[np.float32]
    xy1: NDArray[np.float32]
    xy2: NDArray[np.float64]
    valid: NDArray[np.bool_]
    camera: PinholeCamera
    T_wc1: NDArray[np.float64]
    T_wc2: NDArray[np.float64]
    blurred: bool


class FPSequence:
    """The FP dataset of one TUM-layout folder: frames with a ground-truth pose."""

    def __init__(self, root: str | Path, max_corners: int = 500) -> None:
        self.root = Path(root)
        self.sequence = TumRgbdSequence(self.root)
        if self.sequence.groundtruth_path is None:
            raise DataError(self.root, "no groundtruth.txt: the FP dataset needs ground-truth poses")
        gt = read_trajectory(self.sequence.groundtruth_path)
        i_gt, i_frame = associate(gt.timestamps, self.sequence.timestamps, max_diff=MAX_GT_DIFF)
        if len(i_frame) < 2:
            raise DataError(self.sequence.groundtruth_path, "fewer than 2 frames have a ground-truth pose")
        order = np.argsort(i_frame)
        self.frame_index = np.asarray(i_frame)[order]
        self.poses = gt.poses[np.asarray(i_gt)[order]]
        self.camera = self.sequence.camera
        self.max_corners = max_corners

    def __len__(self) -> int:
        return len(self.frame_index)

    def load(self, k: int) -> tuple[NDArray[np.uint8], NDArray[np.float32]]:
        """(grey image, depth in metres) of the k-th frame with a pose."""
        frame = self.sequence.load(int(self.frame_index[k]))
        assert frame.depth is not None
        return frame.gray, frame.depth

    def pair(self, i: int, j: int, blurred: bool = False, seed: int = 0) -> FPPair:
        """Frames i and j (indices of frames with a pose); blur drawn from (seed, i, j)."""
        g1, d1 = self.load(i)
        g2, d2 = self.load(j)
        xy1 = harris_corners(g1, self.max_corners)
        xy2, valid = transfer_corners(xy1, d1, d2, self.camera, self.poses[i], self.poses[j])
        if blurred:
            rng = np.random.default_rng([seed, i, j])
            g1, g2 = blur(g1, rng), blur(g2, rng)
        return FPPair(g1, g2, d1, d2, xy1, xy2, valid, self.camera, self.poses[i], self.poses[j], blurred)

    def pair_indices(self, gap: int, every: int = 1) -> list[tuple[int, int]]:
        """(i, i + gap) for every ``every``-th i."""
        return [(i, i + gap) for i in range(0, len(self) - gap, max(1, every))]
