"""Building networks by name and saving/loading checkpoints with their metadata.

A checkpoint is one ``torch.save`` dict: ``{"format": "semslam-net-1", "meta": {...},
"state_dict": {...}}``. ``meta`` holds everything needed to run the model (architecture,
width, class ids/names, input size, mean/std) and how it was trained (data, epochs,
metrics, time, command). Shipped checkpoints store fp16 weights and omit the
training-only heads (STDC's auxiliary and detail heads), which is why they are loaded
with ``strict=False`` for those heads only.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import torch
from torch import nn

from semslam.errors import DataError
from semslam.nets.onnx_runtime import input_multiple  # noqa: F401 - torch-free, shared with inference

FORMAT = "semslam-net-1"
ARCHS = ("stdc1", "dunet", "sdfcnn")
#: Parameter-name prefixes used only in training (dropped from shipped weights).
TRAINING_ONLY = {"stdc1": ("conv_out16.", "conv_out32.", "detail_head."), "dunet": (), "sdfcnn": ()}


def build_model(arch: str, n_classes: int, width: float, **options: Any) -> nn.Module:
    """A fresh network: ``"stdc1"`` (STDC1-Seg) or ``"dunet"`` (deformable U-Net; option
    ``modulation`` for DCNv2 blocks). ``options`` are stored in checkpoints as ``meta["options"]``."""
    if arch == "stdc1":
        from semslam.nets.stdc import STDCSeg

        return STDCSeg(n_classes, width, **options)
    if arch == "dunet":
        from semslam.nets.dunet import DUNet

        return DUNet(n_classes, width, **options)
    if arch == "sdfcnn":  # SDF-SLAM's joint depth + segmentation net; options: input_size, output_size
        from semslam.nets.sdfcnn import SDFCNN

        return SDFCNN(n_classes, width, **options)
    raise ValueError(f"unknown architecture {arch!r} (choose from {', '.join(ARCHS)})")


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())


def save_checkpoint(
    path: str | Path, model: nn.Module, meta: dict[str, Any], half: bool = True, inference_only: bool = True
) -> Path:
    """Write ``model`` and ``meta``; fp16 and without training-only heads by default (smaller files)."""
    arch = meta["arch"]
    skip = TRAINING_ONLY.get(arch, ()) if inference_only else ()
    state = {}
    for k, v in model.state_dict().items():
        if skip and k.startswith(skip):
            continue
        state[k] = v.half() if half and v.is_floating_point() else v
    meta = dict(meta, weights_dtype="float16" if half else "float32", inference_only=bool(inference_only))
    # Plain JSON types only, so the file loads with torch.load(weights_only=True).
    meta = json.loads(json.dumps(meta, default=str))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save({"format": FORMAT, "meta": meta, "state_dict": state}, path)
    return path


def load_checkpoint(path: str | Path, map_location: str = "cpu") -> tuple[nn.Module, dict[str, Any]]:
    """(model in eval mode, float32, metadata) from a checkpoint written by :func:`save_checkpoint`."""
    path = Path(path)
    if not path.is_file():
        raise DataError(path, "network weights not found")
    try:
        ckpt = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as exc:  # noqa: BLE001 - torch raises many types for bad files
        raise DataError(path, f"cannot read network weights: {exc}") from exc
    if not isinstance(ckpt, dict) or ckpt.get("format") != FORMAT:
        raise DataError(path, f"not a semslam network checkpoint (format {FORMAT})")
    meta = ckpt["meta"]
    model = build_model(meta["arch"], len(meta["class_ids"]), float(meta["width"]), **meta.get("options", {}))
    state = {k: v.float() if v.is_floating_point() else v for k, v in ckpt["state_dict"].items()}
    missing, unexpected = model.load_state_dict(state, strict=False)
    allowed = TRAINING_ONLY.get(meta["arch"], ())
    bad = [k for k in missing if not k.startswith(allowed)] if allowed else list(missing)
    if bad or unexpected:
        raise DataError(path, f"weights do not match the architecture (missing {bad[:3]}, unexpected {unexpected[:3]})")
    model.eval()
    return model, meta
