#!/usr/bin/env python
"""Benchmark: SDFCNN's depth on real Kinect frames (issue 12, item 7), against the sensor's depth.

    python benchmarks/sdfcnn_real_depth.py [--weights A.onnx --weights B.pt ...] [--renders DIR ...]
        [--json out.json]

The shipped network was trained on the project's renders only; these are the real frames
available here: the first 50 frames of TUM freiburg2_desk (`../shared/data/
rgbd_dataset_freiburg2_desk_first50`) and 5 Kinect v1 frames (`kinect_rgbd_5frames`, depth in
mm). Table 9's measures (RMS, REL, delta < 1.25^k) on the pixels with sensor depth, three ways:
SDFCNN's metric depth as predicted; the same scaled per frame by median(truth) / median(pred)
(the shape of the depth without its scale, what a Sim(3)-aligned monocular run uses); and a
baseline that knows each frame's median true depth and predicts it everywhere.
``--weights`` (repeatable) compares several networks (default: the shipped one), e.g. the
weights of the photo-textured recipe (``semslam train reproduce sdfcnn_photo``) against the
shipped ones; ``--renders`` adds renders (every 3rd frame) to the same table, e.g. the held-out
rooms (``semslam synth DIR --sequence static_xyz -n 60 --layout 1|2|3``), so that a network
better on real frames can be seen not to be worse where it was measured before. Prints a JSON
document, then a markdown table.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from semslam.eval.dense_metrics import DepthErrors
from semslam.io.sequence import TumRgbdSequence
from semslam.semantics.sdfcnn_backend import SdfcnnPredictor

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"


def _tum_frames(root: Path, every: int = 1) -> list[tuple[np.ndarray, np.ndarray]]:
    seq = TumRgbdSequence(root)
    out = []
    for k in range(0, len(seq), every):
        f = seq.load(k)
        assert f.depth is not None
        out.append((f.rgb, f.depth))
    return out


def _kinect_frames(root: Path) -> list[tuple[np.ndarray, np.ndarray]]:
    out = []
    for color in sorted((root / "color").glob("*.png")):
        bgr = cv2.imread(str(color), cv2.IMREAD_COLOR)
        depth = cv2.imread(str(root / "depth" / f"{color.stem}.pgm"), cv2.IMREAD_UNCHANGED)
        if bgr is None or depth is None:
            raise SystemExit(f"{color}: cannot read the frame or its depth")
        out.append((cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), depth.astype(np.float32) / 1000.0))
    return out


def evaluate(frames: list[tuple[np.ndarray, np.ndarray]], predictor: SdfcnnPredictor) -> dict[str, Any]:
    raw, scaled, base = DepthErrors(), DepthErrors(), DepthErrors()
    scales = []
    for rgb, truth in frames:
        pred = predictor.predict(rgb).depth()
        valid = truth > 0
        s = float(np.median(truth[valid]) / np.median(pred[valid]))
        scales.append(s)
        raw.add(pred, truth)
        scaled.add(pred * s, truth)
        base.add(np.full_like(truth, float(np.median(truth[valid]))), truth)
    return {"frames": len(frames), "metric": raw.result(), "median_scaled": scaled.result(),
            "median_depth_baseline": base.result(), "median_scale": float(np.median(scales))}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--weights", type=Path, action="append", default=[],
                    help="SDFCNN weights (.onnx or .pt), repeatable (default: the shipped ones)")
    ap.add_argument("--renders", type=Path, nargs="*", default=[],
                    help="TUM-layout renders to add (every 3rd frame), e.g. the held-out rooms")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    import torch

    torch.set_num_threads(1)
    sets = {"fr2_desk (first 50, real TUM)": _tum_frames(SHARED / "rgbd_dataset_freiburg2_desk_first50"),
            "kinect_rgbd_5frames": _kinect_frames(SHARED / "kinect_rgbd_5frames"),
            **{f"render {r.name}": _tum_frames(r, every=3) for r in args.renders}}
    weights = args.weights or [None]
    doc = {}
    for w in weights:
        predictor = SdfcnnPredictor(w)
        doc[str(w or "shipped")] = {name: evaluate(frames, predictor) for name, frames in sets.items()}
    print(json.dumps(doc, indent=1))
    if args.json:
        args.json.write_text(json.dumps(doc, indent=1))
    print("\n| weights | frames | depth | RMS m | REL | d<1.25 | d<1.25^2 | d<1.25^3 |\n|---|---|---|---|---|---|---|---|")
    for wname, per_set in doc.items():
        for name, res in per_set.items():
            for kind in ("metric", "median_scaled", "median_depth_baseline"):
                r = res[kind]
                print(f"| {Path(wname).name} | {name} | {kind} | {r['rms']:.3f} | {r['rel']:.3f} | {r['delta1']:.3f} "
                      f"| {r['delta2']:.3f} | {r['delta3']:.3f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
