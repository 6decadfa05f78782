#!/usr/bin/env python
"""Benchmark: the shipped networks in ONNX Runtime (``semslam/data/*.onnx``) against the
same graphs in torch (``*.pt`` through ``nets.onnx_graphs.TorchNet``), one thread each.

    python benchmarks/onnx_timing.py [--repeats 10] [--json out.json]

Each graph runs on one input of the size a SLAM run gives it (STDC and DUNet 320x240, the
network input of a 640x480 frame; SDFCNN and FPFDCNN the whole 640x480 frame), batch 1,
after a warm-up; the two runtimes alternate so load changes hit both alike. Reported: the
median (p50) and minimum wall time, the median CPU time of the process (with one thread
it is the whole cost and depends little on other load), and the largest output difference.
Numbers come from this run on this machine.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")  # torch's and ONNX Runtime's intra-op pools

import numpy as np  # noqa: E402
import torch  # noqa: E402

from semslam.nets.onnx_graphs import TorchNet, example_input  # noqa: E402
from semslam.nets.onnx_runtime import OnnxNet  # noqa: E402
from semslam.experiments.bench import emit_json

DATA = Path(__file__).resolve().parents[1] / "semslam" / "data"
NETS = (("stdc_person", "stdc1", (320, 240)), ("dunet_person", "dunet", (320, 240)),
        ("sdfcnn", "sdfcnn", (640, 480)), ("fpfdcnn", "fpfdcnn", (640, 480)))


def _time(run: Any, x: np.ndarray) -> tuple[float, float]:
    w0, c0 = time.perf_counter(), time.process_time()
    run(x)
    return time.perf_counter() - w0, time.process_time() - c0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=10)
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    torch.set_num_threads(1)
    rows = []
    for stem, arch, size in NETS:
        onnx_net, torch_net = OnnxNet(DATA / f"{stem}.onnx"), TorchNet(DATA / f"{stem}.pt", arch)
        x = example_input(arch, onnx_net.meta, size)
        diff = max(float(np.abs(a - b).max()) for a, b in zip(onnx_net.run(x), torch_net.run(x)))  # + warm-up
        times: dict[str, list[tuple[float, float]]] = {"onnx": [], "torch": []}
        for _ in range(args.repeats):
            times["onnx"].append(_time(onnx_net.run, x))
            times["torch"].append(_time(torch_net.run, x))
        row: dict[str, Any] = {"net": stem, "input": f"{size[0]}x{size[1]}", "max_abs_diff": diff,
                               "bytes_onnx": (DATA / f"{stem}.onnx").stat().st_size}
        for name, t in times.items():
            wall, cpu = np.array(t).T * 1e3
            row[name] = {"wall_ms_p50": float(np.median(wall)), "wall_ms_min": float(wall.min()),
                         "cpu_ms_p50": float(np.median(cpu))}
        rows.append(row)
    doc = {"torch": torch.__version__, "onnxruntime": __import__("onnxruntime").__version__,
           "repeats": args.repeats, "load_avg_1min": os.getloadavg()[0], "rows": rows}
    emit_json(doc, args.json)
    print("\n| net | input | .onnx MB | ONNX Runtime ms p50 / min / CPU | torch ms p50 / min / CPU | max diff |")
    print("|---|---|---:|---|---|---:|")
    for r in rows:
        o, t = r["onnx"], r["torch"]
        print(f"| {r['net']} | {r['input']} | {r['bytes_onnx'] / 1e6:.2f} | {o['wall_ms_p50']:.0f} / "
              f"{o['wall_ms_min']:.0f} / {o['cpu_ms_p50']:.0f} | {t['wall_ms_p50']:.0f} / {t['wall_ms_min']:.0f} / "
              f"{t['cpu_ms_p50']:.0f} | {r['max_abs_diff']:.1e} |")


if __name__ == "__main__":
    main()
