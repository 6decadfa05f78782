"""The compiled FAST of ``semslam.features.orb.fast_kernels`` against OpenCV's: the same
keypoints (x, y, score, order) as ``cv2.FastFeatureDetector`` (9/16, non-max suppression)
on random, real and synthetic images, with and without mask; the vectorised score
against the literal ``cornerScore<16>`` port; ORB-SLAM's per-cell detection against the
literal per-cell OpenCV calls (``detect_level_reference``)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from semslam.features.orb import (
    BORDER,
    MaskSampler,
    build_pyramid,
    detect_level,
    detect_level_reference,
    detect_levels,
    detection_levels,
    fast_points,
    fast_points_cv2,
    level_mask,
    level_mask_samplers,
    level_masks,
    scale_factors,
)
from semslam.features.orb import fast_kernels as fk
from semslam.features.orb.detection import cell_grid, detection_region


def _frames(shared_data: Path) -> dict[str, np.ndarray]:
    paths = sorted((shared_data / "kinect_rgbd_5frames" / "color").glob("*.png"))
    paths += sorted((shared_data / "images_people").glob("*.png"))
    if not paths:
        pytest.skip("no real frames in shared data")
    return {p.stem: cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in paths}


@pytest.fixture(scope="module")
def test_frames(shared_data: Path) -> dict[str, np.ndarray]:
    """The real frames, the rendered synthetic one and two texture-poor variants (many
    cells need the low threshold)."""
    from semslam.synth import SEQUENCES, Renderer

    frames = _frames(shared_data)
    rgb = Renderer(SEQUENCES["static_xyz"].replace(frames=3)).render(0).rgb
    frames["synthetic"] = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    first = next(iter(frames.values()))
    frames["blur1.5"] = cv2.GaussianBlur(first, (0, 0), 1.5)
    frames["blur3"] = cv2.GaussianBlur(first, (0, 0), 3.0)
    return frames


def _masks(shape: tuple[int, int], seed: int = 0) -> list[np.ndarray | None]:
    """No mask, a rectangle (a person box) and random blobs."""
    box = np.full(shape, 255, np.uint8)
    h, w = shape
    box[h // 4:3 * h // 4, w // 3:2 * w // 3] = 0
    rng = np.random.default_rng(seed)
    blobs = (cv2.GaussianBlur(rng.random(shape), (0, 0), max(1.0, min(shape) / 60)) > 0.5).astype(np.uint8)
    return [None, box, blobs]


def _same(a: tuple[np.ndarray, ...], b: tuple[np.ndarray, ...]) -> bool:
    return len(a) == len(b) and all(np.array_equal(u, v) and u.dtype == v.dtype for u, v in zip(a, b))


def _cv2_fast(threshold: int) -> cv2.FastFeatureDetector:
    return cv2.FastFeatureDetector_create(threshold, True, cv2.FAST_FEATURE_DETECTOR_TYPE_9_16)


# --------------------------------------------------------------------------- plain FAST

def test_fast_equals_opencv_on_random_images() -> None:
    rng = np.random.default_rng(0)
    images = [rng.integers(0, 256, shape, dtype=np.uint8) for shape in [(7, 7), (8, 9), (40, 33), (100, 120)]]
    images += [cv2.GaussianBlur(rng.integers(0, 256, (200, 300), dtype=np.uint8), (0, 0), s) for s in (0.7, 1.5)]
    images += [np.zeros((6, 50), np.uint8), np.zeros((30, 30), np.uint8)]
    for image in images:
        for t in (0, 1, 7, 20, 60, 255):
            for mask in _masks(image.shape, seed=t):
                ref = fast_points_cv2(_cv2_fast(t), image, mask)
                assert _same(fast_points(image, t, mask), ref), (image.shape, t)


def test_thresholds_outside_0_255_are_refused() -> None:
    """OpenCV clamps them in its scalar code and wraps them modulo 256 in its SIMD code
    (t = 300 finds corners of score >= 44); neither is meaningful."""
    image = np.zeros((50, 50), np.uint8)
    for t in (-1, 256):
        with pytest.raises(ValueError, match="0, 255"):
            fast_points(image, t)
        with pytest.raises(ValueError, match="0, 255"):
            detect_level(image, 20, t)


def test_fast_equals_opencv_on_test_frames(test_frames: dict[str, np.ndarray]) -> None:
    for name, gray in test_frames.items():
        for t in (7, 20):
            for mask in _masks(gray.shape):
                ref = fast_points_cv2(_cv2_fast(t), gray, mask)
                assert len(ref[0]) > 0 or name.startswith("blur")
                assert _same(fast_points(gray, t, mask), ref), (name, t)


def test_fast_reads_views_in_place() -> None:
    """A view of a bigger buffer (the stacked pyramid's levels), a read-only array and a
    boolean mask give the same as a contiguous copy."""
    rng = np.random.default_rng(1)
    big = cv2.GaussianBlur(rng.integers(0, 256, (150, 220), dtype=np.uint8), (0, 0), 1.0)
    view = big[10:130, 7:190]
    ref = fast_points_cv2(_cv2_fast(12), np.ascontiguousarray(view), None)
    assert _same(fast_points(view, 12), ref)
    frozen = view.copy()
    frozen.flags.writeable = False
    assert _same(fast_points(frozen, 12), ref)
    mask = rng.random(view.shape) > 0.4
    assert _same(fast_points(view, 12, mask), fast_points_cv2(_cv2_fast(12), np.ascontiguousarray(view),
                                                                mask.astype(np.uint8)))


def test_vectorised_score_equals_literal_port(test_frames: dict[str, np.ndarray]) -> None:
    """``score_corners`` (branch-free, over many corners) is ``_corner_score`` (OpenCV's
    loop), for every pixel that passes the corner test, at several thresholds."""
    d = np.empty(25, np.int32)
    for name in list(test_frames)[:3] + ["synthetic", "blur3"]:
        gray = test_frames[name]
        h, w = gray.shape
        work = np.ascontiguousarray(gray).reshape(-1)
        flags = np.zeros(w * h, np.uint8)
        positions = np.empty(w * h, np.int64)
        pix = fk._circle_offsets(w)
        for t in (0, 7, 20):
            fk._flag_rows(work, w, 3, h - 3, t, flags)
            n = fk._scan(flags, w, 3, h - 3, positions)
            got = np.empty(n, np.int16)
            fk.score_corners(work, w, positions, n, t, got)
            ref = np.array([fk._corner_score(work, p, pix, t, d) for p in positions[:n]], np.int16)
            assert n > 0 and np.array_equal(got, ref), (name, t)
            assert np.all(got >= t)


# --------------------------------------------------------------------------- ORB-SLAM's cells

def test_detect_level_equals_per_cell_reference(test_frames: dict[str, np.ndarray]) -> None:
    """Every level of every test frame, thresholds (20, 7) and a few others, with and
    without mask: the same keypoints, scores and order as ORB-SLAM's per-cell FAST calls."""
    for name, gray in test_frames.items():
        pyr = build_pyramid(gray, 8, 1.2)
        pairs = [(20, 7), (12, 3), (40, 20)] if name in ("synthetic", "blur1.5") else [(20, 7)]
        for mask in _masks(gray.shape):
            for level, image in enumerate(detection_levels(pyr.levels)):
                lmask = None if mask is None else level_mask(mask, image.shape, 1.2**level)
                for t_hi, t_lo in pairs:
                    ref = detect_level_reference(image, t_hi, t_lo, lmask)
                    assert _same(detect_level(image, t_hi, t_lo, lmask), ref), (name, level, t_hi, t_lo)


def test_detect_level_on_small_and_odd_inputs() -> None:
    rng = np.random.default_rng(2)
    for shape in [(33, 33), (38, 39), (39, 70), (45, 200), (61, 61), (97, 131)]:
        image = cv2.GaussianBlur(rng.integers(0, 256, shape, dtype=np.uint8), (0, 0), 0.8)
        for t_hi, t_lo in [(20, 7), (7, 20), (20, 20), (5, 0)]:
            for mask in _masks(shape, seed=shape[0]):
                ref = detect_level_reference(image, t_hi, t_lo, mask)
                assert _same(detect_level(image, t_hi, t_lo, mask), ref), (shape, t_hi, t_lo)


def test_cells_the_mask_forbids_entirely_are_skipped_with_the_same_keypoints(test_frames: dict[str, np.ndarray]
                                                                             ) -> None:
    """A cell whose every tested pixel is masked is neither scored nor retried at the low
    threshold (nothing found there could be kept): ``_masked_cells`` against a numpy
    reference, and on a frame with a person box (whole cells forbidden) and an all-zero
    mask the keypoints are still the per-cell reference's."""
    gray = test_frames["synthetic"]
    image = detection_levels(build_pyramid(gray, 8, 1.2).levels)[0]
    w, h = detection_region(image)
    g = cell_grid(w, h)
    box = _masks((h, w))[1]
    rows, cols = np.arange(h, dtype=np.int64), np.arange(w, dtype=np.int64)
    got = fk._masked_cells(w, h, g.n_cols, g.n_rows, g.w_cell, g.h_cell, box, rows, cols, True)
    ref = np.array([not box[3 + i * g.h_cell:min(3 + (i + 1) * g.h_cell, h - 3),
                            3 + j * g.w_cell:min(3 + (j + 1) * g.w_cell, w - 3)].any()
                    for i in range(g.n_rows) for j in range(g.n_cols)])
    assert ref.sum() >= 4 and not ref.all() and np.array_equal(got, ref)
    assert not fk._masked_cells(w, h, g.n_cols, g.n_rows, g.w_cell, g.h_cell, box, rows, cols, False).any()
    box = _masks(gray.shape)[1]
    for mask in (box, np.zeros_like(box)):
        lmask = level_mask(mask, image.shape, 1.0)
        assert _same(detect_level(image, 20, 7, lmask), detect_level_reference(image, 20, 7, lmask))
    assert len(detect_level(image, 20, 7, np.zeros_like(box))[0]) == 0


def test_detect_levels_with_mask_samplers_equals_materialised_masks(test_frames: dict[str, np.ndarray]) -> None:
    """The whole pyramid at once, the level masks sampled lazily (``MaskSampler``) or
    materialised (``level_masks``), against the per-level reference."""
    gray = test_frames["synthetic"]
    images = detection_levels(build_pyramid(gray, 8, 1.2).levels)
    scales = scale_factors(8, 1.2)
    for mask in _masks(gray.shape)[1:]:
        samplers = level_mask_samplers(mask, images, scales)
        dense = level_masks(mask, images, scales)
        assert all(np.array_equal(s.image(), m) for s, m in zip(samplers, dense))
        x, y, r, lv = detect_levels(images, 20, 7, samplers)
        for level, image in enumerate(images):
            ref = detect_level_reference(image, 20, 7, dense[level])
            sel = lv == level
            assert _same((x[sel], y[sel], r[sel]), ref), level
        # Samplers of different masks (stacked into one for the compiled call).
        separate = [MaskSampler.same_size(m) for m in dense]
        assert all(_same(a, b) for a, b in zip(detect_levels(images, 20, 7, separate), (x, y, r, lv)))
    assert np.all(np.diff(lv) >= 0)


def test_mask_sampler_crop() -> None:
    mask = (np.random.default_rng(3).random((40, 50)) > 0.5).astype(np.uint8)
    sampler = MaskSampler.same_size(mask)
    assert np.array_equal(sampler.crop(BORDER, 2, 20, 30).image(), mask[2:32, BORDER:BORDER + 20])
