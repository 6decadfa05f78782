"""DUNet: deformable U-Net (Jin et al., "DUNet: A deformable network for retinal vessel
segmentation", Knowledge-Based Systems 2019, arXiv:1811.01206), the network of DDL-SLAM.

DDL-SLAM (Ai et al., IEEE Access 2020) cites Jin et al. for DUNet but says it used the
PyTorch code of Tramac/awesome-semantic-segmentation-pytorch, whose ``dunet`` is a
different network ("Decoders Matter", DUpsampling on a ResNet). We follow the cited
paper, with the layout of its authors' PyTorch code (RanSuLab/DUNet-retinal-vessel-
detection, ``models/deform_unet.py``, class ``DUNetV1V2``):

    inc   = double conv            (3   -> c1)        full resolution
    down1 = maxpool + double DEFORM (c1 -> c2)        1/2
    down2 = maxpool + double DEFORM (c2 -> c3)        1/4
    down3 = maxpool + double conv   (c3 -> c4)        1/8
    down4 = maxpool + double conv   (c4 -> c4)        1/16
    up1   = bilinear x2, concat skip, double conv   (2*c4 -> c3)
    up2   = ...                     double conv   (2*c3 -> c2)
    up3   = ...                     double DEFORM (2*c2 -> c1)
    up4   = ...                     double DEFORM (2*c1 -> c1)
    outc  = 1x1 conv on concat(input image, up4)   (c1 + 3 -> classes)

so the deformable blocks sit in the two high-resolution levels of both the encoder and
the decoder, where object shape matters. (c1..c4) = (64, 128, 256, 512) * width; the
official code's default ``downsize_nb_filters_factor=4`` is width 0.25. A "double conv"
is (3x3 conv, BN, ReLU) x 2; a "double deform" uses deformable convs instead.

The deformable convs are DCNv1 by default (offsets only), as in Jin et al. and their code
(the modulated variant is commented out there); ``modulation=True`` gives DCNv2 (about
25 % slower on CPU, measured). Choices where the code is not followed: convs before BN
have no bias (BN makes it redundant), the deformable convs pad by 1 (the code's
``padding=0`` layer pads internally), and the output is multi-class logits for
softmax/CE instead of one sigmoid channel.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from semslam.nets.deform_conv import DeformConv2d


def _channels(width: float) -> tuple[int, int, int, int]:
    """(c1, c2, c3, c4) = (64, 128, 256, 512) * width, multiples of 4, at least 4."""
    return tuple(max(4, int(round(c * width / 4)) * 4) for c in (64, 128, 256, 512))  # type: ignore[return-value]


def double_conv(cin: int, cout: int, deformable: bool, modulation: bool = False) -> nn.Sequential:
    """(conv 3x3 -> BN -> ReLU) x 2, with deformable convs if asked."""

    def conv(i: int, o: int) -> nn.Module:
        if deformable:
            return DeformConv2d(i, o, 3, 1, 1, bias=False, modulation=modulation)
        return nn.Conv2d(i, o, 3, 1, 1, bias=False)

    return nn.Sequential(
        conv(cin, cout), nn.BatchNorm2d(cout), nn.ReLU(inplace=True),
        conv(cout, cout), nn.BatchNorm2d(cout), nn.ReLU(inplace=True),
    )


class Up(nn.Module):
    """Bilinear x2 upsampling, pad to the skip's size, concatenate, double (deform) conv."""

    def __init__(self, cin: int, cout: int, deformable: bool, modulation: bool = False) -> None:
        super().__init__()
        self.conv = double_conv(cin, cout, deformable, modulation)

    def forward(self, x: Tensor, skip: Tensor) -> Tensor:
        x = F.interpolate(x, scale_factor=2, mode="bilinear", align_corners=True)
        dy, dx = skip.shape[2] - x.shape[2], skip.shape[3] - x.shape[3]
        if dy or dx:
            x = F.pad(x, (dx // 2, dx - dx // 2, dy // 2, dy - dy // 2))
        return self.conv(torch.cat([skip, x], dim=1))


class DUNet(nn.Module):
    """Deformable U-Net. ``forward(x)`` gives logits at input size (H, W multiples of 16)."""

    arch = "dunet"

    def __init__(self, n_classes: int = 2, width: float = 1.0, modulation: bool = False) -> None:
        super().__init__()
        self.n_classes, self.width, self.modulation = n_classes, width, modulation
        c1, c2, c3, c4 = _channels(width)
        mod = modulation
        self.inc = double_conv(3, c1, False)
        self.down1 = double_conv(c1, c2, True, mod)
        self.down2 = double_conv(c2, c3, True, mod)
        self.down3 = double_conv(c3, c4, False)
        self.down4 = double_conv(c4, c4, False)
        self.up1 = Up(2 * c4, c3, False)
        self.up2 = Up(2 * c3, c2, False)
        self.up3 = Up(2 * c2, c1, True, mod)
        self.up4 = Up(2 * c1, c1, True, mod)
        self.outc = nn.Conv2d(c1 + 3, n_classes, 1)

    def forward(self, x: Tensor, aux: bool = False) -> Tensor | dict[str, Tensor]:
        x1 = self.inc(x)
        x2 = self.down1(F.max_pool2d(x1, 2))
        x3 = self.down2(F.max_pool2d(x2, 2))
        x4 = self.down3(F.max_pool2d(x3, 2))
        x5 = self.down4(F.max_pool2d(x4, 2))
        y = self.up1(x5, x4)
        y = self.up2(y, x3)
        y = self.up3(y, x2)
        y = self.up4(y, x1)
        out = self.outc(torch.cat([x, y], dim=1))
        return {"out": out} if aux else out

    def inference_parameters(self) -> int:
        """All parameters are used at inference (no auxiliary heads)."""
        return sum(p.numel() for p in self.parameters())

    def offset_parameters(self) -> list[nn.Parameter]:
        """Parameters of the offset/modulation convs (trained at a lower learning rate)."""
        return [p for m in self.modules() if isinstance(m, DeformConv2d) for p in m.offset_conv.parameters()]
