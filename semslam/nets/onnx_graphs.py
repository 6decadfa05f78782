"""The inference graphs of the project's networks in torch: what ``semslam export-onnx``
writes to ONNX, and what a PyTorch checkpoint runs through when a user passes a ``.pt``.

One graph per architecture, from raw pixels to the outputs the backends post-process
(``nets.outputs``); the normalisation is inside, so a caller feeds uint8 images:

=========  =====================================  ============================================
arch       input                                  outputs
=========  =====================================  ============================================
stdc1      ``image`` (1, H, W, 3) uint8 RGB at    ``prob`` (1, C, H, W) softmax probabilities
dunet      the network's input size               (H, W multiples of 8 / 16)
sdfcnn     ``image`` (1, H, W, 3) uint8 RGB,      ``seg`` (1, 40, h, w) logits, ``depth``
           any size (Layer 0 resizes inside)      (1, 1, h, w) metres; h, w = Layer 0 / 4
fpfdcnn    ``gray`` (1, 1, H, W) uint8,           ``prob`` (1, 1, H, W) keypoint probability,
           H, W multiples of 16                   ``coarse`` (1, 256, H/16, W/16) descriptors
=========  =====================================  ============================================

Export (``export_onnx``) uses the TorchScript-based exporter (``dynamo=False``, opset 17:
DUNet's deformable convolution is ``grid_sample``, opset >= 16) with dynamic H and W.
BatchNorm is written as its arithmetic on the stored statistics instead of being folded
into the convolutions, so every weight keeps the value the checkpoint stores: the shipped
checkpoints hold float16 weights, and tensors float16 represents exactly are stored as
float16 in the ONNX file with a Cast to float32 (half the size, computation unchanged).
The checkpoint's ``meta`` goes into the ONNX metadata (``onnx_runtime.META_KEY``).
After writing, the file is run in ONNX Runtime on a random image at two sizes and compared
with this module's graph; ``export_onnx`` returns the largest difference.
"""

from __future__ import annotations

import hashlib
import json
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray
from torch import Tensor, nn

from semslam.errors import DataError
from semslam.nets.onnx_runtime import META_KEY, input_multiple

OPSET = 17
#: Input and output names per architecture (see the module doc).
IO_NAMES: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "stdc1": (("image",), ("prob",)),
    "dunet": (("image",), ("prob",)),
    "sdfcnn": (("image",), ("seg", "depth")),
    "fpfdcnn": (("gray",), ("prob", "coarse")),
}


class SegmentationGraph(nn.Module):
    """STDC / DUNet: uint8 RGB -> (x / 255 - mean) / std -> network -> softmax."""

    def __init__(self, model: nn.Module, mean: list[float], std: list[float]) -> None:
        super().__init__()
        self.model = model
        self.register_buffer("mean", torch.tensor(mean, dtype=torch.float32).view(1, 3, 1, 1))
        self.register_buffer("std", torch.tensor(std, dtype=torch.float32).view(1, 3, 1, 1))

    def forward(self, image: Tensor) -> Tensor:
        x = image.permute(0, 3, 1, 2).float() / 255.0
        return torch.softmax(self.model((x - self.mean) / self.std), dim=1)


class SdfcnnGraph(nn.Module):
    """SDFCNN: uint8 RGB -> eq. 15 -> Layer 0 .. judge layers (``SDFCNN.heads``)."""

    def __init__(self, model: nn.Module) -> None:
        super().__init__()
        self.model = model

    def forward(self, image: Tensor) -> tuple[Tensor, Tensor]:
        from semslam.nets.sdfcnn import normalise

        return self.model.heads(normalise(image.permute(0, 3, 1, 2)))


class FpfdcnnGraph(nn.Module):
    """FPFDCNN: uint8 grey -> / 255 -> keypoint probabilities and coarse descriptors."""

    def __init__(self, model: nn.Module) -> None:
        super().__init__()
        self.model = model

    def forward(self, gray: Tensor) -> tuple[Tensor, Tensor]:
        return self.model(gray.float() / 255.0)


