"""Semantic-thread scheduling: a skipped frame gets the last segmented mask, warped.

The warp is checked against geometry on a fronto-parallel plane (known depth, known
motion); the scheduler with a segmenter that blocks until told (a backlog on demand) and
paints a per-frame rectangle, so which frame a mask came from is visible.
"""

from __future__ import annotations

import threading

import numpy as np
import pytest

from semslam.config import SemanticsConfig, load_config
from semslam.config.checks import check_values
from semslam.core import registry
from semslam.core.protocols import MotionPrior
from semslam.core.types import Frame, LabelMap
from semslam.dynamics.masks import dilate
from semslam.dynamics.semantic_thread import SemanticThread
from semslam.dynamics.warp import relative_pose, warp_mask
from semslam.errors import ConfigError
from semslam.geometry.camera import PinholeCamera

H, W = 120, 160
CAM = PinholeCamera(100.0, 100.0, 80.0, 60.0, width=W, height=H)


def _translation(x: float = 0.0, y: float = 0.0, z: float = 0.0) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = (x, y, z)
    return T


def _rect(v0: int, v1: int, u0: int, u1: int) -> np.ndarray:
    m = np.zeros((H, W), bool)
    m[v0:v1, u0:u1] = True
    return m


# ---------------------------------------------------------------- warp


def test_warp_sideways_on_a_plane_shifts_by_f_b_over_z() -> None:
    """Camera 0.1 m to the right, plane at 2 m: everything moves fx * 0.1 / 2 = 5 px left;
    masked pixels without depth move with the median depth of the others (2 m too)."""
    depth = np.full((H, W), 2.0, np.float32)
    depth[50:55, :] = 0.0
    T_kj = _translation(x=-0.1)  # j's coordinates in k: the camera moved by +0.1 m
    out = warp_mask(_rect(40, 70, 60, 90), depth, CAM, T_kj)
    assert np.array_equal(out, _rect(40, 70, 55, 85))
    # The margin grows the warped mask, nothing else.
    assert np.array_equal(warp_mask(_rect(40, 70, 60, 90), depth, CAM, T_kj, margin_px=3), _rect(37, 73, 52, 88))


def test_warp_towards_a_plane_scales_about_the_principal_point() -> None:
    """Camera 1 m closer to a plane at 2 m: offsets from (cx, cy) double, and the mask is
    the whole scaled rectangle (no holes)."""
    depth = np.full((H, W), 2.0, np.float32)
    out = warp_mask(_rect(50, 70, 70, 90), depth, CAM, _translation(z=-1.0))
    # Pixel footprints u in [69.5, 89.5] -> (u - 80) * 2 + 80 in [59, 99]: pixel centres
    # 59..98; rows [49.5, 69.5] -> (v - 60) * 2 + 60 in [39, 79]: 39..78.
    assert np.array_equal(out, _rect(39, 79, 59, 99))


def test_warp_rotation_follows_the_homography() -> None:
    """A pure rotation moves pixels by K R K^-1 whatever the depth."""
    depth = np.random.default_rng(0).uniform(1.0, 4.0, (H, W)).astype(np.float32)
    a = np.deg2rad(2.0)
    T_kj = np.eye(4)
    T_kj[:3, :3] = [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]
    src = _rect(40, 60, 70, 90)
    out = warp_mask(src, depth, CAM, T_kj)
    v, u = np.nonzero(src)
    p = CAM.K @ T_kj[:3, :3] @ np.linalg.inv(CAM.K) @ np.stack([u, v, np.ones_like(u)])
    expect = np.zeros((H, W), bool)
    expect[np.rint(p[1] / p[2]).astype(int), np.rint(p[0] / p[2]).astype(int)] = True
    # Every source pixel centre lands where the homography says, give or take the rounding
    # of a pixel on the rim; the area is kept (a small rotation hardly changes it).
    assert not (out & ~dilate(expect, 1)).any() and not (expect & ~dilate(out, 1)).any()
    assert abs(int(out.sum()) - int(src.sum())) <= 0.03 * src.sum()


