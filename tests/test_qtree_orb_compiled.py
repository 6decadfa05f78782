"""The compiled Qtree-ORB (Algorithm 2 in one numba call, Harris in numba) against the
numpy versions it replaced: same candidates, Harris responses, keypoints, descriptors
and counts, on real TUM / Kinect frames and a render, with and without a mask, with
and without Algorithm 2's low-threshold pass."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from semslam.features.orb import BORDER, build_pyramid, level_mask_samplers, scale_factors
from semslam.features.orb.harris import harris_responses, harris_responses_numpy
from semslam.features.qtree_detection import detect_two_thresholds, detect_two_thresholds_numpy
from semslam.features.qtree_orb import QtreeOrbExtractor, paper_features_per_level

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
_FIELDS = ("xy", "octave", "response", "angle", "descriptors")


@pytest.fixture(scope="module")
def frames() -> dict[str, np.ndarray]:
    """A real TUM fr3 frame with a person, a real TUM fr2_desk frame and a render (all
    640x480), each also blurred (texture-poor: Algorithm 2's low pass runs)."""
    out: dict[str, np.ndarray] = {}
    for name, path in (("tum_fr3_walking", SHARED_DATA / "images_people" / "fr3_walking_person.png"),
                       ("tum_fr2_desk", next(iter(sorted((SHARED_DATA / "rgbd_dataset_freiburg2_desk_first50" / "rgb")
                                                         .glob("*.png"))), None))):
        if path is not None and Path(path).exists():
            out[name] = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    from semslam.synth import SEQUENCES, Renderer

    rgb = Renderer(SEQUENCES["walking_xyz"].replace(frames=3)).render(1).rgb
    out["render_walking_xyz"] = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    for name in list(out):
        out[f"{name}_blurred"] = cv2.GaussianBlur(out[name], (0, 0), 2.0)
    if not any(name.startswith("tum") for name in out):
        pytest.skip(f"no real frames under {SHARED_DATA}")
    return out


def _mask(shape: tuple[int, ...]) -> np.ndarray:
    mask = np.full(shape[:2], 255, np.uint8)
    mask[100:330, 230:420] = 0  # a person-sized hole
    return mask


def test_extractor_equals_numpy_reference(frames: dict[str, np.ndarray]) -> None:
    compiled, reference = QtreeOrbExtractor(), QtreeOrbExtractor(reference=True)
    low_pass_seen = False
    for name, gray in frames.items():
        for mask in (None, _mask(gray.shape)):
            a, b = compiled.extract(gray, mask), reference.extract(gray, mask)
            assert len(a) > 300, name
            for f in _FIELDS:
                assert np.array_equal(getattr(a, f), getattr(b, f)), (name, f, mask is None)
            assert compiled.last_counts.as_dict() == reference.last_counts.as_dict(), name
            assert np.array_equal(compiled.last_quality, reference.last_quality)
            assert np.array_equal(compiled.last_fast_score, reference.last_fast_score)
            low_pass_seen |= compiled.last_counts.L > 0
    assert low_pass_seen  # the blurred frames exercise the low-threshold pass


@pytest.mark.parametrize("thresholds", [(20, 7), (40, 5), (12, 12)])
def test_detection_equals_numpy_reference(frames: dict[str, np.ndarray], thresholds: tuple[int, int]) -> None:
    wanted = paper_features_per_level(1000, 6, 1.2)
    for name, gray in frames.items():
        levels = build_pyramid(gray, 6, 1.2, pad=3).levels
        for mask in (None, _mask(gray.shape)):
            samplers = level_mask_samplers(mask, levels, scale_factors(6, 1.2))
            a = detect_two_thresholds(levels, wanted, *thresholds, samplers)
            b = detect_two_thresholds_numpy(levels, wanted, *thresholds, samplers)
            for f in ("x", "y", "score", "high", "level", "n_high", "n_low"):
                assert np.array_equal(getattr(a, f), getattr(b, f)), (name, f)
                assert getattr(a, f).dtype == getattr(b, f).dtype, f


def test_detection_of_few_or_no_levels() -> None:
    """Budgets larger than anything a level holds (every low point of every cell goes in),
    a blank image (nothing at all) and one small level."""
    rng = np.random.default_rng(4)
    noise = cv2.GaussianBlur((rng.random((90, 120)) * 255).astype(np.uint8), (5, 5), 0)
    for image in (noise, np.zeros((90, 120), np.uint8)):
        for wanted in ([10_000], [0], [5]):
            a = detect_two_thresholds([image], np.array(wanted), 20, 7)
            b = detect_two_thresholds_numpy([image], np.array(wanted), 20, 7)
            for f in ("x", "y", "score", "high", "level", "n_high", "n_low"):
                assert np.array_equal(getattr(a, f), getattr(b, f)), f


def _harris_int(image: np.ndarray, x: int, y: int) -> float:
    """OpenCV's ``HarrisResponses`` for one pixel in Python integers (the exact a, b, c)."""
    img = image.astype(np.int64)
    a = b = c = 0
    for yy in range(y - 3, y + 4):
        for xx in range(x - 3, x + 4):
            ix = 2 * (img[yy, xx + 1] - img[yy, xx - 1]) + img[yy - 1, xx + 1] - img[yy - 1, xx - 1] \
                + img[yy + 1, xx + 1] - img[yy + 1, xx - 1]
            iy = 2 * (img[yy + 1, xx] - img[yy - 1, xx]) + img[yy + 1, xx - 1] - img[yy - 1, xx - 1] \
                + img[yy + 1, xx + 1] - img[yy - 1, xx + 1]
            a, b, c = a + ix * ix, b + iy * iy, c + ix * iy
    fa, fb, fc = float(a), float(b), float(c)
    return (fa * fb - fc * fc - 0.04 * (fa + fb) ** 2) * (1.0 / (4.0 * 7.0 * 255.0)) ** 4


def test_harris_equals_numpy_and_exact_integers(frames: dict[str, np.ndarray]) -> None:
    rng = np.random.default_rng(5)
    # A checkerboard of 0/255 squares: sums far above 2^24, where float32 sums round.
    board = ((np.indices((60, 80)).sum(0) // 1) % 2 * 255).astype(np.uint8)
    board = np.kron(board, np.ones((3, 3), np.uint8))
    for image in [*frames.values(), board]:
        h, w = image.shape
        x = np.r_[rng.integers(4, w - 4, 400), 4, w - 5, w - 5]  # the extreme columns and rows too
        y = np.r_[rng.integers(4, h - 4, 400), 4, h - 5, 4]
        got = harris_responses(image, x, y)
        assert np.array_equal(got, harris_responses_numpy(image, x, y))
        assert np.array_equal(got[-3:], [_harris_int(image, int(a), int(b)) for a, b in zip(x[-3:], y[-3:])])
    with pytest.raises(ValueError):
        harris_responses(board, np.array([3]), np.array([10]))
    # The candidates of a real pyramid, read in place in the stacked buffer.
    gray = next(g for n, g in frames.items() if n.startswith("tum"))
    pyr = build_pyramid(gray, 6, 1.2, pad=3)
    det = detect_two_thresholds(pyr.levels, paper_features_per_level(1000, 6, 1.2), 20, 7)
    sx, sy = det.x + BORDER + pyr.pad, det.y + BORDER + pyr.rows[det.level]
    assert np.array_equal(harris_responses(pyr.buffer, sx, sy), harris_responses_numpy(pyr.buffer, sx, sy))
