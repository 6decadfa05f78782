"""ORB-SLAM's ORB extractor: pyramid numbers, quadtree against a literal port of
DistributeOctTree, orientation / descriptors against literal ports of IC_Angle /
computeOrbDescriptor and OpenCV, invariance on real images, mask, determinism."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial import cKDTree

from semslam.config import FeatureConfig
from semslam.core.types import Keypoints
from semslam.features import create_extractor, orb
from semslam.features.orb import (
    build_pyramid,
    detect_level,
    detect_level_reference,
    distribute_quadtree,
    distribute_quadtree_leaves,
    distribute_quadtree_levels,
    features_per_level,
    ic_angles,
    inv_level_sigma2,
    level_mask,
    level_sigma2,
    level_sizes,
    orb_descriptors,
    scale_factors,
)
from semslam.features.orb_slam2 import OrbSlamExtractor

N = 1000


# --------------------------------------------------------------------------- fixtures

@pytest.fixture(scope="module")
def extractor() -> OrbSlamExtractor:
    return OrbSlamExtractor()


# --------------------------------------------------------------------------- literal ports

def reference_octtree(x, y, response, width, height, n_wanted) -> np.ndarray:
    """Literal port of ORB-SLAM2 ``DistributeOctTree`` (lists of nodes, one split at a
    time); equal-sized nodes of the last phase ordered by top-left corner instead of by
    heap address, as the vectorised version documents."""
    n_ini = max(1, int(math.floor(width / height + 0.5)))
    hx = np.float32(width) / np.float32(n_ini)

    def node(x0, x1, y0, y1):
        return {"x0": x0, "x1": x1, "y0": y0, "y1": y1, "keys": []}

    def divide(n):
        mx = n["x0"] + math.ceil((n["x1"] - n["x0"]) / 2)
        my = n["y0"] + math.ceil((n["y1"] - n["y0"]) / 2)
        c = [node(n["x0"], mx, n["y0"], my), node(mx, n["x1"], n["y0"], my),
             node(n["x0"], mx, my, n["y1"]), node(mx, n["x1"], my, n["y1"])]
        for k in n["keys"]:
            if x[k] < mx:
                c[0 if y[k] < my else 2]["keys"].append(k)
            else:
                c[1 if y[k] < my else 3]["keys"].append(k)
        return [ch for ch in c if ch["keys"]]

    nodes = [node(int(np.float32(i) * hx), int(np.float32(i + 1) * hx), 0, int(height)) for i in range(n_ini)]
    for k in range(len(x)):
        nodes[min(int(np.float32(x[k]) / hx), n_ini - 1)]["keys"].append(k)
    nodes = [n for n in nodes if n["keys"]]
    while True:
        prev = len(nodes)
        new_nodes, expand = [], []
        for n in nodes:
            if len(n["keys"]) == 1:
                new_nodes.append(n)
                continue
            for c in divide(n):
                new_nodes.append(c)
                if len(c["keys"]) > 1:
                    expand.append(c)
        nodes = new_nodes
        if len(nodes) >= n_wanted or len(nodes) == prev:
            break
        if len(nodes) + 3 * len(expand) > n_wanted:
            while True:
                prev = len(nodes)
                candidates = sorted(expand, key=lambda n: (len(n["keys"]), -n["y0"], -n["x0"]))
                expand = []
                for n in reversed(candidates):
                    children = divide(n)
                    nodes = [m for m in nodes if m is not n] + children
                    expand += [c for c in children if len(c["keys"]) > 1]
                    if len(nodes) >= n_wanted:
                        break
                if len(nodes) >= n_wanted or len(nodes) == prev:
                    break
            break
    best = []
    for n in nodes:
        b = n["keys"][0]
        for k in n["keys"][1:]:
            if response[k] > response[b]:
                b = k
        best.append(b)
    return np.sort(np.array(best, dtype=np.intp))


def reference_ic_angle(image: np.ndarray, x: int, y: int) -> float:
    """Literal port of ORB-SLAM2 ``IC_Angle``."""
    umax = orb.umax()
    img = image.astype(np.int64)
    m10 = sum(u * img[y, x + u] for u in range(-15, 16))
    m01 = 0
    for v in range(1, 16):
        d = int(umax[v])
        v_sum = 0
        for u in range(-d, d + 1):
            plus, minus = img[y + v, x + u], img[y - v, x + u]
            v_sum += plus - minus
            m10 += u * (plus + minus)
        m01 += v * v_sum
    return cv2.fastAtan2(float(m01), float(m10))


def reference_descriptor(blurred: np.ndarray, x: int, y: int, angle: float) -> np.ndarray:
    """Literal port of ORB-SLAM2 ``computeOrbDescriptor`` (float maths, cvRound)."""
    rad = np.float32(angle) * np.float32(math.pi / 180.0)
    a, b = np.float32(math.cos(rad)), np.float32(math.sin(rad))
    pattern = orb.BIT_PATTERN_31
    out = np.zeros(32, np.uint8)

    def value(i):
        px, py = np.float32(pattern[i, 0]), np.float32(pattern[i, 1])
        return int(blurred[y + int(np.rint(px * b + py * a)), x + int(np.rint(px * a - py * b))])

    for byte in range(32):
        val = 0
        for bit in range(8):
            i = 2 * (8 * byte + bit)
            val |= int(value(i) < value(i + 1)) << bit
        out[byte] = val
    return out


# --------------------------------------------------------------------------- pyramid numbers

def test_features_per_level_matches_orb_slam() -> None:
    counts = features_per_level(1000, 8, 1.2)
    assert counts.tolist() == [217, 181, 151, 126, 105, 87, 73, 60]
    for n, levels, s in [(1000, 8, 1.2), (2000, 8, 1.2), (1500, 12, 1.2), (500, 4, 2.0), (37, 3, 1.5)]:
        c = features_per_level(n, levels, s)
        assert c.sum() == n and len(c) == levels
        f = 1 / s
        formula = n * (1 - f) / (1 - f**levels) * f ** np.arange(levels)
        assert np.all(np.abs(c[:-1] - formula[:-1]) <= 0.5 + 1e-3)
    assert features_per_level(1000, 1, 1.2).tolist() == [1000]


def test_scale_helpers() -> None:
    s = scale_factors(8, 1.2)
    assert np.allclose(s, 1.2 ** np.arange(8))
    assert np.allclose(level_sigma2(8, 1.2), s**2)
    assert np.allclose(inv_level_sigma2(8, 1.2) * level_sigma2(8, 1.2), 1.0)
    assert level_sizes(640, 480, 8, 1.2)[1] == (533, 400)


def test_pyramid_is_a_resize_chain_with_reflect_padding(real_gray: np.ndarray) -> None:
    pyr = build_pyramid(real_gray, 8, 1.2, pad=3)
    prev = real_gray
    for level, (view, row) in enumerate(zip(pyr.levels, pyr.rows)):
        ref = prev if level == 0 else cv2.resize(prev, (view.shape[1], view.shape[0]), interpolation=cv2.INTER_LINEAR)
        assert np.array_equal(view, ref)
        h, w = ref.shape
        padded = pyr.buffer[row - 3:row + h + 3, :w + 6]
        assert np.array_equal(padded, cv2.copyMakeBorder(ref, 3, 3, 3, 3, cv2.BORDER_REFLECT_101))
        prev = ref
    # Reusing the buffer gives the same pyramid.
    again = build_pyramid(real_gray, 8, 1.2, pad=3, buffer=pyr.buffer.copy())
    assert np.array_equal(again.buffer, pyr.buffer)


# --------------------------------------------------------------------------- quadtree

def _random_points(rng: np.random.Generator, width: int, height: int, n: int, clustered: bool):
    if clustered:
        cx, cy = rng.integers(0, width, 5), rng.integers(0, height, 5)
        c = rng.integers(0, 5, n)
        x = np.clip((cx[c] + rng.normal(0, width / 15, n)).astype(int), 0, width - 1)
        y = np.clip((cy[c] + rng.normal(0, height / 15, n)).astype(int), 0, height - 1)
        flat = np.unique(y * width + x)
        rng.shuffle(flat)
    else:
        flat = rng.choice(width * height, size=min(n, width * height), replace=False)
    return flat % width, flat // width


def test_quadtree_equals_literal_port() -> None:
    rng = np.random.default_rng(1)
    for case in range(80):
        w, h = int(rng.integers(20, 700)), int(rng.integers(20, 500))
        x, y = _random_points(rng, w, h, int(rng.integers(0, 1500)), clustered=case % 2 == 1)
        resp = rng.integers(0, 60, len(x)).astype(np.float32)  # many ties, like FAST scores
        n_wanted = int(rng.integers(1, 400))
        got = distribute_quadtree(x, y, resp, w, h, n_wanted)
        assert np.array_equal(got, reference_octtree(x, y, resp, w, h, n_wanted)), case


@settings(max_examples=60, deadline=None)
@given(st.integers(8, 120), st.integers(8, 90), st.integers(1, 60), st.integers(0, 2**31 - 1))
def test_quadtree_equals_literal_port_property(width: int, height: int, n_wanted: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    x, y = _random_points(rng, width, height, int(rng.integers(0, 300)), clustered=bool(seed % 2))
    resp = rng.integers(0, 8, len(x)).astype(np.float32)
    got = distribute_quadtree(x, y, resp, width, height, n_wanted)
    assert np.array_equal(got, reference_octtree(x, y, resp, width, height, n_wanted))


def test_quadtree_levels_batched_equals_one_level_at_a_time() -> None:
    rng = np.random.default_rng(2)
    xs, ys, rs, ls, ws, hs, ns = [], [], [], [], [], [], []
    for level in range(8):
        w, h = int(rng.integers(40, 600)), int(rng.integers(40, 450))
        x, y = _random_points(rng, w, h, int(rng.integers(0, 900)), clustered=level % 2 == 0)
        xs.append(x), ys.append(y), ws.append(w), hs.append(h), ns.append(int(rng.integers(0, 250)))
        rs.append(rng.integers(0, 50, len(x)).astype(np.float32)), ls.append(np.full(len(x), level))
    got = distribute_quadtree_levels(np.concatenate(xs), np.concatenate(ys), np.concatenate(rs),
                                     np.concatenate(ls), np.array(ws), np.array(hs), np.array(ns))
    offsets = np.cumsum([0] + [len(x) for x in xs])
    expected = np.concatenate([offsets[lv] + distribute_quadtree(xs[lv], ys[lv], rs[lv], ws[lv], hs[lv], ns[lv])
                               for lv in range(8)])
    assert np.array_equal(got, np.sort(expected))


def _occupied_cells(x: np.ndarray, y: np.ndarray, width: float, height: float, nx: int = 8, ny: int = 6) -> float:
    cells = np.clip((y / height * ny).astype(int), 0, ny - 1) * nx + np.clip((x / width * nx).astype(int), 0, nx - 1)
    return len(np.unique(cells)) / (nx * ny)


def test_quadtree_one_point_per_node_max_response_and_spread() -> None:
    rng = np.random.default_rng(3)
    w, h, n_wanted = 600, 440, 150
    x, y = _random_points(rng, w, h, 3000, clustered=False)
    # Responses much higher in the top-left ninth: top-N by response clusters there.
    resp = rng.random(len(x)) + 10.0 * ((x < w / 3) & (y < h / 3))
    keep, leaf = distribute_quadtree_leaves(x, y, resp, np.zeros(len(x), int), np.array([w]), np.array([h]),
                                            np.array([n_wanted]))
    assert n_wanted <= len(keep) <= n_wanted + 3  # ORB-SLAM may overshoot by up to 3
    # Exactly one kept point per leaf, and it is the leaf's best.
    assert np.array_equal(np.sort(leaf[keep]), np.arange(leaf.max() + 1))
    best = np.full(leaf.max() + 1, -np.inf)
    np.maximum.at(best, leaf, resp)
    assert np.array_equal(resp[keep], best[leaf[keep]])
    # Leaves are compact: the points of a leaf lie in a box no bigger than the image / 4.
    for lf in np.unique(leaf)[:40]:
        members = leaf == lf
        assert np.ptp(x[members]) < w / 4 and np.ptp(y[members]) < h / 4
    top = np.argsort(-resp)[:len(keep)]
    assert _occupied_cells(x[keep], y[keep], w, h) > 0.95
    assert _occupied_cells(x[keep], y[keep], w, h) > 2 * _occupied_cells(x[top], y[top], w, h)


def test_quadtree_degenerate_inputs() -> None:
    empty = np.zeros(0)
    assert len(distribute_quadtree(empty, empty, empty, 100, 100, 10)) == 0
    one = np.array([5.0])
    assert distribute_quadtree(one, one, one, 100, 100, 10).tolist() == [0]
    assert len(distribute_quadtree(one, one, one, 100, 100, 0)) == 0
    # Fewer points than wanted: all of them.
    x, y = np.array([1, 50, 90]), np.array([1, 60, 10])
    assert distribute_quadtree(x, y, np.ones(3), 100, 100, 10).tolist() == [0, 1, 2]


# --------------------------------------------------------------------------- detection

def test_detection_equals_per_cell_reference(real_gray: np.ndarray) -> None:
    pyr = build_pyramid(real_gray, 8, 1.2)
    for level in (0, 2, 5):
        image = pyr.levels[level]
        got, ref = detect_level(image, 20, 7), detect_level_reference(image, 20, 7)
        assert all(np.array_equal(u, v) for u, v in zip(got, ref))


@pytest.mark.parametrize("masked", [False, True])
def test_extractor_equals_reference_detection(real_grays: list[np.ndarray], synth_gray: np.ndarray,
                                              masked: bool) -> None:
    """The compiled per-cell detection is ORB-SLAM's, so the whole extractor equals the
    one running ORB-SLAM's literal per-cell OpenCV calls, keypoints and descriptors."""
    fast, reference = OrbSlamExtractor(), OrbSlamExtractor(reference_detection=True)
    for gray in [*real_grays, synth_gray, cv2.GaussianBlur(real_grays[0], (0, 0), 2.0)]:
        mask = None
        if masked:
            mask = np.full(gray.shape, 255, np.uint8)
            mask[100:300, 250:450] = 0
        a, b = fast.extract(gray, mask), reference.extract(gray, mask)
        for field in ("xy", "octave", "response", "angle", "descriptors"):
            assert np.array_equal(getattr(a, field), getattr(b, field)), field


