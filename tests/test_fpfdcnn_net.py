"""FPFDCNN against SDF-SLAM's Table 12: output shapes at 640x480 and the parameter count
computed from the table by hand; the descriptor sampling equals Table 12's bilinear
upsampling; the N x 258 output."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from semslam.nets.fpfdcnn import FPFDCNN, count_parameters, load_fpfdcnn, sample_descriptors, save_fpfdcnn, select_points
from semslam.errors import DataError

# Table 12, weight (k x k x in x out) + bias (out) per layer:
TABLE_12 = {
    "layer 1": 4 * 4 * 1 * 32 + 32,  # 544
    "layer 2": 4 * 4 * 32 * 64 + 64,  # 32,832
    "layer 3": 3 * 3 * 64 * 128 + 128,  # 73,856
    "layer 4": 4 * 4 * 128 * 128 + 128,  # 262,272
    "layer 5": 3 * 3 * 128 * 256 + 256,  # 295,168
    "layer 6": 4 * 4 * 256 * 256 + 256,  # 1,048,832
    "layer 7": 3 * 3 * 256 * 256 + 256,  # 590,080
    "layer 8": 1 * 1 * 256 * 256 + 256,  # 65,792
    "layer 9": 3 * 3 * 256 * 256 + 256,  # 590,080
    "layer 10": 1 * 1 * 256 * 256 + 256,  # 65,792
}


def test_parameter_count_is_table_12s():
    assert sum(TABLE_12.values()) == 3_025_248
    model = FPFDCNN(1.0)
    assert count_parameters(model) == 3_025_248
    order = [*model.encoder, *model.keypoint_head, *model.descriptor_head]
    convs = [m for m in order if isinstance(m, torch.nn.Conv2d)]
    assert [sum(p.numel() for p in c.parameters()) for c in convs] == list(TABLE_12.values())


def test_output_shapes_at_640x480():
    model = FPFDCNN(1.0).eval()
    x = torch.rand(1, 1, 480, 640)
    with torch.no_grad():
        feats = []
        h = x
        for layer in model.encoder:
            h = layer(h)
            if isinstance(layer, torch.nn.ELU):
                feats.append(tuple(h.shape[1:]))
        prob, coarse = model(x)
    # Table 12's feature maps (channels, rows, columns) of layers 1-6.
    assert feats == [(32, 240, 320), (64, 120, 160), (128, 120, 160), (128, 60, 80), (256, 60, 80), (256, 30, 40)]
    assert prob.shape == (1, 1, 480, 640) and coarse.shape == (1, 256, 30, 40)  # FP, FD before upsampling
    assert float(prob.min()) > 0 and float(prob.max()) < 1  # sigmoid


def test_descriptor_sampling_equals_bilinear_upsampling():
    torch.manual_seed(0)
    coarse = torch.randn(1, 256, 6, 8)
    full = F.interpolate(coarse, scale_factor=16, mode="bilinear", align_corners=False)  # Table 12's FD
    xy = torch.tensor([[0, 0], [127, 95], [5, 90], [64, 33], [100, 7]], dtype=torch.float32)
    ref = F.normalize(full[0, :, xy[:, 1].long(), xy[:, 0].long()].T, dim=-1)
    torch.testing.assert_close(sample_descriptors(coarse, xy[None])[0], ref, rtol=1e-5, atol=1e-5)


def test_extract_gives_n_by_258_and_honours_the_mask(tmp_path):
    model = FPFDCNN(0.25).half().float().eval()  # weights exactly representable in float16 (as saved)
    gray = (np.random.default_rng(0).random((96, 128)) * 255).astype(np.uint8)
    out = model.extract(gray, n_points=50, threshold=0.0)
    assert out.shape == (50, 258)
    np.testing.assert_allclose(np.linalg.norm(out[:, 2:], axis=1), 1.0, rtol=1e-5)
    mask = np.zeros_like(gray)
    mask[:, :64] = 255
    assert (model.extract(gray, n_points=50, threshold=0.0, mask=mask)[:, 0] < 64).all()
    path = save_fpfdcnn(tmp_path / "w.pt", model, {"command": "test"})
    loaded, meta = load_fpfdcnn(path)
    assert meta["width"] == 0.25 and meta["parameters"] == count_parameters(model)
    np.testing.assert_allclose(loaded.extract(gray, 50, 0.0), out)  # float16 weights round-trip exactly
    with pytest.raises(DataError, match="FPFDCNN weights not found"):
        load_fpfdcnn(tmp_path / "missing.pt")


def test_select_points_keeps_local_maxima_strongest_first():
    prob = np.zeros((40, 40), np.float32)
    prob[10, 10], prob[11, 11], prob[30, 5], prob[20, 30] = 0.9, 0.8, 0.5, 0.7
    xy, p = select_points(prob, 10, 0.1, 4)
    assert xy.tolist() == [[10, 10], [30, 20], [5, 30]] and p.tolist() == pytest.approx([0.9, 0.7, 0.5])
