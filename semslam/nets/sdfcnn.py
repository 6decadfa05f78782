"""SDFCNN: SDF-SLAM's joint semantic segmentation + depth network (Table 13, Table 4, eqs. 15, 21).

Table 13 describes, layer by layer, a MobileNet-v2 encoder with a Light-Weight RefineNet
decoder and two heads (the multi-task network of Nekrasov et al., "Real-time joint semantic
segmentation and depth estimation using asymmetric annotations", ICRA 2019):

* Layer 0: bilinear resize of the normalised image (eq. 15) to 400x300.
* Encoder (Table 4: Layer 1 one convbnrelu, Layers 2-7 with 1, 2, 3, 4, 3, 4 blocks): a
  block is three convbnrelu modules, 1x1 expansion (x1 in Layer 2, x6 after), 3x3 depthwise
  (group = channels), 1x1 projection; blocks inside a layer are summed with residual
  connections (Layer4 = Layer4_3 + Layer4_6 + Layer4_9). Widths 32, 16, 24, 32, 64, 96,
  (160, 160, 160, 320); strides 2, 1, 2, 2, 2, 1, 2 (400x300 -> 13x10 at Layer 7).
* Decoder: the 320 and 160 features are projected to 256 (Layer7_13/14), summed, ReLU'd
  (Layer7_15), refined by four "max-pool 5x5 stride 1 + 1x1 conv" stages whose outputs are
  summed (chained residual pooling, Layer7_16..23), 1x1 conv (Layer7_24), bilinear up
  (Layer 8); Layer 9 = Layer 8 + 1x1(Layer 6) + 1x1(Layer 5), the same refinement; Layer 10
  = its upsampling + 1x1(Layer 4), refined again; Layer 11 = its upsampling + 1x1(Layer 3)
  (no pooling at half resolution: the paper says it costs too much time).
* Judge layers: seg = depthwise 1x1 conv + ReLU, seg1 = 1x1 conv to 40 classes (with bias);
  depth = depthwise 1x1 conv + ReLU, depth1 = 3x3 conv to 1 channel (with bias).
* Output: bilinear interpolation of both to 640x480.

Where Table 13 is inconsistent it is read by its channel shapes, which fix the graph:
Layer5_9 is "1x1x64x384" but maps 384 -> 64; Layer4_10 is "1x1x64x256" and Layer3_7
"1x1x32x256", but Layer 4 has 32 and Layer 3 has 24 channels; the Pre_Layer column of
Layer7_13/14 points at rows whose widths (Layer7_10: 960) cannot feed a 320- or 160-channel
conv, so they take Layer 7's 320 output (Layer7_12) and its 160-channel stage (Layer7_9
summed); seg1's bias is listed as 256 but a 40-channel conv has 40. Table 13 lists the
pooling of Layer 10 only as four convs; the text ("Layer 10 has the same design idea as
Layer 8") and Light-Weight RefineNet pool there too, as here (pooling has no parameters).
Activations follow MobileNet-v2 and Light-Weight RefineNet: ReLU6 in convbnrelu, none after
a block's projection (the linear bottleneck; Table 13 names every module "convbnrelu"),
ReLU after each decoder sum (Table 13 lists only Layer7_15's).

Parameters: this graph at full width has 2,987,113 parameters (40 classes), not the 11.8 M
of Tables 8/9. No reading of Table 13 gets near 11.8 M: every weight shape is written out,
and summing them as printed (:func:`table13_parameter_count`, typos included) gives
2,997,569. What 11.8 matches is a size in MiB: this model's float32 state (weights and
BatchNorm statistics) is 11.5 MiB (:func:`float32_mebibytes`), and Nekrasov et al.'s
released network, whose segmentation conv is 3x3 and which pools depthwise at Layer 11 too
(+82,944 weights), is 11.8 MiB. So the paper's "11.8 M" is most likely its model file's
size, not a parameter count; the tests check the count against Table 13's shapes and the
float32 size against 11.8. ``width`` scales every channel count
(1.0 = Table 13) so a small model can ship.
"""

from __future__ import annotations

from typing import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from semslam.nets.outputs import upsampled_argmax  # noqa: F401 - the output layer, torch-free
from semslam.nets.stdc import scaled

#: What Tables 8 and 9 give as SDFCNN's "Parameter".
PAPER_PARAMETERS = 11.8e6
#: Layer 0's size (w, h) and the output size (w, h), Table 13.
PAPER_INPUT_SIZE = (400, 300)
PAPER_OUTPUT_SIZE = (640, 480)
N_CLASSES = 40
#: Eq. 15: img_scale = 1/255, ImageNet mean and std (Sec. IV-C).
IMG_SCALE = 1.0 / 255.0
MEAN = (0.485, 0.456, 0.406)
STD = (0.229, 0.224, 0.225)
#: Eq. 21's lambda: weight of the segmentation loss (0.4, "more focused on the depth").
LAMBDA = 0.4
IGNORE_INDEX = 255