def test_detection_order_is_cell_by_cell(real_gray: np.ndarray, extractor: OrbSlamExtractor) -> None:
    image = build_pyramid(real_gray, 8, 1.2).levels[0]
    x, y, _ = detect_level(image, 20, 7)
    grid = orb.CellGrid(image.shape[1] - 32, image.shape[0] - 32)
    key = (grid.cell_of(x, y) * 10_000 + y) * 10_000 + x
    assert np.all(np.diff(key) > 0)
    assert x.min() >= 3 and y.min() >= 3  # level pixels >= EDGE_THRESHOLD


# --------------------------------------------------------------------------- orientation, descriptors

def test_orientation_equals_literal_ic_angle(real_gray: np.ndarray) -> None:
    rng = np.random.default_rng(4)
    x, y = rng.integers(19, real_gray.shape[1] - 19, 40), rng.integers(19, real_gray.shape[0] - 19, 40)
    got = ic_angles(real_gray, x, y)
    ref = np.array([reference_ic_angle(real_gray, int(a), int(b)) for a, b in zip(x, y)], np.float32)
    assert np.allclose(got, ref, atol=1e-4)


def test_descriptors_equal_literal_port(real_gray: np.ndarray) -> None:
    blurred = cv2.GaussianBlur(real_gray, (7, 7), 2, sigmaY=2, borderType=cv2.BORDER_REFLECT_101)
    rng = np.random.default_rng(5)
    x, y = rng.integers(19, real_gray.shape[1] - 19, 30), rng.integers(19, real_gray.shape[0] - 19, 30)
    angle = np.concatenate([[0.0, 90.0, 180.0, 270.0, 45.0], rng.random(25) * 360]).astype(np.float32)
    got = orb_descriptors(blurred, x, y, angle)
    ref = np.stack([reference_descriptor(blurred, int(a), int(b), float(t)) for a, b, t in zip(x, y, angle)])
    assert np.array_equal(got, ref)


