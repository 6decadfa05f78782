"""The input checks every extractor shares: what ``Extractor.extract`` accepts, and the
smallest image the configured extractor can find keypoints in."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.core.registry import ALIASES
from semslam.errors import DataError
from semslam.features.orb.pyramid import EDGE_THRESHOLD, PATCH_SIZE, level_sizes
from semslam.io.calibration import check_principal_point

if TYPE_CHECKING:
    from semslam.config import FeatureConfig
    from semslam.io.sequence import Sequence

#: ORB-SLAM keeps keypoints EDGE_THRESHOLD px from every border of a level, so a level
#: holds one only if it is at least this wide and high.
MIN_LEVEL_SIDE = 2 * EDGE_THRESHOLD + 1
#: Extractors on ORB-SLAM's fixed pyramid (features.n_levels levels, each must hold a
#: keypoint); qtree_orb picks its level count from the image size, so only level 0 must.
FIXED_PYRAMID = ("orb_slam2",)
ADAPTIVE_PYRAMID = ("qtree_orb",)


def check_extractor_inputs(gray: NDArray[np.uint8], mask: NDArray[np.uint8] | None
                           ) -> tuple[NDArray[np.uint8], NDArray[np.uint8] | None]:
    """A uint8 grey image (colour is converted) and a uint8 mask of the same size, or an error."""
    gray = np.asarray(gray)
    if gray.ndim == 3:
        gray = cv2.cvtColor(gray, cv2.COLOR_BGR2GRAY if gray.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    if gray.dtype != np.uint8 or gray.ndim != 2:
        raise ValueError(f"expected a uint8 grey image, got {gray.dtype} {gray.shape}")
    if mask is not None:
        mask = np.asarray(mask)
        if mask.shape != gray.shape:
            raise ValueError(f"mask shape {mask.shape} differs from the image's {gray.shape}")
        mask = np.ascontiguousarray(mask) if mask.dtype == np.uint8 else (mask != 0).view(np.uint8)
    return gray, mask


def min_image_side(cfg: FeatureConfig) -> tuple[int, str]:
    """The smallest image width/height the configured extractor can use, and why: on ORB-SLAM's
    pyramid the top level (side / scale_factor^(n_levels - 1), rounded as the pyramid does)
    must hold a keypoint, i.e. be 2 x EDGE_THRESHOLD + 1 px; other extractors need one
    descriptor patch (PATCH_SIZE px)."""
    name = ALIASES["extractor"].get(cfg.extractor, cfg.extractor)
    if name in ADAPTIVE_PYRAMID:
        return MIN_LEVEL_SIDE, f"keypoints are kept {EDGE_THRESHOLD} px from each border"
    if name not in FIXED_PYRAMID:
        return PATCH_SIZE, f"one {PATCH_SIZE} px descriptor patch"
    top = cfg.n_levels - 1
    side = max(MIN_LEVEL_SIDE, math.floor((MIN_LEVEL_SIDE - 0.5) * cfg.scale_factor ** top))
    while level_sizes(side, side, cfg.n_levels, cfg.scale_factor)[-1][0] < MIN_LEVEL_SIDE:
        side += 1
    return side, (f"its top pyramid level (features.n_levels={cfg.n_levels}, scale_factor={cfg.scale_factor:g}) "
                  f"must be {MIN_LEVEL_SIDE} px to hold a keypoint {EDGE_THRESHOLD} px from each border; "
                  "fewer features.n_levels need less")


def check_image_size(cfg: FeatureConfig, width: int, height: int, source: str | Path) -> None:
    """DataError naming ``source`` when a ``width`` x ``height`` image is below what the
    configured extractor needs (it would fail or find nothing on every frame)."""
    need, why = min_image_side(cfg)
    if min(width, height) < need:
        raise DataError(source, f"image is {width}x{height} px; features.extractor {cfg.extractor} needs at least "
                                f"{need}x{need} ({why})")


def check_sequence_images(seq: Sequence, cfg: FeatureConfig) -> None:
    """Before the first frame is tracked: the sequence's image size (its first image's, which
    the camera carries) fits the extractor, and a principal point the user gave lies in it."""
    cam = seq.camera
    if cam.width <= 0:  # size not known yet: the reader reports an unreadable first image itself
        return
    need, _ = min_image_side(cfg)
    if min(cam.width, cam.height) < need:
        first = next(iter(seq.frames(0, 1)), None)
        source = first.rgb_path if first is not None and first.rgb_path is not None else seq.root
        check_image_size(cfg, cam.width, cam.height, source)
    check_principal_point(cam)
