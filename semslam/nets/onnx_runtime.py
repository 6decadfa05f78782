"""Running the shipped networks with ONNX Runtime, so that inference needs no torch.

:class:`OnnxNet` is the :class:`Net` of an ``.onnx`` file (the shipped ones, or one written
by ``semslam export-onnx``): ``run(*arrays)`` returns the graph's outputs as NumPy arrays
from an ONNX Runtime session on the CPU, and ``meta`` is the checkpoint's metadata
(architecture, classes, input size, how it was trained). ``nets.onnx_load.load_net`` picks
it or torch (for a ``.pt``) by the file. The graphs, their inputs and outputs are described
in ``nets.onnx_graphs``.

Threads: a session's intra-op pool has ``SEMSLAM_ONNX_THREADS`` threads if set, else
``OMP_NUM_THREADS`` (what torch's intra-op pool reads, and what the CLI's
``runtime.limit_threads`` sets to 1, since SLAM's own threads fill the cores), else ONNX
Runtime's default (one per physical core, as torch). Idle pool threads do not spin.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from semslam.errors import DataError

#: Key of the metadata property holding the checkpoint's ``meta`` as JSON.
META_KEY = "semslam_meta"
#: What each architecture's weights are called in messages.
LABELS = {"stdc1": "STDC network", "dunet": "DUNet network", "sdfcnn": "SDFCNN", "fpfdcnn": "FPFDCNN"}
THREADS_VARIABLE = "SEMSLAM_ONNX_THREADS"


class Net(Protocol):
    """A network's inference graph: arrays in, arrays out (see ``nets.onnx_graphs``)."""

    path: Path
    meta: dict[str, Any]

    def run(self, *inputs: NDArray[Any]) -> tuple[NDArray[Any], ...]: ...


def input_multiple(arch: str) -> int:
    """Input sides are kept multiples of this.

    STDC resizes its context features to the recorded sizes of the finer ones (as the
    original code), so any size runs; multiples of 8 keep the 1/8 head aligned
    (240 = 7.5 * 32 is fine). The U-Net's 4 poolings need multiples of 16 to align skips,
    and FPFDCNN's 16-pixel cells too.
    """
    return 8 if arch == "stdc1" else 16


def intra_op_threads() -> int:
    """Threads of a session's intra-op pool (0 = ONNX Runtime's default); see the module doc."""
    for var in (THREADS_VARIABLE, "OMP_NUM_THREADS"):
        value = os.environ.get(var, "").strip()
        if value:
            try:
                return max(0, int(value))
            except ValueError:
                continue
    return 0


class OnnxNet:
    """One ``.onnx`` network in an ONNX Runtime CPU session (thread-safe: ``run`` may be
    called from several threads at once)."""

    def __init__(self, path: str | Path) -> None:
        import onnxruntime as ort

        self.path = Path(path)
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = intra_op_threads()
        opts.inter_op_num_threads = 1
        opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        opts.log_severity_level = 3  # errors only: no optimizer chatter on stderr
        opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
        try:
            self.session = ort.InferenceSession(str(self.path), opts, providers=["CPUExecutionProvider"])
        except Exception as exc:  # noqa: BLE001 - onnxruntime raises its own types for bad files
            raise DataError(self.path, f"cannot load ONNX network: {str(exc).splitlines()[0]}") from None
        text = self.session.get_modelmeta().custom_metadata_map.get(META_KEY)
        if not text:
            raise DataError(self.path, f"ONNX file without semslam metadata ({META_KEY}); "
                                       "write it with `semslam export-onnx`")
        self.meta: dict[str, Any] = json.loads(text)
        self.input_names = [i.name for i in self.session.get_inputs()]
        self.output_names = [o.name for o in self.session.get_outputs()]

    def run(self, *inputs: NDArray[Any]) -> tuple[NDArray[Any], ...]:
        if len(inputs) != len(self.input_names):
            raise ValueError(f"{self.path.name}: expects inputs {self.input_names}, got {len(inputs)} arrays")
        feeds = {name: np.ascontiguousarray(a) for name, a in zip(self.input_names, inputs)}
        return tuple(self.session.run(self.output_names, feeds))