def test_descriptors_agree_with_opencv_orb(real_gray: np.ndarray) -> None:
    """Same pattern, steering and bit order as OpenCV's ORB (its internal blur differs by
    +-1 grey level on a few pixels, so a handful of bits may flip)."""
    rng = np.random.default_rng(6)
    x, y = rng.integers(40, real_gray.shape[1] - 40, 300), rng.integers(40, real_gray.shape[0] - 40, 300)
    angle = (rng.random(300) * 360).astype(np.float32)
    kps = [cv2.KeyPoint(float(a), float(b), 31, float(t), 1.0, 0) for a, b, t in zip(x, y, angle)]
    orb = cv2.ORB_create(nlevels=1, edgeThreshold=19, patchSize=31)
    out_kps, cv_desc = orb.compute(real_gray, kps)
    assert len(out_kps) == len(kps)
    assert np.allclose([k.angle for k in out_kps], angle)  # OpenCV kept our angles
    blurred = cv2.GaussianBlur(real_gray, (7, 7), 2, sigmaY=2, borderType=cv2.BORDER_REFLECT_101)
    ours = orb_descriptors(blurred, x, y, angle)
    bits_equal = np.unpackbits(ours, axis=1) == np.unpackbits(cv_desc, axis=1)
    assert bits_equal.mean() > 0.99


