"""STDC-Seg (STDC1 backbone, "STDCNet813"): the segmentation network of STDC-SLAM.

STDC-SLAM (Hu et al., IEEE Access 2022, Figs. 2-3) uses STDC-Seg unchanged and describes
it only at block level; the details below follow the original paper and code (Fan et
al., "Rethinking BiSeNet For Real-time Semantic Segmentation", CVPR 2021, and
MichaelFan01/STDC-Seg ``nets/stdcnet.py``, ``models/model_stages.py``,
``loss/detail_loss.py``):

* backbone: stage 1-2 are single stride-2 ConvX (Conv-BN-ReLU) layers (32, 64 ch), stages
  3-5 two STDC modules each (256, 512, 1024 ch), the first with stride 2. An STDC module
  is 4 ConvX blocks (1x1 then three 3x3) whose widths halve (N/2, N/4, N/8, N/8) and whose
  outputs are concatenated (N channels). With stride 2 the second block is preceded by a
  3x3 depthwise stride-2 conv + BN, and the first block's output is skipped through a
  3x3 stride-2 average pool (Fig. 3c).
* context path: ARMs (3x3 ConvBNReLU, global pool, 1x1 conv, BN, sigmoid, multiply) on the
  1/16 and 1/32 features, a global-average "tail" added at 1/32, nearest upsampling and
  3x3 ConvBNReLU heads; FFM fuses the 1/8 spatial feature (stage 3) with the context
  feature (concat, 1x1 ConvBNReLU, channel attention, residual).
* heads: main head (3x3 ConvBNReLU + 1x1) on the FFM output, two auxiliary heads on the
  context features (training only) and the detail head on stage 3 (training only:
  the paper's "Detail Head inserted in Stage 3" = ``use_boundary_8``).
* detail ground truth: Laplacian conv of the label map at strides 1, 2, 4, thresholded,
  upsampled, fused by a fixed 1x1 conv (0.6, 0.3, 0.1) and thresholded again; loss =
  BCE + dice on the detail logits.

Differences from the original code (all documented): plain ``nn.BatchNorm2d`` instead of
InPlace-ABN; the backbone's ImageNet classifier (conv_last/fc/linear, unused for
segmentation) and the unused detail heads at 1/2, 1/4, 1/16 are not built; ignore
pixels (255) are set to background before the Laplacian so the ignore band creates no
fake detail; ``width`` scales every channel count (1.0 = STDC1-Seg as published).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

IGNORE_INDEX = 255


def scaled(channels: int, width: float, divisor: int = 8) -> int:
    """``channels * width`` rounded to a multiple of ``divisor`` (at least ``divisor``).

    STDC modules split N into N/2, N/4, N/8, N/8, so stage widths must stay multiples of 8.
    """
    return max(divisor, int(round(channels * width / divisor)) * divisor)


class ConvX(nn.Sequential):
    """Conv-BN-ReLU (the paper's ConvX; ``ConvBNReLU`` in the heads)."""

    def __init__(self, cin: int, cout: int, kernel: int = 3, stride: int = 1) -> None:
        super().__init__(
            nn.Conv2d(cin, cout, kernel, stride, kernel // 2, bias=False),
            nn.BatchNorm2d(cout),
            nn.ReLU(inplace=True),
        )


class STDCModule(nn.Module):
    """Short-Term Dense Concatenate module with 4 blocks (``CatBottleneck`` in the code)."""

    def __init__(self, cin: int, cout: int, stride: int = 1, blocks: int = 4) -> None:
        super().__init__()
        if blocks != 4:
            raise ValueError("only the 4-block STDC module (STDC1/STDC2) is implemented")
        if cout % 8:
            raise ValueError(f"STDC module width must be a multiple of 8, got {cout}")
        self.stride = stride
        self.convs = nn.ModuleList([
            ConvX(cin, cout // 2, 1),
            ConvX(cout // 2, cout // 4, 3),
            ConvX(cout // 4, cout // 8, 3),
            ConvX(cout // 8, cout // 8, 3),
        ])
        if stride == 2:
            half = cout // 2
            self.avd = nn.Sequential(
                nn.Conv2d(half, half, 3, 2, 1, groups=half, bias=False), nn.BatchNorm2d(half)
            )
            self.skip = nn.AvgPool2d(3, 2, 1)

    def forward(self, x: Tensor) -> Tensor:
        out1 = self.convs[0](x)
        y = self.avd(out1) if self.stride == 2 else out1
        outs = [self.skip(out1) if self.stride == 2 else out1]
        for conv in self.convs[1:]:
            y = conv(y)
            outs.append(y)
        return torch.cat(outs, dim=1)


class STDC1Backbone(nn.Module):
    """STDC1 (STDCNet813): returns the features at strides 2, 4, 8, 16, 32."""

    def __init__(self, width: float = 1.0) -> None:
        super().__init__()
        b = scaled(64, width)
        self.channels = (b // 2, b, 4 * b, 8 * b, 16 * b)
        self.stage1 = ConvX(3, b // 2, 3, 2)
        self.stage2 = ConvX(b // 2, b, 3, 2)
        self.stage3 = nn.Sequential(STDCModule(b, 4 * b, 2), STDCModule(4 * b, 4 * b, 1))
        self.stage4 = nn.Sequential(STDCModule(4 * b, 8 * b, 2), STDCModule(8 * b, 8 * b, 1))
        self.stage5 = nn.Sequential(STDCModule(8 * b, 16 * b, 2), STDCModule(16 * b, 16 * b, 1))

    def forward(self, x: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
        f2 = self.stage1(x)
        f4 = self.stage2(f2)
        f8 = self.stage3(f4)
        f16 = self.stage4(f8)
        f32 = self.stage5(f16)
        return f2, f4, f8, f16, f32


class AttentionRefinementModule(nn.Module):
    """ARM: channel attention from global context re-weights a 3x3 ConvBNReLU output."""

    def __init__(self, cin: int, cout: int) -> None:
        super().__init__()
        self.conv = ConvX(cin, cout, 3)
        self.atten = nn.Sequential(nn.Conv2d(cout, cout, 1, bias=False), nn.BatchNorm2d(cout), nn.Sigmoid())

    def forward(self, x: Tensor) -> Tensor:
        feat = self.conv(x)
        return feat * self.atten(F.adaptive_avg_pool2d(feat, 1))


class FeatureFusionModule(nn.Module):
    """FFM: fuse spatial (stage 3) and context features with SE-style attention + residual."""

    def __init__(self, cin: int, cout: int) -> None:
        super().__init__()
        self.convblk = ConvX(cin, cout, 1)
        self.atten = nn.Sequential(
            nn.Conv2d(cout, cout // 4, 1, bias=False),
            nn.ReLU(inplace=True),
            nn.Conv2d(cout // 4, cout, 1, bias=False),
            nn.Sigmoid(),
        )

    def forward(self, fsp: Tensor, fcp: Tensor) -> Tensor:
        feat = self.convblk(torch.cat([fsp, fcp], dim=1))
        return feat + feat * self.atten(F.adaptive_avg_pool2d(feat, 1))


class SegHead(nn.Sequential):
    """``BiSeNetOutput``: 3x3 ConvBNReLU then a 1x1 classifier (no bias)."""

    def __init__(self, cin: int, mid: int, n_out: int) -> None:
        super().__init__(ConvX(cin, mid, 3), nn.Conv2d(mid, n_out, 1, bias=False))


class STDCSeg(nn.Module):
    """STDC1-Seg. ``forward(x)`` gives logits at input size; ``aux=True`` adds training outputs.

    Any input size runs (features are resized to the finer stage's size, as in the
    original); multiples of 8 keep the 1/8 head aligned with the image.
    """

    arch = "stdc1"

    def __init__(self, n_classes: int = 2, width: float = 1.0) -> None:
        super().__init__()
        self.n_classes, self.width = n_classes, width
        self.backbone = STDC1Backbone(width)
        _, _, c8, c16, c32 = self.backbone.channels
        h = scaled(128, width)  # context-path width (128 in STDC1-Seg)
        f = scaled(256, width)  # FFM / main head width (256)
        m = scaled(64, width)  # auxiliary / detail head width (64)
        self.arm16 = AttentionRefinementModule(c16, h)
        self.arm32 = AttentionRefinementModule(c32, h)
        self.conv_avg = ConvX(c32, h, 1)
        self.conv_head32 = ConvX(h, h, 3)
        self.conv_head16 = ConvX(h, h, 3)
        self.ffm = FeatureFusionModule(c8 + h, f)
        self.conv_out = SegHead(f, f, n_classes)
        self.conv_out16 = SegHead(h, m, n_classes)  # auxiliary (training only)
        self.conv_out32 = SegHead(h, m, n_classes)  # auxiliary (training only)
        self.detail_head = SegHead(c8, m, 1)  # detail guidance on stage 3 (training only)
        for mod in self.modules():
            if isinstance(mod, nn.Conv2d):
                nn.init.kaiming_normal_(mod.weight, a=1)  # as the original init_weight()

    def forward(self, x: Tensor, aux: bool = False) -> Tensor | dict[str, Tensor]:
        size = x.shape[2:]
        _, _, f8, f16, f32 = self.backbone(x)
        avg = self.conv_avg(F.adaptive_avg_pool2d(f32, 1))
        f32_sum = self.arm32(f32) + avg  # broadcast = nearest upsampling of the 1x1 tail
        cp16 = self.conv_head32(F.interpolate(f32_sum, f16.shape[2:], mode="nearest"))
        f16_sum = self.arm16(f16) + cp16
        cp8 = self.conv_head16(F.interpolate(f16_sum, f8.shape[2:], mode="nearest"))
        out = self.conv_out(self.ffm(f8, cp8))
        out = F.interpolate(out, size, mode="bilinear", align_corners=True)
        if not aux:
            return out
        up = lambda t: F.interpolate(t, size, mode="bilinear", align_corners=True)  # noqa: E731
        return {
            "out": out,
            "out16": up(self.conv_out16(cp8)),
            "out32": up(self.conv_out32(cp16)),
            "detail": self.detail_head(f8),  # 1/8 resolution, upsampled in the loss
        }

    def inference_parameters(self) -> int:
        """Parameters used at inference (without the auxiliary and detail heads)."""
        skip = ("conv_out16.", "conv_out32.", "detail_head.")
        return sum(p.numel() for n, p in self.named_parameters() if not n.startswith(skip))


# --- detail guidance (training only) -------------------------------------------------

_LAPLACIAN = torch.tensor([[-1.0, -1.0, -1.0], [-1.0, 8.0, -1.0], [-1.0, -1.0, -1.0]]).view(1, 1, 3, 3)
_FUSE = torch.tensor([0.6, 0.3, 0.1]).view(1, 3, 1, 1)


def detail_ground_truth(labels: Tensor, threshold: float = 0.1) -> Tensor:
    """Binary detail map (N, 1, H, W) of a label map (N, H, W), as STDC's DetailAggregateLoss.

    Laplacian of the (train-id) label map at strides 1, 2, 4 (padding 1), clamped at 0,
    thresholded, nearest-upsampled, fused 0.6/0.3/0.1 by a 1x1 conv and thresholded. The
    original keeps the fuse kernel as a Parameter, but it sits between two thresholds so
    it never receives a gradient: a constant here. Ignore pixels count as background.
    """
    lab = labels.clone()
    lab[lab == IGNORE_INDEX] = 0
    lab = lab.unsqueeze(1).float()
    k = _LAPLACIAN.to(lab.device)
    size = lab.shape[2:]
    maps = []
    for stride in (1, 2, 4):
        b = F.conv2d(lab, k, stride=stride, padding=1).clamp(min=0)
        if stride > 1:
            b = F.interpolate(b, size, mode="nearest")
        maps.append((b > threshold).float())
    fused = F.conv2d(torch.cat(maps, dim=1), _FUSE.to(lab.device))
    return (fused > threshold).float()


def dice_loss(prob: Tensor, target: Tensor, smooth: float = 1.0) -> Tensor:
    """1 - Dice per image, averaged (STDC's ``dice_loss_func``)."""
    n = prob.shape[0]
    p, t = prob.reshape(n, -1), target.reshape(n, -1)
    inter = (p * t).sum(1)
    return (1 - (2 * inter + smooth) / (p.sum(1) + t.sum(1) + smooth)).mean()


def detail_loss(detail_logits: Tensor, labels: Tensor) -> tuple[Tensor, Tensor]:
    """(BCE, dice) of the detail head against :func:`detail_ground_truth`."""
    target = detail_ground_truth(labels)
    if detail_logits.shape[2:] != target.shape[2:]:
        detail_logits = F.interpolate(detail_logits, target.shape[2:], mode="bilinear", align_corners=True)
    bce = F.binary_cross_entropy_with_logits(detail_logits, target)
    return bce, dice_loss(torch.sigmoid(detail_logits), target)


def ohem_ce_loss(logits: Tensor, labels: Tensor, thresh: float = 0.7, min_frac: float = 1 / 16) -> Tensor:
    """Online hard example mining CE (STDC's ``OhemCELoss``).

    Keeps pixels whose loss exceeds -log(thresh), but at least ``min_frac`` of all pixels
    (the original's ``n_min = batch * H * W // 16``).
    """
    loss = F.cross_entropy(logits, labels, ignore_index=IGNORE_INDEX, reduction="none").flatten()
    n_min = max(1, int(loss.numel() * min_frac))
    hard = loss[loss > -torch.log(torch.tensor(thresh))]
    if hard.numel() < n_min:
        hard, _ = torch.topk(loss, n_min)
    return hard.mean()


def stdc_loss(outputs: dict[str, Tensor], labels: Tensor) -> tuple[Tensor, dict[str, float]]:
    """Total STDC-Seg training loss: OHEM CE on the main and two auxiliary outputs + detail BCE + dice."""
    l_out = ohem_ce_loss(outputs["out"], labels)
    l16 = ohem_ce_loss(outputs["out16"], labels)
    l32 = ohem_ce_loss(outputs["out32"], labels)
    bce, dice = detail_loss(outputs["detail"], labels)
    total = l_out + l16 + l32 + bce + dice
    parts = {"ce": float(l_out.detach()), "aux": float((l16 + l32).detach()), "bce": float(bce.detach()),
             "dice": float(dice.detach())}
    return total, parts