#: Encoder layers 2-7 (Table 4 and 13): (expansion t, output channels c, blocks n, stride s).
#: Layer 7 holds three 160-channel blocks and one 320-channel block (Layer7_1..Layer7_12).
ENCODER: tuple[tuple[tuple[int, int, int, int], ...], ...] = (
    ((1, 16, 1, 1),),  # Layer 2
    ((6, 24, 2, 2),),  # Layer 3
    ((6, 32, 3, 2),),  # Layer 4
    ((6, 64, 4, 2),),  # Layer 5
    ((6, 96, 3, 1),),  # Layer 6
    ((6, 160, 3, 2), (6, 320, 1, 1)),  # Layer 7
)
DECODER_WIDTH = 256
CRP_STAGES = 4


def normalise(rgb: Tensor) -> Tensor:
    """Eq. 15 on a uint8 (N, 3, H, W) RGB batch: (img * 1/255 - mean) / std."""
    mean = torch.tensor(MEAN, device=rgb.device).view(1, 3, 1, 1)
    std = torch.tensor(STD, device=rgb.device).view(1, 3, 1, 1)
    return (rgb.float() * IMG_SCALE - mean) / std


class ConvBnRelu(nn.Sequential):
    """The paper's convbnrelu (Fig. 6 left): conv without bias, BatchNorm, ReLU6 (optional)."""

    def __init__(self, cin: int, cout: int, kernel: int = 1, stride: int = 1, groups: int = 1,
                 act: bool = True) -> None:
        layers: list[nn.Module] = [nn.Conv2d(cin, cout, kernel, stride, kernel // 2, groups=groups, bias=False),
                                   nn.BatchNorm2d(cout)]
        if act:
            layers.append(nn.ReLU6(inplace=True))
        super().__init__(*layers)


class Block(nn.Module):
    """Fig. 6 middle: 1x1 expansion, 3x3 depthwise, 1x1 (linear) projection; the layer's
    residual sum (Fig. 6 right) where input and output shapes agree."""

    def __init__(self, cin: int, cout: int, expansion: int, stride: int) -> None:
        super().__init__()
        hidden = cin * expansion
        self.convs = nn.Sequential(
            ConvBnRelu(cin, hidden, 1),
            ConvBnRelu(hidden, hidden, 3, stride, groups=hidden),
            ConvBnRelu(hidden, cout, 1, act=False),
        )
        self.residual = stride == 1 and cin == cout

    def forward(self, x: Tensor) -> Tensor:
        out = self.convs(x)
        return x + out if self.residual else out


class ChainedPooling(nn.Module):
    """Layers 8-10's refinement: ``stages`` x (max-pool 5x5 stride 1 -> 1x1 conv), the input
    and every stage's output summed, then the 1x1 "adapt" conv (Layer7_16..Layer7_24)."""

    def __init__(self, channels: int, stages: int = CRP_STAGES, pool: bool = True) -> None:
        super().__init__()
        self.convs = nn.ModuleList([nn.Conv2d(channels, channels, 1, bias=False) for _ in range(stages)])
        self.pool = nn.MaxPool2d(5, 1, 2) if pool else nn.Identity()
        self.adapt = nn.Conv2d(channels, channels, 1, bias=False)

    def forward(self, x: Tensor) -> Tensor:
        top, total = x, x
        for conv in self.convs:
            top = conv(self.pool(top))
            total = total + top
        return self.adapt(total)


class SDFCNN(nn.Module):
    """Table 13. ``forward(x)`` takes an eq.-15-normalised batch of any size and returns
    ``{"seg": (N, 40, H, W) logits, "depth": (N, 1, H, W) metres}`` at ``out_size``
    (default 640x480; ``None`` = the input's size)."""

    arch = "sdfcnn"

    def __init__(self, n_classes: int = N_CLASSES, width: float = 1.0,
                 input_size: Sequence[int] | None = PAPER_INPUT_SIZE,
                 output_size: Sequence[int] | None = PAPER_OUTPUT_SIZE) -> None:
        super().__init__()
        self.n_classes, self.width = n_classes, width
        self.input_size = tuple(input_size) if input_size else None  # (w, h) of Layer 0
        self.output_size = tuple(output_size) if output_size else None  # (w, h)
        cin = scaled(32, width)
        self.layer1 = ConvBnRelu(3, cin, 3, 2)
        self.layers = nn.ModuleList()
        self.stage_channels: list[int] = []  # output widths of Layers 2-7 (and Layer 7's 160 stage)
        for groups in ENCODER:
            blocks: list[nn.Module] = []
            for t, c, n, s in groups:
                cout = scaled(c, width)
                for k in range(n):
                    blocks.append(Block(cin, cout, t, s if k == 0 else 1))
                    cin = cout
                self.stage_channels.append(cout)
            self.layers.append(nn.Sequential(*blocks))
        c3, c4, c5, c6, c7a, c7 = self.stage_channels[1:]
        d = scaled(DECODER_WIDTH, width)
        self.decoder_width = d
        self.conv7_13 = nn.Conv2d(c7, d, 1, bias=False)  # 320 -> 256
        self.conv7_14 = nn.Conv2d(c7a, d, 1, bias=False)  # 160 -> 256
        self.refine8 = ChainedPooling(d)
        self.conv6_10 = nn.Conv2d(c6, d, 1, bias=False)
        self.conv5_13 = nn.Conv2d(c5, d, 1, bias=False)
        self.refine9 = ChainedPooling(d)
        self.conv4_10 = nn.Conv2d(c4, d, 1, bias=False)
        self.refine10 = ChainedPooling(d)
        self.conv3_7 = nn.Conv2d(c3, d, 1, bias=False)
        self.seg = nn.Conv2d(d, d, 1, groups=d, bias=False)
        self.seg1 = nn.Conv2d(d, n_classes, 1, bias=True)
        self.depth = nn.Conv2d(d, d, 1, groups=d, bias=False)
        self.depth1 = nn.Conv2d(d, 1, 3, padding=1, bias=True)
        self.relu = nn.ReLU(inplace=False)
        self._init_weights()

    def _init_weights(self) -> None:
        """Kaiming for the encoder's convs (each followed by BatchNorm); PyTorch's default for the
        decoder's and heads' plain convs, as Light-Weight RefineNet's code: with no BatchNorm
        between its summed stages, Kaiming scaling would blow the activations up ~1000x."""
        for m in self.modules():
            if isinstance(m, ConvBnRelu):
                nn.init.kaiming_normal_(m[0].weight, mode="fan_out")
        nn.init.normal_(self.seg1.weight, std=1e-2)  # start near uniform class scores
        nn.init.zeros_(self.seg1.bias)
        nn.init.normal_(self.depth1.weight, std=1e-3)
        nn.init.constant_(self.depth1.bias, 2.0)  # start near indoor depths (metres)

    def features(self, x: Tensor) -> Tensor:
        """Layer 0 to Layer 11: the shared decoder output at 1/4 of Layer 0's size."""
        if self.input_size is not None and tuple(x.shape[-1:-3:-1]) != self.input_size:
            w, h = self.input_size
            x = F.interpolate(x, size=(h, w), mode="bilinear", align_corners=False)
        x = self.layer1(x)
        l2 = self.layers[0](x)
        l3 = self.layers[1](l2)
        l4 = self.layers[2](l3)
        l5 = self.layers[3](l4)
        l6 = self.layers[4](l5)
        l7a = self.layers[5][:3](l6)  # the 160-channel stage (Layer7_9 + Layer7_6 + Layer7_3)
        l7 = self.layers[5][3:](l7a)  # Layer7_12, 320 channels
        up = lambda t, ref: F.interpolate(t, size=ref.shape[2:], mode="bilinear", align_corners=False)  # noqa: E731
        l8 = self.refine8(self.relu(self.conv7_13(l7) + self.conv7_14(l7a)))
        l9 = self.refine9(self.relu(up(l8, l6) + self.conv6_10(l6) + self.conv5_13(l5)))
        l10 = self.refine10(self.relu(up(l9, l4) + self.conv4_10(l4)))
        return self.relu(up(l10, l3) + self.conv3_7(l3))

    def heads(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """The judge layers' outputs before the output layer: (seg logits, depth) at 1/4 of
        Layer 0's size (100x75 for the paper's 400x300)."""
        f = self.features(x)
        return self.seg1(self.relu(self.seg(f))), self.depth1(self.relu(self.depth(f)))

    def forward(self, x: Tensor, output_size: Sequence[int] | None = None) -> dict[str, Tensor]:
        size = tuple(output_size) if output_size else (self.output_size or tuple(x.shape[-1:-3:-1]))
        seg, depth = self.heads(x)
        w, h = size
        return {"seg": F.interpolate(seg, size=(h, w), mode="bilinear", align_corners=False),
                "depth": F.interpolate(depth, size=(h, w), mode="bilinear", align_corners=False)}

    def inference_parameters(self) -> int:
        """Every parameter is used at inference (no training-only heads)."""
        return sum(p.numel() for p in self.parameters())


# --- the paper's 11.8 M ---------------------------------------------------------------

def table13_parameter_count(n_classes: int = N_CLASSES) -> int:
    """Sum of Table 13's Weight/Bias column, shapes taken literally (typos included: Layer4_10
    64x256, Layer3_7 32x256, seg1 bias 256), plus BatchNorm's scale and shift per convbnrelu."""
    total = 3 * 3 * 3 * 32 + 2 * 32  # Layer1
    cin = 32
    for groups in ENCODER:
        for t, c, n, _ in groups:
            for _ in range(n):
                h = cin * t
                total += cin * h + 9 * h + h * c + 2 * (h + h + c)
                cin = c
    total += 320 * 256 + 160 * 256 + 5 * 256 * 256  # Layer7_13, 7_14, 7_17..7_24
    total += 96 * 256 + 64 * 256 + 5 * 256 * 256  # Layer6_10, 5_13, 9_2..9_9
    total += 64 * 256 + 5 * 256 * 256  # Layer4_10 (as printed), 10_1..10_5
    total += 32 * 256  # Layer3_7 (as printed)
    total += 256 + 256 * n_classes + 256  # seg, seg1 (+ its printed bias of 256)
    total += 256 + 9 * 256 + 1  # depth, depth1
    return total


def float32_mebibytes(model: nn.Module) -> float:
    """Size of the model's float32 state (weights + BatchNorm statistics) in MiB."""
    n = sum(v.numel() for v in model.state_dict().values() if v.is_floating_point())
    return n * 4 / 2**20


def parameter_report(width: float = 1.0, n_classes: int = N_CLASSES) -> str:
    """Parameter count of SDFCNN at ``width``, next to the paper's 11.8 M (and why they differ)."""
    model = SDFCNN(n_classes, width)
    n = sum(p.numel() for p in model.parameters())
    lines = [f"SDFCNN width {width:g}: {n:,} parameters ({n / 1e6:.2f} M); paper (Tables 8/9): "
             f"{PAPER_PARAMETERS / 1e6:.1f} M",
             f"  Table 13's weight shapes summed literally: {table13_parameter_count(n_classes) / 1e6:.2f} M",
             f"  this model as float32 (weights + BN statistics): {float32_mebibytes(model):.1f} MiB "
             "(the paper's 11.8 M is near the full-width float32 size in MiB: most likely a file size, not a count)"]
    return "\n".join(lines)


# --- eq. 21 --------------------------------------------------------------------------

def berhu(residual: Tensor) -> Tensor:
    """Reverse Huber (berHu) of the depth residuals: |r| up to c, (r^2 + c^2) / 2c above, with
    c = max|r| / 5 per batch (Laina et al., FCRN: Table 9's depth baseline)."""
    a = residual.abs()
    c = (a.max().detach() / 5).clamp(min=1e-6)
    return torch.where(a <= c, a, (a * a + c * c) / (2 * c)).mean()


def sdfcnn_loss(outputs: dict[str, Tensor], labels: Tensor, depth: Tensor, lam: float = LAMBDA
                ) -> tuple[Tensor, dict[str, float]]:
    """Eq. 21: lambda * H(p, q) + (1 - lambda) * L(y - f(x)).

    H is the pixel cross-entropy of the 40-class logits (the paper writes -lambda H with
    H = sum p log q, i.e. the negative of this positive cross-entropy); L the berHu
    regression loss of the depth residual over pixels with a measured depth (y > 0).
    ``labels`` (N, H, W) class indices 0..39 or 255 (ignored), ``depth`` (N, H, W) metres.
    """
    seg, pred = outputs["seg"], outputs["depth"][:, 0]
    if seg.shape[2:] != labels.shape[1:]:
        raise ValueError(f"outputs {tuple(seg.shape[2:])} and labels {tuple(labels.shape[1:])} differ in size")
    ce = F.cross_entropy(seg, labels, ignore_index=IGNORE_INDEX) if (labels != IGNORE_INDEX).any() \
        else seg.sum() * 0.0
    valid = depth > 0
    reg = berhu(pred[valid] - depth[valid]) if valid.any() else pred.sum() * 0.0
    total = lam * ce + (1 - lam) * reg
    return total, {"ce": float(ce.detach()), "depth": float(reg.detach())}


if __name__ == "__main__":  # python -m semslam.nets.sdfcnn [WIDTH ...]: counts next to the paper's 11.8 M
    import sys

    for arg in sys.argv[1:] or ["1.0"]:
        print(parameter_report(float(arg)))
