"""SDFCNN (SDF-SLAM Table 13): layer shapes and parameter counts against the table, eq. 15 and
eq. 21 by hand, the exact upsampled argmax, Tables 8/9's metrics on hand-counted arrays."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from semslam.eval.dense_metrics import (
    DepthErrors,
    class_iou,
    confusion,
    depth_metrics,
    mean_iou,
    mean_pixel_accuracy,
)
from semslam.nets.sdfcnn import (
    SDFCNN,
    berhu,
    float32_mebibytes,
    normalise,
    parameter_report,
    sdfcnn_loss,
    table13_parameter_count,
    upsampled_argmax,
)


pytestmark = pytest.mark.usefixtures("torch_one_thread")


@pytest.fixture(scope="module")
def full() -> SDFCNN:
    torch.manual_seed(0)
    return SDFCNN().eval()


def test_feature_maps_follow_table13(full: SDFCNN) -> None:
    """Table 13's "Feature map" column (c x h x w) at the paper's 640x480 input."""
    seen: dict[str, tuple[int, ...]] = {}
    names = ["layer1", "layer2", "layer3", "layer4", "layer5", "layer6", "layer7"]
    mods = [full.layer1, *full.layers[:5], full.layers[5][-1]]  # Layer 7 runs in two parts
    hooks = [m.register_forward_hook(lambda _m, _i, o, n=n: seen.__setitem__(n, tuple(o.shape[1:])))
             for n, m in zip(names, mods)]
    with torch.inference_mode():
        out = full(torch.zeros(1, 3, 480, 640))
        f = full.features(torch.zeros(1, 3, 480, 640))
    for h in hooks:
        h.remove()
    assert seen == {"layer1": (32, 150, 200), "layer2": (16, 150, 200), "layer3": (24, 75, 100),
                    "layer4": (32, 38, 50), "layer5": (64, 19, 25), "layer6": (96, 19, 25),
                    "layer7": (320, 10, 13)}
    assert tuple(f.shape[1:]) == (256, 75, 100)  # Layer 11
    assert out["seg"].shape == (1, 40, 480, 640) and out["depth"].shape == (1, 1, 480, 640)


def test_output_size_and_width() -> None:
    model = SDFCNN(40, width=0.25, input_size=(160, 120), output_size=None).eval()
    with torch.inference_mode():
        out = model(torch.zeros(2, 3, 90, 120), output_size=(64, 48))
        native = model(torch.zeros(1, 3, 90, 120))
    assert out["seg"].shape == (2, 40, 48, 64) and out["depth"].shape == (2, 1, 48, 64)
    assert native["seg"].shape == (1, 40, 90, 120)
    assert model.decoder_width == 64 and model.stage_channels[-1] == 80


def test_parameter_count_against_table13(full: SDFCNN) -> None:
    """Every weight shape of Table 13; the count differs from the tables' 11.8 M (see the module
    docstring: 11.8 is the float32 size in MiB, not a count)."""
    n = sum(p.numel() for p in full.parameters())
    assert n == 2_987_113
    # Table 13 as printed has three typo'd shapes: Layer4_10 64x256 (Layer 4 has 32 channels),
    # Layer3_7 32x256 (Layer 3 has 24) and seg1's bias of 256 (40 outputs).
    typos = (64 - 32) * 256 + (32 - 24) * 256 + (256 - 40)
    assert table13_parameter_count() == n + typos
    assert abs(n - 11.8e6) > 8e6  # not the paper's number, by design
    assert abs(float32_mebibytes(full) - 11.8) < 0.5
    assert full.conv7_13.weight.shape == (256, 320, 1, 1) and full.conv7_14.weight.shape == (256, 160, 1, 1)
    assert full.seg.weight.shape == (256, 1, 1, 1) and full.seg1.weight.shape == (40, 256, 1, 1)
    assert full.depth1.weight.shape == (1, 256, 3, 3) and full.depth1.bias.shape == (1,)
    assert len(full.refine8.convs) == 4 and full.layers[3][3].convs[1][0].groups == 384  # Layer5_11
    assert "11.8 M" in parameter_report(0.25)


def test_normalise_is_eq15() -> None:
    rgb = torch.tensor([255, 0, 128], dtype=torch.uint8).view(1, 3, 1, 1)
    got = normalise(rgb).flatten().tolist()
    want = [(1 - 0.485) / 0.229, (0 - 0.456) / 0.224, (128 / 255 - 0.406) / 0.225]
    assert got == pytest.approx(want, rel=1e-6)


def test_berhu_by_hand() -> None:
    # c = max|r| / 5 = 0.2: |0.1| -> 0.1; 0.5 -> (0.25 + 0.04) / 0.4; 1.0 -> (1 + 0.04) / 0.4
    assert float(berhu(torch.tensor([0.1, -0.5, 1.0]))) == pytest.approx((0.1 + 0.725 + 2.6) / 3)


def test_loss_is_eq21() -> None:
    torch.manual_seed(1)
    seg = torch.randn(1, 40, 2, 2)
    labels = torch.tensor([[[3, 255], [7, 39]]])
    depth_pred = torch.tensor([[[[1.0, 2.0], [3.0, 9.0]]]])
    depth_true = torch.tensor([[[1.1, 2.0], [2.95, 0.0]]])  # the last pixel has no depth
    total, parts = sdfcnn_loss({"seg": seg, "depth": depth_pred}, labels, depth_true)
    ce = F.cross_entropy(seg, labels, ignore_index=255)
    c = 0.1 / 5  # berHu's c = max|residual| / 5
    r = np.array([-0.1, 0.0, 0.05])
    reg = float(np.mean(np.where(np.abs(r) <= c, np.abs(r), (r * r + c * c) / (2 * c))))
    assert float(total) == pytest.approx(0.4 * float(ce) + 0.6 * reg, rel=1e-5)
    assert parts["ce"] == pytest.approx(float(ce)) and parts["depth"] == pytest.approx(reg, rel=1e-5)


@pytest.mark.parametrize("size", [(640, 480), (320, 240), (97, 61)])
def test_upsampled_argmax_equals_interpolate_then_argmax(size: tuple[int, int]) -> None:
    torch.manual_seed(2)
    logits = F.interpolate(torch.randn(1, 40, 8, 10), size=(30, 40), mode="bilinear") * 3
    ref = F.interpolate(logits, size=size[::-1], mode="bilinear", align_corners=False)[0].argmax(0).numpy()
    got = upsampled_argmax(logits[0].numpy(), size)
    assert got.shape == ref.shape and (got == ref).all()


# ---------------------------------------------------------------- Tables 8 and 9
def test_segmentation_metrics_by_hand() -> None:
    truth = np.array([0, 0, 1, 1, 2, 255])
    pred = np.array([0, 1, 1, 1, 0, 2])
    conf = confusion(truth, pred, 3)
    assert conf.tolist() == [[1, 1, 0], [0, 2, 0], [1, 0, 0]]
    assert mean_pixel_accuracy(conf) == pytest.approx((1 / 2 + 1 + 0) / 3)
    assert class_iou(conf).tolist() == pytest.approx([1 / 3, 2 / 3, 0.0])
    assert mean_iou(conf) == pytest.approx(1 / 3)
    # a class in neither truth nor prediction does not count
    assert mean_iou(confusion(truth, pred, 4)) == pytest.approx(1 / 3)
    assert math.isnan(mean_pixel_accuracy(np.zeros((2, 2))))


def test_depth_metrics_by_hand() -> None:
    pred = np.array([1.0, 2.0, 4.0, 0.5, 0.0])
    truth = np.array([1.0, 2.5, 2.0, 0.0, 1.0])  # 4th has no truth; 5th predicted 0 (wrong)
    m = depth_metrics(pred, truth)
    assert m["pixels"] == 4
    assert m["rms"] == pytest.approx(math.sqrt((0 + 0.25 + 4 + 1) / 4))
    assert m["rel"] == pytest.approx((0 + 0.2 + 1 + 1) / 4)
    # ratios 1, 1.25, 2, inf: 1.25 is not < 1.25; 2 is not < 1.25^3 = 1.953
    assert (m["delta1"], m["delta2"], m["delta3"]) == pytest.approx((1 / 4, 2 / 4, 2 / 4))
    acc = DepthErrors()
    acc.add(pred[:2], truth[:2])
    rest = DepthErrors()
    rest.add(pred[2:], truth[2:])
    acc.merge(rest)
    assert acc.result() == pytest.approx(m)
