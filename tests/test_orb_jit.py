"""``warm_up`` compiles every ORB kernel once, and extracting frames afterwards compiles
nothing more (no hidden per-frame compile, whatever the input: colour, masks, sizes)."""

from __future__ import annotations

import numpy as np

from semslam.features.orb import brief_kernels, fast_kernels, harris_kernels, pyramid_kernels, quadtree_kernels, warm_up
from semslam.features.orb_slam2 import OrbSlamExtractor
from semslam.features.qtree_orb import QtreeOrbExtractor

_KERNELS = [fast_kernels.detect_cells, fast_kernels.detect_pyramid, fast_kernels.detect_two_thresholds_pyramid,
            brief_kernels.ic_moments, brief_kernels.steered_brief, quadtree_kernels.quadtree_levels,
            pyramid_kernels.reflect_pad_levels, harris_kernels.harris_at]


def _signatures() -> list[int]:
    return [len(k.signatures) for k in _KERNELS]


def test_warm_up_once_then_nothing_compiles_per_frame() -> None:
    assert warm_up() >= 0.0
    assert warm_up() == 0.0  # done once per process
    assert all(n >= 1 for n in _signatures())
    before = _signatures()
    rng = np.random.default_rng(0)
    gray = (rng.random((120, 160)) * 255).astype(np.uint8)
    colour = np.dstack([gray] * 3)
    mask = rng.random(gray.shape) > 0.3
    frozen_gray, frozen_mask = gray.copy(), mask.astype(np.uint8)
    frozen_gray.flags.writeable = frozen_mask.flags.writeable = False  # another numba type if passed on
    cases = ((gray, None), (colour, mask), (gray[:100, :130], None), (gray, mask.astype(np.uint8)),
             (frozen_gray, frozen_mask), (np.asfortranarray(gray), None))
    for extractor in (OrbSlamExtractor(n_features=300), QtreeOrbExtractor(n_features=300)):
        for image, m in cases:
            assert len(extractor.extract(image, m)) > 0
    assert _signatures() == before