def test_warp_without_pose_or_depth_keeps_the_mask_and_adds_the_margin() -> None:
    src = _rect(40, 70, 60, 90)
    assert np.array_equal(warp_mask(src, None, CAM, _translation(x=1.0), 2), _rect(38, 72, 58, 92))
    assert np.array_equal(warp_mask(src, np.ones((H, W), np.float32), CAM, None, 0), src)
    assert not warp_mask(np.zeros((H, W), bool), np.ones((H, W), np.float32), CAM, _translation(x=1.0)).any()
    # T_kj from the source's pose and the predicted pose of k; none without either.
    T_src, T_pred = _translation(x=0.5), _translation(x=0.3)
    assert np.allclose(relative_pose(T_src, T_pred), _translation(x=-0.2))
    assert relative_pose(None, T_pred) is None and relative_pose(T_src, None) is None


def test_warping_the_masks_box_equals_warping_the_whole_image() -> None:
    """``warp_mask`` warps only where the mask's bounding box lands; on random blobs and
    motions (sideways, towards, behind the horizon, off the image) it gives the pixels of
    one ``cv2.warpPerspective`` over the whole image, and a plane depth given by the caller
    (the scheduler measures it once per source) gives the same as measuring it."""
    import cv2

    from semslam.dynamics.warp import plane_depth, plane_homography

    rng = np.random.default_rng(3)
    checked = 0
    for i in range(200):
        src = np.zeros((H, W), bool)
        for _ in range(rng.integers(1, 4)):
            v0, u0 = rng.integers(0, H - 5), rng.integers(0, W - 5)
            src[v0:v0 + rng.integers(3, 60), u0:u0 + rng.integers(3, 80)] = True
        depth = rng.uniform(0.5, 5.0, (H, W)).astype(np.float32)
        rot, _ = cv2.Rodrigues(rng.normal(size=3) * (0.02 if i % 3 else 0.3))
        T_kj = np.eye(4)
        T_kj[:3, :3], T_kj[:3, 3] = rot, rng.normal(size=3) * (0.05 if i % 3 else 1.0)
        full = cv2.warpPerspective(src.view(np.uint8), plane_homography(T_kj, CAM, plane_depth(src, depth)),
                                   (W, H), flags=cv2.INTER_NEAREST).view(bool)
        out = warp_mask(src, depth, CAM, T_kj)
        assert np.array_equal(out, full), i
        assert np.array_equal(warp_mask(src, depth, CAM, T_kj, 2, plane_depth(src, depth)), dilate(full, 2)), i
        checked += int(full.any())
    assert checked > 100  # most motions keep part of the mask in view


# ---------------------------------------------------------------- scheduler


class _Blocking:
    """Paints frame i's person as a 10 px wide rectangle at u = 20 + 10 i; waits for ``go``."""

    name = "blocking"
    names = {0: "background", 15: "person"}

    def __init__(self) -> None:
        self.go = threading.Event()
        self.go.set()
        self.calls: list[int] = []

    def segment(self, rgb: np.ndarray, frame: Frame | None = None) -> LabelMap:
        assert frame is not None
        self.go.wait(10)
        self.calls.append(frame.index)
        labels = np.zeros(rgb.shape[:2], np.uint8)
        labels[20:40, 20 + 10 * frame.index:30 + 10 * frame.index] = 15
        return LabelMap(labels, dict(self.names))

    def close(self) -> None:
        self.go.set()


_SEGMENTER = _Blocking()


def blocking(cfg: SemanticsConfig) -> _Blocking:
    return _SEGMENTER


@pytest.fixture
def segmenter(monkeypatch: pytest.MonkeyPatch) -> _Blocking:
    global _SEGMENTER
    _SEGMENTER = _Blocking()
    monkeypatch.setitem(registry.PLUGINS["segmenter"], "test_blocking", "tests.test_semantic_schedule:blocking")
    return _SEGMENTER


def _frames(n: int, depth_m: float = 2.0) -> list[Frame]:
    rgb = np.zeros((H, W, 3), np.uint8)
    return [Frame(i, i / 30, rgb, np.full((H, W), depth_m, np.float32)) for i in range(n)]


def _painted(index: int) -> np.ndarray:
    return _rect(20, 40, 20 + 10 * index, 30 + 10 * index)


def _thread(schedule: str = "every", stride: int = 1, threaded: bool = True, margin: int = 0) -> SemanticThread:
    cfg = SemanticsConfig(backend="test_blocking", dynamic_classes=["person"], schedule=schedule, stride=stride,
                          warp_margin_px=margin)
    return SemanticThread(cfg, threaded=threaded, camera=CAM)


