"""The compiled 7x7 Gaussian blur of the pyramid levels (``orb.blur``) against OpenCV's
``GaussianBlur`` (the call ORB-SLAM makes): byte-identical on every level's pixels, on the
real frames, on random images and on the extremes; and ORB-SLAM's extractor gives the
descriptors of the OpenCV blur."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from semslam.features.orb import build_pyramid
from semslam.features.orb.blur import blur_levels, blur_levels_reference, gaussian_kernel_q8
from semslam.features.orb.descriptors import SteeredBrief


def _level_pixels(pyr, image: np.ndarray) -> list[np.ndarray]:
    return [image[r:r + lv.shape[0], pyr.pad:pyr.pad + lv.shape[1]] for lv, r in zip(pyr.levels, pyr.rows)]


def _images(shared_data: Path) -> list[np.ndarray]:
    paths = sorted((shared_data / "kinect_rgbd_5frames" / "color").glob("*.png"))
    paths += sorted((shared_data / "images_people").glob("*.png"))
    rng = np.random.default_rng(7)
    images = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in paths]
    images += [rng.integers(0, 256, (480, 640), dtype=np.uint8), rng.integers(0, 256, (97, 131), dtype=np.uint8),
               np.full((480, 640), 255, np.uint8), np.zeros((480, 640), np.uint8)]
    return images


def test_kernel_taps_are_opencvs_fixed_point_ones() -> None:
    # Symmetric, summing to 1.0 in 8 fractional bits, within one unit of the ideal kernel;
    # that they are OpenCV's own taps is what the blur tests below check (same bytes).
    taps = gaussian_kernel_q8(7, 2.0)
    assert taps.sum() == 256 and (taps == taps[::-1]).all()
    ideal = cv2.getGaussianKernel(7, 2.0).ravel() * 256
    assert np.abs(taps - ideal).max() < 1.0
    with pytest.raises(ValueError, match="odd ksize"):
        gaussian_kernel_q8(6, 2.0)


def test_levels_blur_equals_opencv_on_every_level(shared_data: Path) -> None:
    for gray in _images(shared_data):
        pyr = build_pyramid(gray, 8, 1.2, pad=3)
        out = np.zeros_like(pyr.buffer)
        blur_levels(pyr, out)
        reference = blur_levels_reference(pyr)
        for ours, theirs in zip(_level_pixels(pyr, out), _level_pixels(pyr, reference)):
            np.testing.assert_array_equal(ours, theirs)
        # each level blurred on its own as ORB-SLAM does (a clone, BORDER_REFLECT_101)
        for lv, ours in zip(pyr.levels, _level_pixels(pyr, out)):
            alone = cv2.GaussianBlur(np.ascontiguousarray(lv), (7, 7), 2, sigmaY=2,
                                     borderType=cv2.BORDER_REFLECT_101)
            np.testing.assert_array_equal(ours, alone)


def test_levels_blur_reuses_its_ring_and_checks_its_arguments() -> None:
    gray = np.random.default_rng(1).integers(0, 256, (120, 160), dtype=np.uint8)
    pyr = build_pyramid(gray, 4, 1.2, pad=3)
    out = np.zeros_like(pyr.buffer)
    ring = blur_levels(pyr, out)
    assert blur_levels(pyr, out, ring) is ring
    with pytest.raises(ValueError, match="out must be uint8"):
        blur_levels(pyr, np.zeros((5, 5), np.uint8))
    with pytest.raises(ValueError, match="padding"):
        blur_levels(build_pyramid(gray, 2, 1.2, pad=2), out)


def test_descriptors_are_those_of_the_opencv_blur(shared_data: Path) -> None:
    from semslam.features.orb import orb_descriptors

    gray = _images(shared_data)[0]
    pyr = build_pyramid(gray, 8, 1.2, pad=3)
    rng = np.random.default_rng(3)
    level = rng.integers(0, 8, 500)
    x = np.array([rng.integers(19, pyr.levels[lv].shape[1] - 19) for lv in level]) + pyr.pad
    y = np.array([rng.integers(19, pyr.levels[lv].shape[0] - 19) for lv in level]) + pyr.rows[level]
    angle, ours = SteeredBrief().compute(pyr, x, y)
    np.testing.assert_array_equal(ours, orb_descriptors(blur_levels_reference(pyr), x, y, angle))
    with pytest.raises(ValueError, match="inside their pyramid level"):
        SteeredBrief().compute(pyr, np.array([pyr.pad + 5]), np.array([pyr.rows[0] + 100]))
