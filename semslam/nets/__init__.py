"""The papers' segmentation networks in PyTorch: STDC1-Seg (STDC-SLAM) and DUNet (DDL-SLAM).

Modules: ``stdc`` (STDC1 backbone, ARM, FFM, heads, detail guidance loss), ``deform_conv``
(hand-written DCNv2), ``dunet`` (deformable U-Net), ``datasets`` (TUM/semantic and VOC
folders, augmentation), ``train`` (CPU training loop), ``models`` (build/save/load
checkpoints), ``segmenters`` (``StdcSegmenter``/``DunetSegmenter`` backends) and
``evaluate`` (metrics on folders, the real-frame check). Inference needs no torch:
``onnx_runtime`` runs the shipped ``.onnx`` files, ``outputs`` holds the NumPy output
layers, and ``onnx_graphs`` (torch) defines and exports the graphs (``semslam export-onnx``)
and runs a user's ``.pt`` through them. Torch is imported lazily so that ``import
semslam.nets`` stays cheap.
"""

from __future__ import annotations

from typing import Any

_EXPORTS = {
    "StdcSegmenter": "semslam.nets.segmenters",
    "DunetSegmenter": "semslam.nets.segmenters",
    "STDCSeg": "semslam.nets.stdc",
    "DUNet": "semslam.nets.dunet",
    "DeformConv2d": "semslam.nets.deform_conv",
    "deform_conv2d": "semslam.nets.deform_conv",
    "build_model": "semslam.nets.models",
    "load_checkpoint": "semslam.nets.models",
    "save_checkpoint": "semslam.nets.models",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        import importlib

        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'semslam.nets' has no attribute {name!r}")
