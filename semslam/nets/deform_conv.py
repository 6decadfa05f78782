"""Deformable convolution v2 (Zhu et al., CVPR 2019) written with plain PyTorch ops.

Why by hand: torchvision (which has ``ops.deform_conv2d``) has no CPU wheel that fits this
project, and DUNet (Jin et al. 2019) needs deformable convs. The op is:

    y(p) = sum_k w_k * m_k(p) * x(p0 + p_k + dp_k(p))

with offsets ``dp`` and modulation ``m`` (in [0, 1]) predicted per output pixel by an
ordinary conv. Sampling at fractional positions is bilinear with zeros outside the
image (like the CUDA DCN kernels), done by ``F.grid_sample`` for all kernel taps at
once; the taps are then contracted with the weights as one matrix product (the
"unfolded" im2col form of a convolution). Gradients flow to the input, the weights,
the offsets and the mask through ``grid_sample`` autograd.

Offset layout follows torchvision/mmcv: ``offset`` is (N, 2*kh*kw, Ho, Wo) holding
(dy, dx) pairs per tap in row-major tap order; ``mask`` is (N, kh*kw, Ho, Wo).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

#: Most elements of the sampled-column buffer (C*K*rows*Wo per image) built at once;
#: larger outputs are processed in bands of output rows to bound memory (a full-width
#: DUNet at 640x480 would otherwise need >1 GB for one layer).
MAX_COLUMN_ELEMENTS = 1 << 25


def _pair(v: int | tuple[int, int]) -> tuple[int, int]:
    return (v, v) if isinstance(v, int) else (int(v[0]), int(v[1]))


def deform_conv2d(
    x: Tensor,
    offset: Tensor,
    weight: Tensor,
    bias: Tensor | None = None,
    mask: Tensor | None = None,
    stride: int | tuple[int, int] = 1,
    padding: int | tuple[int, int] = 0,
    dilation: int | tuple[int, int] = 1,
) -> Tensor:
    """Modulated deformable convolution (one offset group, no weight groups).

    With ``offset == 0`` and ``mask == 1`` (or ``None``) this is exactly
    ``F.conv2d(x, weight, bias, stride, padding, dilation)``.
    """
    n, c, h, w = x.shape
    o, cw, kh, kw = weight.shape
    if cw != c:
        raise ValueError(f"deform_conv2d: weight expects {cw} input channels, got {c}")
    sh, sw = _pair(stride)
    ph, pw = _pair(padding)
    dh, dw = _pair(dilation)
    ho = (h + 2 * ph - dh * (kh - 1) - 1) // sh + 1
    wo = (w + 2 * pw - dw * (kw - 1) - 1) // sw + 1
    k = kh * kw
    if offset.shape != (n, 2 * k, ho, wo):
        raise ValueError(f"deform_conv2d: offset must be {(n, 2 * k, ho, wo)}, got {tuple(offset.shape)}")
    if mask is not None and mask.shape != (n, k, ho, wo):
        raise ValueError(f"deform_conv2d: mask must be {(n, k, ho, wo)}, got {tuple(mask.shape)}")

    dev, dt = x.device, x.dtype
    # Regular sampling grid p0 + p_k in input pixel coordinates (padding = zeros outside).
    tap_y = (torch.arange(kh, device=dev, dtype=dt) * dh).repeat_interleave(kw)  # (K,)
    tap_x = (torch.arange(kw, device=dev, dtype=dt) * dw).repeat(kh)  # (K,)
    base_y = torch.arange(ho, device=dev, dtype=dt) * sh - ph  # (Ho,)
    base_x = torch.arange(wo, device=dev, dtype=dt) * sw - pw  # (Wo,)
    off = offset.view(n, k, 2, ho, wo)
    # grid_sample(align_corners=False) puts the centre of pixel i at (2i + 1) / size - 1.
    scale_y, scale_x = 2.0 / h, 2.0 / w
    w2 = weight.reshape(o, c * k)

    rows_per_band = max(1, MAX_COLUMN_ELEMENTS // max(1, c * k * wo))
    outs = []
    for r0 in range(0, ho, rows_per_band):
        r1 = min(ho, r0 + rows_per_band)
        py = tap_y[:, None, None] + base_y[None, r0:r1, None]  # (K, R, 1)
        px = tap_x[:, None, None] + base_x[None, None, :]  # (K, 1, Wo)
        sy = py + off[:, :, 0, r0:r1]  # (N, K, R, Wo)
        sx = px + off[:, :, 1, r0:r1]
        grid = torch.stack(((sx + 0.5) * scale_x - 1.0, (sy + 0.5) * scale_y - 1.0), dim=-1)
        grid = grid.reshape(n, k * (r1 - r0), wo, 2)
        cols = F.grid_sample(x, grid, mode="bilinear", padding_mode="zeros", align_corners=False)
        cols = cols.view(n, c, k, r1 - r0, wo)
        if mask is not None:
            cols = cols * mask[:, None, :, r0:r1]
        # (O, C*K) @ (N, C*K, R*Wo): the im2col form of the convolution.
        outs.append(torch.matmul(w2, cols.reshape(n, c * k, (r1 - r0) * wo)).view(n, o, r1 - r0, wo))
    out = outs[0] if len(outs) == 1 else torch.cat(outs, dim=2)
    if bias is not None:
        out = out + bias.view(1, o, 1, 1)
    return out


class DeformConv2d(nn.Module):
    """DCNv2 layer: a conv predicts offsets (and a sigmoid modulation) for a deformable conv.

    As in DCNv2, the offset/modulation conv starts at zero, so training starts from a
    regular conv (offsets 0) with every tap weighted 0.5; ``modulation=False`` gives
    DCNv1 (what the official DUNet code uses). The offset conv has the same kernel, stride,
    padding and dilation as the main conv so its output is on the output grid.
    """

    def __init__(
        self,
        in_channels: int,
        out_channels: int,
        kernel_size: int = 3,
        stride: int = 1,
        padding: int = 1,
        dilation: int = 1,
        bias: bool = True,
        modulation: bool = True,
    ) -> None:
        super().__init__()
        kh, kw = _pair(kernel_size)
        self.stride, self.padding, self.dilation = _pair(stride), _pair(padding), _pair(dilation)
        self.modulation = modulation
        self.n_taps = kh * kw
        self.weight = nn.Parameter(torch.empty(out_channels, in_channels, kh, kw))
        self.bias = nn.Parameter(torch.empty(out_channels)) if bias else None
        n_off = (3 if modulation else 2) * self.n_taps
        self.offset_conv = nn.Conv2d(
            in_channels, n_off, (kh, kw), self.stride, self.padding, self.dilation, bias=True
        )
        self.reset_parameters()

    def reset_parameters(self) -> None:
        # Same initialisation as nn.Conv2d for the main weights; zeros for the offsets.
        nn.init.kaiming_uniform_(self.weight, a=math.sqrt(5))
        if self.bias is not None:
            fan_in = self.weight.shape[1] * self.n_taps
            bound = 1.0 / math.sqrt(fan_in)
            nn.init.uniform_(self.bias, -bound, bound)
        nn.init.zeros_(self.offset_conv.weight)
        nn.init.zeros_(self.offset_conv.bias)

    def forward(self, x: Tensor) -> Tensor:
        om = self.offset_conv(x)
        offset = om[:, : 2 * self.n_taps]
        mask = torch.sigmoid(om[:, 2 * self.n_taps :]) if self.modulation else None
        return deform_conv2d(
            x, offset, self.weight, self.bias, mask, self.stride, self.padding, self.dilation
        )

    def extra_repr(self) -> str:
        o, i, kh, kw = self.weight.shape
        return (f"{i}, {o}, kernel_size=({kh}, {kw}), stride={self.stride}, padding={self.padding}, "
                f"dilation={self.dilation}, modulation={self.modulation}")
