"""SDFCNN's data, training and runtime: NYU-40 mapping of synthetic labels, a tiny training run
lowers eq. 21's loss, ``semslam train sdfcnn`` / ``eval-sdfcnn`` write what they promise, and
the ``sdfcnn`` depth source and segmenter answer at the frame's size from ONE inference."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from semslam.cli.main import main
from semslam.config import DepthConfig, SemanticsConfig, load_config
from semslam.core import protocols, registry
from semslam.core.labels import NYU40_CLASSES
from semslam.errors import DataError
from semslam.io.sequence import TumRgbdSequence
from semslam.nets.models import build_model, load_checkpoint, save_checkpoint
from semslam.nets.sdf_dataset import SdfDataset, load_folder, nyu40_lut, synth_lut
from semslam.nets.sdfcnn import sdfcnn_loss
from semslam.semantics import sdfcnn_backend
from semslam.semantics.sdfcnn_backend import SdfcnnPredictor, shared_predictor
from semslam.synth import SEQUENCES, render_sequence


pytestmark = pytest.mark.usefixtures("torch_one_thread")


@pytest.fixture(scope="module")
def seq(tmp_path_factory: pytest.TempPathFactory) -> Path:
    cfg = SEQUENCES["walking_xyz"].replace(frames=6, width=160, height=120, seed=901, fps=3.0)
    return render_sequence(cfg, tmp_path_factory.mktemp("sdf") / "walk", progress=False, workers=1)


@pytest.fixture(scope="module")
def weights(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Random-init weights in the shipped format (small width, 96x64 Layer 0)."""
    torch.manual_seed(0)
    options = {"input_size": [96, 72], "output_size": [640, 480]}
    model = build_model("sdfcnn", 40, 0.25, **options)
    meta = {"arch": "sdfcnn", "width": 0.25, "options": options, "class_ids": sorted(NYU40_CLASSES),
            "class_names": [NYU40_CLASSES[i] for i in sorted(NYU40_CLASSES)]}
    return save_checkpoint(tmp_path_factory.mktemp("w") / "sdf.pt", model, meta)


def test_label_mapping() -> None:
    lut = synth_lut()
    assert (lut[101], lut[122], lut[140]) == (0, 21, 39)  # wall, ceiling, otherprop
    assert NYU40_CLASSES[lut[15] + 1] == "person"  # synthetic people are NYU's person
    assert lut[21] == 255 and lut[0] == 255 and lut[99] == 255  # mover, nothing, unknown: ignored
    assert nyu40_lut()[0] == 255 and nyu40_lut()[40] == 39


def test_dataset_reads_depth_in_metres_and_nyu_labels(seq: Path) -> None:
    samples = load_folder(seq, (96, 72))
    assert len(samples) == 6
    s = samples[0]
    assert s.rgb.shape == (72, 96, 3) and s.label.shape == (72, 96) and s.depth.dtype == np.float32
    frame = TumRgbdSequence(seq).load(0)
    assert 0.3 < float(np.median(s.depth[s.depth > 0])) < 6.0
    assert abs(float(np.median(s.depth[s.depth > 0])) - float(np.median(frame.depth[frame.depth > 0]))) < 0.3
    labelled = s.label[s.label != 255]
    assert labelled.size > 0.9 * s.label.size and labelled.max() < 40
    x, y, d = SdfDataset(samples, augment=True)[0]
    assert x.shape == (3, 72, 96) and y.shape == (72, 96) and d.shape == (72, 96)


def test_tiny_training_lowers_the_loss(seq: Path) -> None:
    torch.manual_seed(0)
    ds = SdfDataset(load_folder(seq, (64, 48), limit=2))
    x, y, d = (torch.stack(t) for t in zip(*(ds[i] for i in range(2))))
    model = build_model("sdfcnn", 40, 0.25, input_size=None, output_size=None)
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    losses = []
    for _ in range(10):
        loss, _ = sdfcnn_loss(model(x), y, d)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
    assert losses[-1] < 0.7 * losses[0]


