"""The compiled orientation and descriptor kernels (``orb.brief_kernels``) against the
numpy versions they replaced (``ic_angles_numpy``, ``orb_descriptors_numpy``), on random
keypoints of the real frames and a synthetic one: angles identical (hence the same
30-degree bins ORB-SLAM's rotation histogram uses), descriptors byte-identical."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from semslam.features.orb import (
    build_pyramid,
    ic_angles,
    ic_angles_numpy,
    orb_descriptors,
    orb_descriptors_numpy,
)
from semslam.features.orb import descriptors as desc_module
from semslam.features.orb.brief_kernels import rotated_pattern


@pytest.fixture(scope="module")
def grays(shared_data: Path) -> list[np.ndarray]:
    paths = sorted((shared_data / "kinect_rgbd_5frames" / "color").glob("*.png"))
    paths += sorted((shared_data / "images_people").glob("*.png"))
    if not paths:
        pytest.skip("no real frames in shared data")
    from semslam.synth import SEQUENCES, Renderer

    rgb = Renderer(SEQUENCES["static_xyz"].replace(frames=3)).render(0).rgb
    return [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in paths] + [cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)]


def _stacked(gray: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The stacked pyramid buffer (what the extractors pass) and its blurred copy."""
    buffer = build_pyramid(gray, 8, 1.2, pad=3).buffer
    return buffer, cv2.GaussianBlur(buffer, (7, 7), 2, sigmaY=2, borderType=cv2.BORDER_REFLECT_101)


def test_angles_equal_numpy_version(grays: list[np.ndarray]) -> None:
    rng = np.random.default_rng(0)
    for gray in grays:
        buffer, _ = _stacked(gray)
        h, w = buffer.shape
        x, y = rng.integers(15, w - 15, 2000), rng.integers(15, h - 15, 2000)
        x[:3], y[:3] = [15, w - 16, 300], [15, h - 16, 20]  # the extreme windows
        got, ref = ic_angles(buffer, x, y), ic_angles_numpy(buffer, x, y)
        assert got.dtype == ref.dtype == np.float32
        assert np.allclose(got, ref, rtol=0, atol=1e-4)
        assert np.array_equal(got, ref)  # in fact bit-identical (same exact moments, same cv2.phase)
        assert np.array_equal((got / 30.0).astype(int), (ref / 30.0).astype(int))


def test_descriptors_equal_numpy_version(grays: list[np.ndarray]) -> None:
    rng = np.random.default_rng(1)
    for gray in grays:
        buffer, blurred = _stacked(gray)
        h, w = buffer.shape
        x, y = rng.integers(19, w - 19, 2000), rng.integers(19, h - 19, 2000)
        angle = np.concatenate([[0.0, 45.0, 90.0, 180.0, 270.0, 359.999],
                                rng.random(1994) * 360]).astype(np.float32)
        got = orb_descriptors(blurred, x, y, angle)
        assert got.shape == (2000, 32) and got.dtype == np.uint8
        assert np.array_equal(got, orb_descriptors_numpy(blurred, x, y, angle))
        # With the keypoints' own IC angles, as the extractors use them.
        own = ic_angles(buffer, x, y)
        assert np.array_equal(orb_descriptors(blurred, x, y, own), orb_descriptors_numpy(blurred, x, y, own))


def test_steering_rounding_is_the_numpy_versions() -> None:
    """What "same rounding" means, checked on the offsets themselves over many angles:
    the kernel's rint(fma(b, -py, a px)), rint(fma(b, px, a py)) equal the numpy
    version's rounded float32 (N, 2) @ (2, 512) BLAS products, before rounding too."""
    rng = np.random.default_rng(2)
    angle = np.concatenate([np.arange(0, 360, 0.25), rng.random(4000) * 360]).astype(np.float32)
    ab = desc_module._cos_sin(angle)
    col_ref = ab @ desc_module._PAT_X_ROT
    row_ref = ab @ desc_module._PAT_Y_ROT
    col, row = np.empty_like(col_ref), np.empty_like(row_ref)
    rotated_pattern(np.ascontiguousarray(ab[:, 0]), np.ascontiguousarray(ab[:, 1]), desc_module._PATTERN_X,
                    desc_module._PATTERN_Y, col, row)
    assert np.array_equal(col, np.rint(col_ref)) and np.array_equal(row, np.rint(row_ref))
    # Rounding half to even (cvRound), and exact multiples of 90 degrees give the pattern.
    assert np.array_equal(col[0], desc_module._PATTERN_X) and np.array_equal(row[0], desc_module._PATTERN_Y)


def test_keypoints_too_close_to_the_border_are_refused() -> None:
    image = np.zeros((60, 70), np.uint8)
    with pytest.raises(ValueError):
        ic_angles(image, np.array([14]), np.array([30]))
    with pytest.raises(ValueError):
        ic_angles(image, np.array([30]), np.array([45]))
    with pytest.raises(ValueError):
        orb_descriptors(image, np.array([30]), np.array([17]), np.array([0.0]))
    with pytest.raises(ValueError):
        orb_descriptors(image, np.array([52]), np.array([30]), np.array([0.0]))
    assert len(ic_angles(image, np.zeros(0, int), np.zeros(0, int))) == 0
    assert orb_descriptors(image, np.zeros(0, int), np.zeros(0, int), np.zeros(0)).shape == (0, 32)
    assert math.isfinite(float(ic_angles(image, np.array([54]), np.array([44]))[0]))