def test_when_behind_skips_a_frame_and_gives_it_the_last_segmented_mask(segmenter: _Blocking) -> None:
    st = _thread("when_behind")
    try:
        p = _frames(3)
        segmenter.go.clear()  # frame 0's segmentation hangs: a backlog
        st.prepare(p[0])
        st.prepare(p[1])  # decoded while 0 is still segmented -> skipped
        segmenter.go.set()
        m0, _ = st.mask(p[0])
        m1, _ = st.mask(p[1])  # no motion prior: frame 0's mask as it was
        st.prepare(p[2])  # the segmenter has caught up: 2 is segmented
        m2, _ = st.mask(p[2])
    finally:
        st.close()
    assert segmenter.calls == [0, 2]
    assert np.array_equal(m0, _painted(0)) and np.array_equal(m1, _painted(0)) and np.array_equal(m2, _painted(2))
    stats = st.stats()
    assert (stats["segmented_frames"], stats["warped_frames"]) == (2, 1)


def test_latest_does_not_wait_and_uses_the_late_mask_once_finished(segmenter: _Blocking) -> None:
    """Frame 1's segmentation hangs: tracking takes frame 0's mask for it instead of waiting;
    frame 2 (skipped: decoded while 1 was segmented) gets frame 1's, finished meanwhile."""
    st = _thread("latest")
    try:
        p = _frames(3)
        st.prepare(p[0])
        m0, _ = st.mask(p[0])
        segmenter.go.clear()
        st.prepare(p[1])
        st.prepare(p[2])
        late = st._pending  # frame 1's segmentation (frame 2 was skipped: looking inside)
        m1, _ = st.mask(p[1])
        segmenter.go.set()
        assert late is not None and not isinstance(late, np.ndarray)
        late.result()
        m2, _ = st.mask(p[2])
    finally:
        st.close()
    assert segmenter.calls == [0, 1]
    assert np.array_equal(m0, _painted(0)) and np.array_equal(m1, _painted(0)) and np.array_equal(m2, _painted(1))
    stats = st.stats()
    assert (stats["frames_without_own_mask"], stats["warped_frames"], stats["segmented_frames"]) == (1, 2, 2)


def test_every_waits_through_the_backlog(segmenter: _Blocking) -> None:
    st = _thread("every")
    try:
        p = _frames(2)
        segmenter.go.clear()
        st.prepare(p[0])
        st.prepare(p[1])
        segmenter.go.set()
        masks = [st.mask(q)[0] for q in p]
    finally:
        st.close()
    assert segmenter.calls == [0, 1]
    assert np.array_equal(masks[1], _painted(1))


@pytest.mark.parametrize("threaded", [False, True])
def test_stride_warps_skipped_frames_with_the_motion_model(segmenter: _Blocking, threaded: bool) -> None:
    """Stride 2: frames 1 and 3 get the masks of 0 and 2, moved by the motion model. The
    camera moves 0.1 m right per frame in front of a plane at 2 m: 5 px left per frame."""
    st = _thread(stride=2, threaded=threaded, margin=1)
    step = _translation(x=-0.1)  # T_cw(k) = step @ T_cw(k-1)
    try:
        p = _frames(4)
        for q in p:
            st.prepare(q)
        masks, T_cw = [], np.eye(4)
        for i, q in enumerate(p):
            prior = None if i == 0 else MotionPrior(i - 1, T_cw, step)
            masks.append(st.mask(q, prior)[0])
            if i > 0:
                T_cw = step @ T_cw
    finally:
        st.close()
    assert segmenter.calls == [0, 2]
    assert np.array_equal(masks[0], _painted(0)) and np.array_equal(masks[2], _painted(2))
    for k in (1, 3):
        grown = _rect(19, 41, 20 + 10 * (k - 1) - 5 - 1, 30 + 10 * (k - 1) - 5 + 1)
        assert np.array_equal(masks[k], grown), k
    # Lost tracking (no velocity): the mask stays where it was, grown by the margin only.
    st2 = _thread(stride=2, threaded=False)
    try:
        q = _frames(2)
        st2.mask(q[0])
        m1, _ = st2.mask(q[1], MotionPrior(0, np.eye(4), None))
    finally:
        st2.close()
    assert np.array_equal(m1, _painted(0))


# ---------------------------------------------------------------- config