# --------------------------------------------------------------------------- whole extractor

def _check_keypoints(kp: Keypoints, shape: tuple[int, int]) -> None:
    n = len(kp)
    assert kp.xy.dtype == np.float32 and kp.xy.shape == (n, 2)
    assert kp.octave.dtype == np.int32 and kp.response.dtype == np.float32 and kp.angle.dtype == np.float32
    assert kp.descriptors.dtype == np.uint8 and kp.descriptors.shape == (n, 32)
    assert np.all(kp.xy >= 0) and np.all(kp.xy[:, 0] < shape[1]) and np.all(kp.xy[:, 1] < shape[0])
    assert np.all((kp.angle >= 0) & (kp.angle < 360))
    assert np.all(np.diff(kp.octave) >= 0)  # level by level, like ORB-SLAM


def test_counts_per_level_follow_the_formula(real_grays: list[np.ndarray], extractor: OrbSlamExtractor) -> None:
    wanted = features_per_level(N, 8, 1.2)
    for gray in real_grays:
        kp = extractor.extract(gray)
        _check_keypoints(kp, gray.shape)
        counts = np.bincount(kp.octave, minlength=8)
        assert np.all(counts >= wanted) and np.all(counts <= wanted + 3), counts
        assert N <= len(kp) <= N + 3 * 8
        # Level coordinates are integer pixels scaled by s^level (ORB-SLAM: pt * scale).
        lvl = kp.xy / scale_factors(8, 1.2).astype(np.float32)[kp.octave][:, None]
        assert np.allclose(lvl, np.round(lvl), atol=1e-3)