def inference_graph(model: nn.Module, meta: dict[str, Any]) -> nn.Module:
    """The graph of ``model`` (an ``meta["arch"]`` network), in eval mode."""
    arch = meta["arch"]
    if arch in ("stdc1", "dunet"):
        graph: nn.Module = SegmentationGraph(model, meta["mean"], meta["std"])
    elif arch == "sdfcnn":
        graph = SdfcnnGraph(model)
    elif arch == "fpfdcnn":
        graph = FpfdcnnGraph(model)
    else:
        raise ValueError(f"no inference graph for architecture {arch!r}")
    return graph.eval()


def load_torch(path: str | Path, arch: str) -> tuple[nn.Module, dict[str, Any]]:
    """(network, meta) of a PyTorch checkpoint of ``arch`` (FPFDCNN has its own format)."""
    if arch == "fpfdcnn":
        from semslam.nets.fpfdcnn import load_fpfdcnn

        return load_fpfdcnn(path)
    from semslam.nets.models import load_checkpoint

    return load_checkpoint(path)


class TorchNet:
    """A PyTorch checkpoint run through its inference graph: the ``onnx_runtime.Net`` of a
    ``.pt`` file, and the reference the ONNX files are checked against."""

    def __init__(self, path: str | Path, arch: str) -> None:
        self.path = Path(path)
        model, self.meta = load_torch(self.path, arch)
        self.graph = inference_graph(model, self.meta)

    def run(self, *inputs: NDArray[Any]) -> tuple[NDArray[Any], ...]:
        with torch.inference_mode():
            out = self.graph(*(torch.from_numpy(np.ascontiguousarray(a)) for a in inputs))
        return tuple(t.numpy() for t in ((out,) if isinstance(out, Tensor) else out))


# ------------------------------------------------------------------------------- export

class ExplicitBatchNorm(nn.Module):
    """Eval-mode BatchNorm written out (scale and shift from the stored statistics), so the
    exporter keeps the stored tensors instead of folding them into the preceding conv."""

    def __init__(self, bn: nn.BatchNorm2d) -> None:
        super().__init__()
        self.bn = bn

    def forward(self, x: Tensor) -> Tensor:
        bn = self.bn
        scale = bn.weight * torch.rsqrt(bn.running_var + bn.eps)
        shift = bn.bias - bn.running_mean * scale
        return x * scale.view(1, -1, 1, 1) + shift.view(1, -1, 1, 1)


def _explicit_batch_norms(module: nn.Module) -> None:
    for name, child in module.named_children():
        if isinstance(child, nn.BatchNorm2d):
            setattr(module, name, ExplicitBatchNorm(child))
        else:
            _explicit_batch_norms(child)


def example_input(arch: str, meta: dict[str, Any], size: tuple[int, int] | None = None,
                  seed: int = 0) -> NDArray[np.uint8]:
    """A random uint8 input of the graph: ``size`` (w, h), default the training input size
    (640x480 for SDFCNN and FPFDCNN, whose graphs take whole frames)."""
    if size is None:
        size = tuple(meta["input_size"]) if arch in ("stdc1", "dunet") else (640, 480)  # type: ignore[assignment]
    w, h = size
    shape = (1, 1, h, w) if arch == "fpfdcnn" else (1, h, w, 3)
    return np.random.default_rng(seed).integers(0, 256, shape, dtype=np.uint8)


def _drop_identities(model: Any) -> None:
    """Point the users of ``Identity(initializer)`` nodes at the initializer itself. The
    exporter writes such nodes for parameters with equal values (e.g. untrained BatchNorms,
    all ones), and ONNX Runtime 1.32 refuses the graph when they feed a later node."""
    inits = {i.name for i in model.graph.initializer}
    alias = {n.output[0]: n.input[0] for n in model.graph.node if n.op_type == "Identity" and n.input[0] in inits}
    if not alias:
        return
    outputs = {o.name for o in model.graph.output}
    kept = [n for n in model.graph.node if not (n.op_type == "Identity" and n.output[0] in alias
                                                 and n.output[0] not in outputs)]
    for node in kept:
        for k, name in enumerate(node.input):
            if name in alias and name not in outputs:
                node.input[k] = alias[name]
    del model.graph.node[:]
    model.graph.node.extend(kept)


