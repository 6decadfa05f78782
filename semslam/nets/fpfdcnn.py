"""FPFDCNN, SDF-SLAM's keypoint network (Yang et al. 2022, Fig. 3 and Table 12).

Layer by layer as Table 12 (input 640x480x1, grey):

    encoder   1: 4x4 conv  1->32,  stride 2, pad 1, ELU      240x320
              2: 4x4 conv 32->64,  stride 2, pad 1, ELU      120x160
              3: 3x3 conv 64->128, stride 1, pad 1, ELU      120x160
              4: 4x4 conv 128->128, stride 2, pad 1, ELU      60x80
              5: 3x3 conv 128->256, stride 1, pad 1, ELU      60x80
              6: 4x4 conv 256->256, stride 2, pad 1, ELU      30x40
    keypoints 7: 3x3 conv 256->256, ELU; 8: 1x1 conv 256->256, sigmoid; pixel shuffle
                 (256 = 16 x 16 channels -> one 480x640 probability map, "FP")
    descript. 9: 3x3 conv 256->256, ELU; 10: 1x1 conv 256->256; bilinear upsampling x16
                 ("FD", 256-d per pixel), L2-normalised as SuperPoint's descriptors
    output    the N points of FP that are kept (Table 12's "FP_nonzero": with a sigmoid no
              probability is exactly 0, so points are kept by threshold, non-maximum
              suppression and the top N, as the paper's experiments keep 500) with their
              descriptors: N x 258 = (x, y, 256-d descriptor).

The 640x480x256 "FD" map is never materialised (300 MB): bilinear upsampling followed by
reading pixel (x, y) equals bilinear sampling of the 30x40 map at (x, y)
(``sample_descriptors``; the test checks the equality against ``F.interpolate``).

``width`` scales the hidden channels (32..256) for a cheaper network; the keypoint head's
256 = 16^2 shuffle channels and the 256-d descriptor stay as in the table. ``width=1`` is
Table 12 exactly (3,025,248 parameters).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from numpy.typing import NDArray
from torch import nn

from semslam.errors import DataError
from semslam.nets.outputs import CELL, NMS_RADIUS, nms_points, select_points  # torch-free, shared with inference

__all__ = ["CELL", "DESC_DIM", "FORMAT", "FPFDCNN", "load_fpfdcnn", "nms_points", "sample_descriptors",
           "save_fpfdcnn", "select_points"]

DESC_DIM = 256
FORMAT = "semslam-fpfdcnn-1"

#: Table 12's encoder: (kernel, in, out, stride, padding) of layers 1-6 at width 1.
ENCODER = ((4, 1, 32, 2, 1), (4, 32, 64, 2, 1), (3, 64, 128, 1, 1),
           (4, 128, 128, 2, 1), (3, 128, 256, 1, 1), (4, 256, 256, 2, 1))
HEAD = 256  # layers 7 and 9 (3x3) at width 1


def _scaled(channels: int, width: float) -> int:
    return max(8, int(round(channels * width)))


class FPFDCNN(nn.Module):
    """Table 12's network. ``forward(gray)`` takes (B, 1, H, W) in [0, 1] (H, W multiples
    of 16) and returns the keypoint probability map (B, 1, H, W) and the coarse
    descriptor map (B, 256, H/16, W/16), not yet normalised (see ``sample_descriptors``)."""

    def __init__(self, width: float = 1.0) -> None:
        super().__init__()
        self.width = float(width)
        layers: list[nn.Module] = []
        for k, c_in, c_out, stride, pad in ENCODER:
            c_in = 1 if c_in == 1 else _scaled(c_in, width)
            layers += [nn.Conv2d(c_in, _scaled(c_out, width), k, stride, pad), nn.ELU()]
        self.encoder = nn.Sequential(*layers)
        c6, head = _scaled(ENCODER[-1][2], width), _scaled(HEAD, width)
        self.keypoint_head = nn.Sequential(nn.Conv2d(c6, head, 3, 1, 1), nn.ELU(),  # layer 7
                                           nn.Conv2d(head, CELL * CELL, 1))  # layer 8 (logits)
        self.descriptor_head = nn.Sequential(nn.Conv2d(c6, head, 3, 1, 1), nn.ELU(),  # layer 9
                                             nn.Conv2d(head, DESC_DIM, 1))  # layer 10
        self.shuffle = nn.PixelShuffle(CELL)

    def logits(self, gray: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Keypoint logits at full resolution (B, 1, H, W) and coarse descriptors: the
        training losses use the logits (numerically stable BCE)."""
        if gray.shape[-1] % CELL or gray.shape[-2] % CELL:
            raise ValueError(f"FPFDCNN input sides must be multiples of {CELL}, got {tuple(gray.shape[-2:])}")
        feat = self.encoder(gray)
        return self.shuffle(self.keypoint_head(feat)), self.descriptor_head(feat)

    def forward(self, gray: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        logit, desc = self.logits(gray)
        return torch.sigmoid(logit), desc

    @torch.inference_mode()
    def extract(self, gray: NDArray[np.uint8], n_points: int = 500, threshold: float = 0.015,
                nms_radius: int = NMS_RADIUS, mask: NDArray[np.uint8] | None = None) -> NDArray[np.float32]:
        """Table 12's output for one grey image: (N, 258) rows (x, y, descriptor) of the
        ``n_points`` most probable points after NMS; ``mask`` (0 = forbidden) as OpenCV's."""
        prob, coarse = self.forward(to_tensor(gray))
        xy, _ = select_points(prob[0, 0].numpy(), n_points, threshold, nms_radius, mask)
        desc = sample_descriptors(coarse, torch.from_numpy(xy)[None])[0].numpy()
        return np.concatenate([xy, desc], axis=1).astype(np.float32)


def to_tensor(gray: NDArray[np.uint8]) -> torch.Tensor:
    """(1, 1, H, W) float tensor in [0, 1] of a uint8 grey image."""
    return torch.from_numpy(np.ascontiguousarray(gray, np.float32) / 255.0)[None, None]


def sample_descriptors(coarse: torch.Tensor, xy: torch.Tensor) -> torch.Tensor:
    """L2-normalised descriptors (B, N, 256) at pixel positions ``xy`` (B, N, 2) of the
    full-resolution image: bilinear sampling of the coarse map, identical to Table 12's
    bilinear upsampling by 16 (``F.interpolate``, ``align_corners=False``) read at the pixel."""
    h, w = coarse.shape[-2] * CELL, coarse.shape[-1] * CELL
    # Pixel centre x of the upsampled map sits at coarse coordinate (x + 0.5) / 16 - 0.5;
    # grid_sample with align_corners=False maps [-1, 1] to the outer edges of the map.
    grid = torch.stack([(xy[..., 0] + 0.5) / w * 2 - 1, (xy[..., 1] + 0.5) / h * 2 - 1], dim=-1)
    desc = F.grid_sample(coarse, grid[:, :, None, :].to(coarse.dtype), mode="bilinear",
                         padding_mode="border", align_corners=False)
    return F.normalize(desc[..., 0].transpose(1, 2), dim=-1)


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())