def test_synthetic_frame(synth_gray: np.ndarray, extractor: OrbSlamExtractor) -> None:
    kp = extractor.extract(synth_gray)
    _check_keypoints(kp, synth_gray.shape)
    assert len(kp) >= 0.9 * N
    assert _occupied_cells(kp.xy[:, 0], kp.xy[:, 1], 640, 480) > 0.7


def _match_points(kp_a: Keypoints, kp_b: Keypoints, ratio: float = 0.8) -> tuple[np.ndarray, np.ndarray]:
    matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
    pairs = matcher.knnMatch(kp_a.descriptors, kp_b.descriptors, k=2)
    good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < ratio * p[1].distance]
    ia = np.array([m.queryIdx for m in good], int)
    ib = np.array([m.trainIdx for m in good], int)
    return ia, ib


def test_rotation_by_90_degrees_rotates_angles(real_gray: np.ndarray, extractor: OrbSlamExtractor) -> None:
    kp0 = extractor.extract(real_gray)
    kp1 = extractor.extract(cv2.rotate(real_gray, cv2.ROTATE_90_CLOCKWISE))
    h = real_gray.shape[0]
    moved = np.c_[h - 1 - kp0.xy[:, 1], kp0.xy[:, 0]]  # (x, y) -> (h - 1 - y, x)
    dist, idx = cKDTree(kp1.xy).query(moved)
    same = (dist < 1.0) & (kp1.octave[idx] == kp0.octave)
    assert same.sum() >= 200
    # Image y points down: a clockwise quarter turn adds 90 degrees.
    diff = (kp1.angle[idx[same]] - kp0.angle[same] - 90.0 + 180.0) % 360.0 - 180.0
    assert np.median(np.abs(diff)) < 1.0
    assert np.mean(np.abs(diff) < 5.0) > 0.9


@pytest.mark.parametrize("use_synthetic", [False, True])
def test_descriptors_match_under_rotation_and_scale(use_synthetic: bool, request: pytest.FixtureRequest,
                                                    extractor: OrbSlamExtractor) -> None:
    gray = request.getfixturevalue("synth_gray" if use_synthetic else "real_gray")
    h, w = gray.shape
    warp = cv2.getRotationMatrix2D((w / 2, h / 2), 20.0, 1.2)
    warped = cv2.warpAffine(gray, warp, (w, h), flags=cv2.INTER_LINEAR)
    kp0, kp1 = extractor.extract(gray), extractor.extract(warped)
    ia, ib = _match_points(kp0, kp1)
    assert len(ia) >= 100
    predicted = kp0.xy[ia] @ warp[:, :2].T + warp[:, 2]
    err = np.linalg.norm(predicted - kp1.xy[ib], axis=1)
    assert np.mean(err < 3.0) >= 0.6