def test_train_and_eval_commands(seq: Path, tmp_path: Path) -> None:
    out = tmp_path / "sdf.pt"
    rc = main(["train", "sdfcnn", "--data", str(seq), "--out", str(out), "--epochs", "1", "--batch", "2",
               "--size", "96x64", "--width", "0.25", "--threads", "1", "-q"])
    assert rc == 0
    model, meta = load_checkpoint(out)
    assert meta["arch"] == "sdfcnn" and meta["weights_dtype"] == "float16" and meta["lambda"] == 0.4
    assert meta["command"].startswith("semslam train sdfcnn --out") and "--size 96x64" in meta["command"]
    assert 0 <= meta["val"]["delta1"] <= 1
    report = tmp_path / "eval.json"
    assert main(["eval-sdfcnn", str(seq), "--weights", str(out), "--limit", "3", "--json", str(report)]) == 0
    res = json.loads(report.read_text())
    row = res["all"]
    assert row["frames"] == 3 and res["parameters"] == sum(p.numel() for p in model.parameters())
    assert 0 <= row["mpa"] <= 1 and 0 <= row["miou"] <= 1 and row["rms"] > 0 and row["ms_per_frame_median"] > 0
    assert row["delta1"] <= row["delta2"] <= row["delta3"] <= 1


def test_depth_and_segmenter_share_one_inference(seq: Path, weights: Path,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(sdfcnn_backend, "DEFAULT_WEIGHTS", weights)
    depth_source = registry.create("depth_source", "sdfcnn", DepthConfig(source="sdfcnn"))
    segmenter = registry.create("segmenter", "sdfcnn", SemanticsConfig(backend="sdfcnn"))
    assert isinstance(depth_source, protocols.DepthSource) and isinstance(segmenter, protocols.Segmenter)
    assert depth_source.predictor is segmenter.predictor is shared_predictor(weights)
    frame = TumRgbdSequence(seq).load(2)
    runs = segmenter.predictor.inferences
    depth = depth_source.depth(frame)
    labels = segmenter.segment(frame.rgb, frame)
    again = segmenter.segment(frame.rgb.copy())  # a keyframe snapshot's copy: same content
    assert segmenter.predictor.inferences == runs + 1
    assert depth.shape == frame.shape and depth.dtype == np.float32 and (depth >= 0).all()
    assert labels.labels.shape == frame.shape and labels.labels.dtype == np.uint8
    assert set(np.unique(labels.labels)) <= set(NYU40_CLASSES) and labels.names == NYU40_CLASSES
    assert again.labels is labels.labels
    other = TumRgbdSequence(seq).load(3)
    depth_source.depth(other)
    assert segmenter.predictor.inferences == runs + 2


def test_depth_source_honours_weights(weights: Path, tmp_path: Path) -> None:
    """depth.weights picks the depth network; empty, it follows semantics.weights when the
    segmenter is sdfcnn too (one predictor, one forward pass), else the shipped weights."""
    def depth_predictor(overrides: list[str]) -> SdfcnnPredictor:
        cfg = load_config("sdf", overrides)
        source = registry.create("depth_source", cfg.depth.source, cfg.depth.resolved(cfg.semantics))
        return source.predictor

    assert depth_predictor([f"depth.weights={weights}"]) is shared_predictor(weights)
    assert depth_predictor([f"semantics.weights={weights}"]) is shared_predictor(weights)
    assert depth_predictor([]) is shared_predictor()  # the shipped weights
    assert shared_predictor().weights.name == "sdfcnn.onnx"
    other = load_config("sdf", [f"semantics.weights={weights}", "semantics.backend=ground_truth"])
    assert other.depth.resolved(other.semantics).weights == ""  # another segmenter's weights are not depth's
    with pytest.raises(DataError, match="weights not found"):
        depth_predictor([f"depth.weights={tmp_path / 'none.pt'}"])


def test_missing_weights_is_one_clear_error(tmp_path: Path) -> None:
    with pytest.raises(DataError, match="sdfcnn.pt.*weights not found"):
        SdfcnnPredictor(tmp_path / "sdfcnn.pt")
