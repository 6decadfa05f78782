"""SIFT through the descriptor-neutral ORB-SLAM core: the extractor and its spec, search by
bag-of-words over the flat vocabulary (= brute force with the L2 matcher), the one-line
refusal of loop closing without a vocabulary, and the whole ``orb_slam`` tracker with
``features.extractor=sift`` through the CLI on a static synthetic render.

Bound: a static scene rotating +-12/18/15 degrees (``rpy``) over 90 frames, 6 keyframes
with SIFT (so local mapping, local BA and keyframe culling run on float descriptors);
measured ATE 0.28 cm (ORB on the same render: 0.45 cm). The bound (< 2 cm) is the one
the other static end-to-end tests use.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from semslam.cli.main import main
from semslam.config import FeatureConfig, load_config
from semslam.core.types import DescriptorKind
from semslam.errors import ConfigError
from semslam.eval.metrics import ate
from semslam.features import create_extractor
from semslam.features.matching import L2Matcher, matcher_for
from semslam.features.sift import N_LEVELS, SCALE_FACTOR, SiftExtractor, sift_levels
from semslam.io.trajectory import read_tum
from semslam.place.flat import FlatVocabulary, vocabulary_for
from semslam.slam.orb.map_io import load_map
from semslam.slam.orb.search import search_by_bow
from semslam.synth import SynthConfig, render_sequence


@pytest.fixture(scope="module")
def real_pair(shared_data: Path) -> tuple[np.ndarray, np.ndarray]:
    paths = sorted((shared_data / "kinect_rgbd_5frames" / "color").glob("*.png"))[:2]
    a, b = (cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in paths)
    return a, b


def test_extractor_and_spec(real_pair: tuple[np.ndarray, np.ndarray]) -> None:
    ex = create_extractor(FeatureConfig(extractor="sift", n_features=500))
    assert isinstance(ex, SiftExtractor)
    spec = ex.spec
    assert (spec.kind, spec.dim) == (DescriptorKind.FLOAT, 128)
    assert (spec.n_levels, spec.scale_factor) == (N_LEVELS, SCALE_FACTOR)
    assert spec.dtype is np.float32 and 0 < spec.th_low < spec.th_high < np.sqrt(2)
    kp = ex.extract(real_pair[0])
    assert 450 <= len(kp) <= 520
    assert kp.descriptors.dtype == np.float32 and kp.descriptors.shape[1] == 128
    assert np.allclose(np.linalg.norm(kp.descriptors, axis=1), 1.0, atol=1e-5)  # RootSIFT: unit
    assert kp.octave.min() >= 0 and kp.octave.max() <= N_LEVELS - 1
    assert len(np.unique(kp.octave)) > 6
    mask = np.ones_like(real_pair[0])
    mask[:, :320] = 0
    masked = ex.extract(real_pair[0], mask)
    assert len(masked) > 100 and (masked.xy[:, 0] >= 319.5).all()
    assert len(ex.extract(np.zeros((48, 64), np.uint8))) == 0


def test_octave_to_level() -> None:
    # OpenCV packs octave (signed low byte) and layer (1..3): octave -1 layer 1 is level 0.
    packed = np.array([(1 << 8) | 255, (3 << 8) | 255, (1 << 8) | 0, (2 << 8) | 2, (1 << 8) | 5])
    assert sift_levels(packed).tolist() == [0, 2, 3, 10, N_LEVELS - 1]


def test_flat_vocabulary_search_is_brute_force(real_pair: tuple[np.ndarray, np.ndarray]) -> None:
    ex = SiftExtractor(800)
    ka, kb = (ex.extract(g) for g in real_pair)
    voc = vocabulary_for(ex.spec, "default")
    assert isinstance(voc, FlatVocabulary) and not voc.recognises_places
    (bow_a, fa), (_, fb) = voc.transform(ka.descriptors), voc.transform(kb.descriptors)
    assert list(fa) == [0] and len(fa[0]) == len(ka) and len(bow_a) == 1
    ia, ib = search_by_bow(fa, ka.descriptors, fb, kb.descriptors, np.ones(len(ka), bool),
                           np.ones(len(kb), bool), matcher_for(ex.spec), ex.spec.th_low, 0.7)
    qi, ti, _ = L2Matcher().match_brute_force(ka.descriptors, kb.descriptors, ex.spec.th_low, 0.7)
    assert len(ia) > 30
    assert set(zip(ia.tolist(), ib.tolist())) == set(zip(qi.tolist(), ti.tolist()))
    empty_bow, empty_fv = voc.transform(ka.descriptors[:0])
    assert len(empty_bow) == 0 and empty_fv == {}


def test_no_vocabulary_for_float_descriptors_is_one_config_error() -> None:
    spec = SiftExtractor().spec
    with pytest.raises(ConfigError, match="slam.vocabulary"):
        vocabulary_for(spec, "some_orb_vocab.npz")
    cfg = load_config("orb", ["features.extractor=sift"])
    from semslam.api import System
    from semslam.synth import SEQUENCES

    with pytest.raises(ConfigError, match="slam.loop_closing=false"):
        System(cfg, _camera(SEQUENCES["static_xyz"]), image_size=(640, 480))  # sized: built at once
    cfg = load_config("f2kf", ["features.extractor=sift"])
    from semslam.slam.trackers.frame_to_keyframe import FrameToKeyframeTracker

    with pytest.raises(ConfigError, match="frame_to_keyframe"):
        FrameToKeyframeTracker(cfg, _camera(SEQUENCES["static_xyz"]))


def _camera(synth: SynthConfig):  # type: ignore[no-untyped-def]
    from semslam.geometry.camera import PinholeCamera

    return PinholeCamera(*synth.intrinsics())


@pytest.mark.slow
def test_orb_slam_tracker_with_sift_through_the_cli(tmp_path: Path) -> None:
    synth = SynthConfig(motion="rpy", frames=90, people=0, seed=7)
    seq = render_sequence(synth, tmp_path / "static_rpy")
    out = tmp_path / "run"
    assert main(["run", str(seq), "--out", str(out), "--preset", "orb",
                 "--set", "features.extractor=sift", "--set", "slam.loop_closing=false",
                 "--sequential", "--quiet", "--no-report", "--save-map", str(out / "map.npz")]) == 0
    stats = json.loads((out / "stats.json").read_text())
    assert stats["tracked_frames"] == stats["frames"] == 90
    # Local mapping (local BA, fusion, culling) ran on float descriptors.
    assert stats["keyframes"] >= 3 and stats["local_ba"] >= 2
    result = ate(read_tum(seq / "groundtruth.txt"), read_tum(out / "trajectory.txt"))
    assert result.n_associated == 90
    assert result.rmse < 0.02
    # The saved map keeps its float descriptors and only loads with the same features.
    spec = SiftExtractor().spec
    loaded = load_map(out / "map.npz", spec)
    point = next(iter(loaded.points.values()))
    assert point.descriptor.dtype == np.float32 and point.descriptor.shape == (128,)
    with pytest.raises(ConfigError, match="--load-map"):
        load_map(out / "map.npz", create_extractor(FeatureConfig(extractor="orb_slam2")).spec)
