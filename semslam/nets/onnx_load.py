"""``load_net(path, arch)``: a network's :class:`~semslam.nets.onnx_runtime.Net` by its file.

An ``.onnx`` file runs in ONNX Runtime (``onnx_runtime.OnnxNet``, no torch); any other file
is taken for a PyTorch checkpoint and runs the same graph in torch
(``onnx_graphs.TorchNet``), which needs the ``train`` extra: without torch it is one clear
error that says how to convert the file.
"""

from __future__ import annotations

from pathlib import Path

from semslam.errors import DataError
from semslam.nets.onnx_runtime import LABELS, Net, OnnxNet


def load_net(path: str | Path, arch: str) -> Net:
    """The network in ``path`` (``.onnx``: ONNX Runtime; else a PyTorch checkpoint, run by
    torch), checked to be an ``arch`` network. DataError naming the file if it is missing,
    unreadable, of another architecture, or a checkpoint while torch is not installed."""
    path = Path(path)
    label = LABELS.get(arch, arch)
    if not path.is_file():
        raise DataError(path, f"{label} weights not found (semslam/data/NETS.md says how to train and export them)")
    if path.suffix == ".onnx":
        net: Net = OnnxNet(path)
    else:
        try:
            from semslam.nets.onnx_graphs import TorchNet
        except ImportError as exc:
            if (exc.name or "").split(".")[0] != "torch":
                raise
            raise DataError(path, f"is a PyTorch checkpoint, which needs torch (pip install 'semslam[train]'); "
                                  f"or convert it once with `semslam export-onnx {path}` and use the .onnx") from None
        net = TorchNet(path, arch)
    found = net.meta.get("arch")
    if found != arch:
        raise DataError(path, f"holds a {found} network, not {arch}")
    return net
