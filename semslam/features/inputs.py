"""The input checks every extractor shares: what ``Extractor.extract`` accepts, and the
smallest image the configured extractor can find keypoints in."""

from __future__ import annotations

import logging
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

log = logging.getLogger(__name__)

#: ORB-SLAM keeps keypoints EDGE_THRESHOLD px from every border of a level, so a level
#: holds one only if it is at least this wide and high.
MIN_LEVEL_SIDE = 2 * EDGE_THRESHOLD + 1
#: Extractors on ORB-SLAM's pyramid and border: level 0 must hold a keypoint. orb_slam2's
#: levels are fixed (features.n_levels); qtree_orb picks its level count from the image size.
ORB_PYRAMIDS = ("orb_slam2", "qtree_orb")
FIXED_PYRAMID = ("orb_slam2",)


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


def _canonical(extractor: str) -> str:
    return ALIASES["extractor"].get(extractor, extractor)


def min_image_side(cfg: FeatureConfig) -> tuple[int, str]:
    """The smallest image width/height the configured extractor can use, and why: on
    ORB-SLAM's pyramid, level 0 must hold a keypoint EDGE_THRESHOLD px from each border
    (2 x EDGE_THRESHOLD + 1 px); other extractors need one descriptor patch (PATCH_SIZE px)."""
    if _canonical(cfg.extractor) in ORB_PYRAMIDS:
        return MIN_LEVEL_SIDE, f"ORB keeps keypoints {EDGE_THRESHOLD} px from each border"
    return PATCH_SIZE, f"one {PATCH_SIZE} px descriptor patch"


def levels_without_room(cfg: FeatureConfig, width: int, height: int) -> list[int]:
    """Levels of orb_slam2's pyramid (features.n_levels, scale_factor) too small at this
    image size to hold a keypoint: they find nothing, and their share of n_features is lost."""
    if _canonical(cfg.extractor) not in FIXED_PYRAMID:
        return []
    sizes = level_sizes(width, height, cfg.n_levels, cfg.scale_factor)
    return [level for level, (w, h) in enumerate(sizes) if min(w, h) < MIN_LEVEL_SIDE]


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
    empty = levels_without_room(cfg, cam.width, cam.height)
    if empty:
        which = f"level {empty[0]}" if len(empty) == 1 else f"levels {empty[0]}-{empty[-1]}"
        log.warning("%dx%d px images: pyramid %s of features.n_levels=%d (scale_factor %g) under %d px "
                    "find no keypoints; features.n_levels=%d fits", cam.width, cam.height, which,
                    cfg.n_levels, cfg.scale_factor, MIN_LEVEL_SIDE, empty[0])