def _store_half(model: Any) -> None:
    """Float32 initializers that float16 represents exactly become float16 + Cast."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    casts = []
    for init in model.graph.initializer:
        if init.data_type != TensorProto.FLOAT:
            continue
        arr = numpy_helper.to_array(init)
        half = arr.astype(np.float16)
        if arr.size < 2 or not np.array_equal(half.astype(np.float32), arr):
            continue
        name = init.name
        init.CopyFrom(numpy_helper.from_array(half, f"{name}.fp16"))
        casts.append(helper.make_node("Cast", [f"{name}.fp16"], [name], name=f"{name}.cast", to=TensorProto.FLOAT))
    nodes = list(model.graph.node)
    del model.graph.node[:]
    model.graph.node.extend(casts + nodes)
    onnx.checker.check_model(model)


def export_onnx(checkpoint: str | Path, out: str | Path, arch: str | None = None,
                half: bool = True) -> dict[str, Any]:
    """Write ``checkpoint``'s inference graph to ``out`` (.onnx); returns what was written:
    path, bytes, arch and the largest |ONNX Runtime - torch| difference of any output on a
    random image at the training size and at a second size (checks the dynamic axes)."""
    import onnx

    from semslam.nets.onnx_runtime import OnnxNet

    checkpoint, out = Path(checkpoint), Path(out)
    if arch is None:
        arch = _checkpoint_arch(checkpoint)
    model, meta = load_torch(checkpoint, arch)
    graph = inference_graph(model, meta)
    reference = TorchNet(checkpoint, arch)  # a fresh copy: the export graph's BatchNorms are rewritten
    _explicit_batch_norms(graph)
    inputs, outputs = IO_NAMES[arch]
    x = example_input(arch, meta)
    axes = {"image": {1: "height", 2: "width"}, "gray": {2: "height", 3: "width"}}
    dynamic = {n: axes[n] for n in inputs}
    dynamic.update({n: {2: "out_height", 3: "out_width"} for n in outputs})
    out.parent.mkdir(parents=True, exist_ok=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # TracerWarnings of shape checks that hold for every valid input
        torch.onnx.export(graph, (torch.from_numpy(x),), str(out), input_names=list(inputs),
                          output_names=list(outputs), dynamic_axes=dynamic, opset_version=OPSET,
                          do_constant_folding=False, dynamo=False)
    proto = onnx.load(str(out))
    _drop_identities(proto)
    if half:
        _store_half(proto)
    digest = hashlib.sha256(checkpoint.read_bytes()).hexdigest()
    export = {"source": checkpoint.name, "source_sha256": digest, "opset": OPSET, "torch": torch.__version__,
              "inputs": list(inputs), "outputs": list(outputs),
              "weights": "float16 where exact, else float32" if half else "float32"}
    stored = dict(meta, onnx_export=export)
    stored.setdefault("parameters", sum(p.numel() for p in model.parameters()))
    del proto.metadata_props[:]
    onnx.helper.set_model_props(proto, {META_KEY: json.dumps(stored, default=str)})
    proto.doc_string = f"semslam {arch} network exported from {checkpoint.name}"
    onnx.save(proto, str(out))

    net = OnnxNet(out)
    h, w = x.shape[-2:] if arch == "fpfdcnn" else x.shape[1:3]
    m = input_multiple(arch)
    err = 0.0
    for size in ((w, h), (w * 3 // 4 // m * m, h * 3 // 4 // m * m)):
        xi = example_input(arch, meta, size, seed=1)
        for a, b in zip(net.run(xi), reference.run(xi)):
            err = max(err, float(np.abs(a - b).max()))
    return {"path": str(out), "bytes": out.stat().st_size, "arch": arch, "max_abs_diff": err}


def _checkpoint_arch(path: Path) -> str:
    """The architecture a checkpoint holds (``meta["arch"]``)."""
    if not path.is_file():
        raise DataError(path, "checkpoint not found")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
        arch = ckpt["meta"]["arch"]
    except Exception as exc:  # noqa: BLE001 - torch raises many types for bad files
        raise DataError(path, f"not a semslam network checkpoint ({exc})") from None
    if arch not in IO_NAMES:
        raise DataError(path, f"no ONNX graph for architecture {arch!r}")
    return str(arch)