def test_mask_excludes_region_and_keeps_the_budget(real_gray: np.ndarray, extractor: OrbSlamExtractor) -> None:
    mask = np.full(real_gray.shape, 255, np.uint8)
    x0, y0, x1, y1 = 200, 120, 420, 360
    mask[y0:y1, x0:x1] = 0
    kp = extractor.extract(real_gray, mask)
    _check_keypoints(kp, real_gray.shape)
    px = np.rint(kp.xy).astype(int)
    assert np.all(mask[px[:, 1], px[:, 0]] > 0)  # documented rule: nearest level-0 pixel allowed
    inside = (kp.xy[:, 0] > x0 - 0.5) & (kp.xy[:, 0] < x1 - 0.5) & (kp.xy[:, 1] > y0 - 0.5) & (kp.xy[:, 1] < y1 - 0.5)
    assert not inside.any()
    assert len(kp) >= 0.9 * N
    # A boolean mask means the same.
    kp_bool = extractor.extract(real_gray, mask > 0)
    assert np.array_equal(kp_bool.xy, kp.xy)


def test_level_mask_samples_nearest_level0_pixel() -> None:
    rng = np.random.default_rng(7)
    mask = (rng.random((480, 640)) > 0.5).astype(np.uint8)
    scale = 1.2**3
    lm = level_mask(mask, (278, 370), scale)
    ys, xs = rng.integers(0, 278, 200), rng.integers(0, 370, 200)
    pos = np.rint(np.c_[xs, ys].astype(np.float32) * np.float32(scale)).astype(int)
    pos = np.minimum(pos, [639, 479])
    assert np.array_equal(lm[ys, xs], mask[pos[:, 1], pos[:, 0]])


def test_deterministic(real_gray: np.ndarray, extractor: OrbSlamExtractor) -> None:
    a = extractor.extract(real_gray)
    b = extractor.extract(real_gray.copy())
    c = OrbSlamExtractor().extract(real_gray)
    for other in (b, c):
        for field in ("xy", "octave", "response", "angle", "descriptors"):
            assert np.array_equal(getattr(a, field), getattr(other, field))


def test_registered_factory_uses_the_config(real_gray: np.ndarray) -> None:
    cfg = FeatureConfig(extractor="orb_slam2", n_features=500, scale_factor=1.3, n_levels=6,
                        fast_threshold=25, fast_min_threshold=5)
    ex = create_extractor(cfg)
    assert isinstance(ex, OrbSlamExtractor)
    old_name = create_extractor(FeatureConfig(extractor="orb_slam"))
    assert isinstance(old_name, OrbSlamExtractor)
    spec = ex.spec
    assert (spec.kind.value, spec.dim, spec.n_levels, spec.scale_factor) == ("binary", 32, 6, 1.3)
    assert (ex.n_features, ex.scale_factor, ex.n_levels, ex.fast_threshold, ex.fast_min_threshold) == (
        500, 1.3, 6, 25, 5)
    kp = ex.extract(real_gray)
    assert 500 <= len(kp) <= 500 + 18 and kp.octave.max() <= 5


def test_small_blank_and_colour_inputs() -> None:
    ex = OrbSlamExtractor()
    assert len(ex.extract(np.zeros((480, 640), np.uint8))) == 0
    assert len(ex.extract(np.zeros((20, 20), np.uint8))) == 0
    rng = np.random.default_rng(8)
    noise = cv2.GaussianBlur((rng.random((60, 80)) * 255).astype(np.uint8), (3, 3), 0)
    kp = ex.extract(noise)  # only the first levels are big enough for the border
    _check_keypoints(kp, noise.shape)
    assert len(kp) > 0
    colour = cv2.cvtColor(noise, cv2.COLOR_GRAY2BGR)
    assert np.array_equal(ex.extract(colour).xy, kp.xy)
    with pytest.raises(ValueError):
        ex.extract(noise.astype(np.float32))
    with pytest.raises(ValueError):
        ex.extract(noise, np.ones((10, 10), np.uint8))