def save_fpfdcnn(path: str | Path, model: FPFDCNN, meta: dict[str, Any], half: bool = True) -> Path:
    """One ``torch.save`` dict ``{"format", "meta", "state_dict"}``, float16 weights by
    default; ``meta`` (plain JSON types) says how the weights were made."""
    import json

    state = {k: (v.half() if half and v.is_floating_point() else v) for k, v in model.state_dict().items()}
    meta = json.loads(json.dumps(dict(meta, arch="fpfdcnn", width=model.width,
                                      parameters=count_parameters(model),
                                      weights_dtype="float16" if half else "float32"), default=str))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save({"format": FORMAT, "meta": meta, "state_dict": state}, path)
    return path


def load_fpfdcnn(path: str | Path) -> tuple[FPFDCNN, dict[str, Any]]:
    """(model in eval mode, float32, metadata); DataError naming the file if it is missing
    or not an FPFDCNN checkpoint."""
    path = Path(path)
    if not path.is_file():
        raise DataError(path, "FPFDCNN weights not found (train them with `semslam train fpfdcnn`)")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - torch raises many types for bad files
        raise DataError(path, f"cannot read FPFDCNN weights: {exc}") from exc
    if not isinstance(ckpt, dict) or ckpt.get("format") != FORMAT:
        raise DataError(path, f"not an FPFDCNN checkpoint (format {FORMAT})")
    meta = ckpt["meta"]
    model = FPFDCNN(float(meta.get("width", 1.0)))
    try:
        model.load_state_dict({k: v.float() for k, v in ckpt["state_dict"].items()})
    except RuntimeError as exc:
        raise DataError(path, f"weights do not fit FPFDCNN width {meta.get('width')}: {exc}") from exc
    return model.eval(), meta
