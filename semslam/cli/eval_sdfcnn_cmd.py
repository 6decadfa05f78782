"""``semslam eval-sdfcnn SEQ [SEQ...]``: SDF-SLAM's Tables 8 and 9 for SDFCNN on labelled
TUM-layout folders: MPA, MIoU (eqs. 16-17), RMS, REL, delta < 1.25^k (eqs. 18-20), ms per
frame and parameters, per sequence and pooled.

Frames go through the ``sdfcnn`` backends' predictor exactly as a run uses them (full-size
frame in; depth and NYU-40 labels out at the frame's size), so the timing covers the
network, Layer 0's resize and the output layer. Truth labels are mapped to NYU-40 as for
training (``nets.sdf_dataset``: synthetic people are NYU "person", movers ignored).

Next to the network, a baseline that knows no image: each frame's depth predicted as one
constant, the median of that frame's true depth. In a room seen from its middle this
already scores high deltas, so a depth net's numbers mean something only next to it.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path
from typing import Any, Optional

import numpy as np
import typer

from semslam.errors import ConfigError


def evaluate_sequences(paths: list[Path], weights: Path | None, every: int = 1, limit: int = 0,
                       threads: int = 1) -> dict[str, Any]:
    """Tables 8/9's numbers per sequence and over all frames of ``paths``."""
    import torch

    from semslam.core.labels import NYU40_CLASSES
    from semslam.eval.dense_metrics import DepthErrors, class_iou, confusion, mean_iou, mean_pixel_accuracy
    from semslam.io.sequence import TumRgbdSequence
    from semslam.nets.datasets import read_label
    from semslam.nets.sdf_dataset import label_lut
    from semslam.nets.onnx_runtime import THREADS_VARIABLE
    from semslam.semantics.sdfcnn_backend import SdfcnnPredictor

    torch.set_num_threads(threads)
    os.environ[THREADS_VARIABLE] = str(threads)  # the ONNX Runtime session of the shipped .onnx
    predictor = SdfcnnPredictor(weights)
    n = len(NYU40_CLASSES)
    total_conf = np.zeros((n, n), np.int64)
    total_depth = DepthErrors()
    total_base = DepthErrors()
    all_ms: list[float] = []
    rows = []
    for path in paths:
        seq = TumRgbdSequence(path)
        lut = label_lut(path)
        conf = np.zeros((n, n), np.int64)
        depth_err = DepthErrors()
        base = DepthErrors()
        ms: list[float] = []
        indices = list(range(0, len(seq), every))[: limit or None]
        for k in indices:
            frame = seq.load(k)
            assert frame.rgb_path is not None and frame.depth is not None
            truth = lut[read_label(path / "semantic" / frame.rgb_path.name)]
            t0 = time.perf_counter()
            pred = predictor.predict(frame.rgb)
            depth, labels = pred.depth(), pred.labels()
            ms.append(1e3 * (time.perf_counter() - t0))
            conf += confusion(truth, labels.astype(np.int64) - 1, n)  # NYU id k -> index k - 1
            depth_err.add(depth, frame.depth)
            valid = frame.depth[frame.depth > 0]
            if valid.size:
                base.add(np.full_like(frame.depth, float(np.median(valid))), frame.depth)
        total_conf += conf
        total_depth.merge(depth_err)
        total_base.merge(base)
        all_ms += ms
        rows.append(_row(str(path), len(indices), conf, depth_err, ms, mean_pixel_accuracy, mean_iou))
        rows[-1]["constant_depth_baseline"] = base.result()
    params = predictor.parameter_count()
    iou = class_iou(total_conf)
    names = [NYU40_CLASSES[i + 1] for i in range(n)]
    return {
        "weights": str(predictor.weights), "parameters": params, "threads": threads,
        "paper": {"mpa": 0.561, "miou": 0.319, "rms": 0.692, "rel": 0.149, "delta1": 0.761, "delta2": 0.950,
                  "delta3": 0.989, "seconds_per_frame": 0.66, "parameters": "11.8 M"},
        "sequences": rows,
        "all": _row("all", sum(r["frames"] for r in rows), total_conf, total_depth, all_ms, mean_pixel_accuracy,
                    mean_iou),
        "constant_depth_baseline": total_base.result(),
        "class_iou": {nm: round(float(v), 4) for nm, v in zip(names, iou) if not np.isnan(v)},
    }


def _row(name: str, frames: int, conf: np.ndarray, depth: Any, ms: list[float], mpa: Any, miou: Any
         ) -> dict[str, Any]:
    return {"sequence": name, "frames": frames, "mpa": mpa(conf), "miou": miou(conf), **depth.result(),
            "ms_per_frame_median": float(np.median(ms)) if ms else float("nan"),
            "ms_per_frame_mean": float(np.mean(ms)) if ms else float("nan")}


def register(app: typer.Typer) -> None:
    @app.command("eval-sdfcnn")
    def eval_sdfcnn(
        sequences: list[Path] = typer.Argument(..., help="TUM-layout folders with depth and semantic/ labels"),
        weights: Optional[Path] = typer.Option(None, "--weights", help="weights, .onnx or .pt (default: "
                                                                       "the shipped semslam/data/sdfcnn.onnx)"),
        every: int = typer.Option(1, "--every", min=1, help="evaluate every N-th frame"),
        limit: int = typer.Option(0, "--limit", min=0, help="at most this many frames per sequence (0 = all)"),
        threads: int = typer.Option(1, "--threads", min=1, help="inference threads (timing: 1, as in a SLAM run)"),
        json_out: Optional[Path] = typer.Option(None, "--json", help="also write the numbers as JSON"),
    ) -> None:
        """SDFCNN's semantic (Table 8) and depth (Table 9) accuracy, time and size."""
        from rich.console import Console
        from rich.table import Table

        for p in sequences:
            if not (p / "semantic").is_dir():
                raise ConfigError(f"eval-sdfcnn: {p} has no semantic/ folder (labels are needed)")
        res = evaluate_sequences(list(sequences), weights, every, limit, threads)
        table = Table(title=f"SDFCNN ({res['weights']}, {res['parameters'] / 1e6:.2f} M parameters, "
                            f"{threads} thread(s)); paper: MPA 0.561 MIoU 0.319 RMS 0.692 REL 0.149 "
                            "delta 0.761/0.950/0.989, 0.66 s, 11.8 M")
        for col in ("sequence", "frames", "MPA", "MIoU", "RMS (m)", "REL", "d<1.25", "d<1.25^2", "d<1.25^3",
                    "ms/frame (median)"):
            table.add_column(col)
        for r in [*res["sequences"], res["all"]]:
            table.add_row(Path(r["sequence"]).name, str(r["frames"]), f"{r['mpa']:.3f}", f"{r['miou']:.3f}",
                          f"{r['rms']:.3f}", f"{r['rel']:.3f}", f"{r['delta1']:.3f}", f"{r['delta2']:.3f}",
                          f"{r['delta3']:.3f}", f"{r['ms_per_frame_median']:.1f}")
        Console(width=max(140, Console().width)).print(table)
        b = res["constant_depth_baseline"]
        typer.echo(f"baseline (each frame's median true depth everywhere, no image): RMS {b['rms']:.3f} m "
                   f"REL {b['rel']:.3f} delta {b['delta1']:.3f}/{b['delta2']:.3f}/{b['delta3']:.3f}")
        if json_out is not None:
            json_out.parent.mkdir(parents=True, exist_ok=True)
            json_out.write_text(json.dumps(res, indent=2))
            typer.echo(f"wrote {json_out}")
