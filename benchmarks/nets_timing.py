#!/usr/bin/env python
"""Benchmark: parameter counts and CPU inference time of the segmentation networks.

    python benchmarks/nets_timing.py [--repeats 10] [--threads 1] [--json out.json]

Models: STDC1-Seg at full width (1.0, as published) and the shipped STDC
(``semslam/data/stdc_person.pt``), DUNet at full width (64..512 channels) and the shipped
DUNet (``dunet_person.pt``). Each is timed on one frame at 640x480 and at 320x240: the
network forward only (``torch.inference_mode``, eval mode, batch 1), median (p50) and
minimum over ``--repeats`` runs after a warm-up, wall time and the process's CPU time
(with ``--threads 1`` the CPU time is the whole cost and barely depends on other load).
Inference parameters exclude STDC's training-only heads (auxiliary and detail).
Prints a JSON document, then a markdown table. Numbers come from this run on this machine.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path
from typing import Any

import torch

from semslam.experiments.bench import time_calls, timing_summary
from semslam.nets.models import build_model, load_checkpoint

DATA = Path(__file__).resolve().parents[1] / "semslam" / "data"
SIZES = ((640, 480), (320, 240))


def timed(model: torch.nn.Module, w: int, h: int, repeats: int) -> dict[str, float]:
    x = torch.randn(1, 3, h, w)
    with torch.inference_mode():  # warm-up: allocator, oneDNN kernels
        return timing_summary(*time_calls(lambda: model(x), repeats, cpu_clock=time.process_time))


def models() -> list[tuple[str, torch.nn.Module, dict[str, Any]]]:
    out: list[tuple[str, torch.nn.Module, dict[str, Any]]] = [
        ("STDC1-Seg full (width 1.0)", build_model("stdc1", 2, 1.0).eval(), {"width": 1.0, "file": None}),
    ]
    for arch, fname, label, full in (("stdc1", "stdc_person.pt", "STDC shipped", None),
                                     ("dunet", None, "DUNet full (width 1.0)", 1.0),
                                     ("dunet", "dunet_person.pt", "DUNet shipped", None)):
        if full is not None:
            out.append((label, build_model(arch, 2, full).eval(), {"width": full, "file": None}))
            continue
        path = DATA / str(fname)
        if path.is_file():
            model, meta = load_checkpoint(path)
            out.append((f"{label} (width {meta['width']})", model,
                        {"width": meta["width"], "file": path.name, "file_bytes": path.stat().st_size,
                         "trained_input": meta["input_size"]}))
    # Keep the table in the documented order: STDC full, STDC shipped, DUNet full, DUNet shipped.
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=10)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--json", type=Path)
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    rows = []
    for name, model, info in models():
        params = int(model.inference_parameters())  # type: ignore[operator]
        row: dict[str, Any] = {"model": name, "inference_parameters": params, **info, "timing": {}}
        for w, h in SIZES:
            # Full-width DUNet at 640x480: one run is enough to know it is far from real time.
            reps = 2 if "DUNet full" in name and w == 640 else a.repeats
            row["timing"][f"{w}x{h}"] = timed(model, w, h, reps)
            print(f"{name} {w}x{h}: {row['timing'][f'{w}x{h}']['wall_ms_p50']:.1f} ms", file=sys.stderr, flush=True)
        rows.append(row)
    doc = {
        "benchmark": "nets_timing",
        "torch": torch.__version__,
        "threads": a.threads,
        "machine": {"cpu_count": os.cpu_count(), "platform": platform.platform(),
                    "processor": platform.processor(), "load_avg": os.getloadavg()},
        "rows": rows,
    }
    text = json.dumps(doc, indent=2)
    print(text)
    if a.json:
        a.json.write_text(text + "\n")
    print("\n| model | inference params | 640x480 ms (p50 wall / cpu) | 320x240 ms (p50 wall / cpu) |")
    print("|---|---:|---:|---:|")
    for r in rows:
        t6, t3 = r["timing"]["640x480"], r["timing"]["320x240"]
        print(f"| {r['model']} | {r['inference_parameters']:,} | {t6['wall_ms_p50']:.0f} / {t6['cpu_ms_p50']:.0f} "
              f"| {t3['wall_ms_p50']:.0f} / {t3['cpu_ms_p50']:.0f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