@pytest.mark.parametrize(("field", "value", "message"), [
    ("schedule", "sometimes", "semantics.schedule: expected one of every, when_behind, latest, got 'sometimes'"),
    ("stride", 0, "semantics.stride: expected an integer >= 1, got 0"),
    ("warp", "flow", "semantics.warp: expected one of pose, none, got 'flow'"),
    ("warp_margin_px", -2, r"semantics.warp_margin_px: expected an integer in \[0, 10000\], got -2"),
])
def test_schedule_config_errors(field: str, value: object, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        check_values(SemanticsConfig(**{field: value}), "semantics")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match=message):
        load_config("default", [f"semantics.{field}={value}"])


def test_schedule_config_defaults() -> None:
    cfg = load_config("default").semantics  # tracking takes the newest finished mask
    assert (cfg.schedule, cfg.stride, cfg.warp) == ("latest", 2, "pose")
    assert load_config("stdc").semantics.schedule == "every"  # STDC-SLAM waits for its own
    cfg = load_config("default", ["semantics.schedule=when_behind", "semantics.stride=2"]).semantics
    assert (cfg.schedule, cfg.stride) == ("when_behind", 2)


def test_margin_grows_with_the_frames_since_the_segmented_one(segmenter: _Blocking) -> None:
    """The people's own motion adds up: stride 3, margin 2 px -> frame 1 grown 2 px, frame 2 4 px."""
    st = _thread(stride=3, threaded=False, margin=2)
    try:
        masks = [st.mask(q)[0] for q in _frames(3)]
    finally:
        st.close()
    assert segmenter.calls == [0]
    assert np.array_equal(masks[1], dilate(_painted(0), 2)) and np.array_equal(masks[2], dilate(_painted(0), 4))


# ---------------------------------------------------------------- priorities


def _niceness() -> int:
    import os

    return os.getpriority(os.PRIO_PROCESS, threading.get_native_id())


#: (thread name, niceness) where ``recording`` built each backend.
_BUILT_ON: list[tuple[str, int]] = []


def recording(cfg: SemanticsConfig) -> _Blocking:
    _BUILT_ON.append((threading.current_thread().name, _niceness()))
    return _Blocking()


def test_latest_builds_the_backend_on_the_niced_semantic_thread(monkeypatch: pytest.MonkeyPatch) -> None:
    """A backend's own inference threads (MediaPipe's graph) inherit the niceness of the
    thread that builds it: with ``latest`` that is the semantic thread, below tracking; with
    ``every`` tracking waits for the masks, so nothing is niced."""
    import os

    from semslam.runtime import BACKGROUND_NICE

    if not hasattr(os, "setpriority") or BACKGROUND_NICE <= 0:
        pytest.skip("no per-thread priorities here")
    _BUILT_ON.clear()
    monkeypatch.setitem(registry.PLUGINS["segmenter"], "test_recording", "tests.test_semantic_schedule:recording")
    base = os.getpriority(os.PRIO_PROCESS, os.getpid())
    for schedule, nice in (("latest", min(19, base + BACKGROUND_NICE)), ("every", base)):
        cfg = SemanticsConfig(backend="test_recording", dynamic_classes=["person"], schedule=schedule)
        SemanticThread(cfg, threaded=True, camera=CAM).close()
        name, niceness = _BUILT_ON[-1]
        assert name.startswith("semantic") and niceness == nice, (schedule, _BUILT_ON)


def test_a_thread_is_niced_relative_to_the_process_not_twice() -> None:
    """A pool's worker starts in whichever thread first submits to it and inherits its
    niceness: lowering it again must not add up (the reader's pool once put the semantic
    thread at twice the background niceness)."""
    import os

    from semslam.runtime import lower_thread_priority

    if not hasattr(os, "setpriority"):
        pytest.skip("no per-thread priorities here")
    base = os.getpriority(os.PRIO_PROCESS, os.getpid())
    seen: list[int] = []

    def inner() -> None:
        lower_thread_priority(3)
        seen.append(_niceness())

    def outer() -> None:
        lower_thread_priority(3)
        seen.append(_niceness())
        lower_thread_priority(3)  # again: no change
        seen.append(_niceness())
        t = threading.Thread(target=inner)  # inherits 3, asks for 3: stays 3
        t.start()
        t.join()

    t = threading.Thread(target=outer)
    t.start()
    t.join()
    assert seen == [min(19, base + 3)] * 3
    assert _niceness() == base  # the calling thread is untouched
