"""How often a keypoint detector finds the same points again (issue 12, FPFDCNN's detector).

For pairs of frames ``--gap`` apart (the FP dataset of ``nets.fp_dataset``, clear and
motion-blurred), the share of frame i's points (with depth, moved into frame j by the true
pose, eqs. 5-7, and landing inside it) that have a point of frame j within ``--px`` pixels:
for the shipped FPFDCNN (or ``--weights``) and for OpenCV's Harris response selected the same
way (local maxima in the same NMS window, the ``--points`` strongest). Also the share for the
100 strongest FPFDCNN points. Prints JSON and a table.

    python benchmarks/keypoint_repeatability.py out/bench/data_maps/static_xyz out/bench/data_maps/walking_xyz
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from semslam.eval.feature_eval import lookup_depth, transfer_points
from semslam.features.fpfdcnn import THRESHOLD
from semslam.nets.fp_dataset import FPPair, FPSequence, harris_response
from semslam.nets.onnx_load import load_net
from semslam.nets.outputs import NMS_RADIUS, select_points

DEFAULT_WEIGHTS = Path(__file__).resolve().parents[1] / "semslam" / "data" / "fpfdcnn.onnx"


def _found_again(p: FPPair, a: np.ndarray, b: np.ndarray, px: float) -> np.ndarray:
    """Per point of ``a`` that has depth and lands inside frame j: is a point of ``b`` within ``px``?"""
    z = lookup_depth(p.depth1, a)
    xy2, z2 = transfer_points(a[z > 0], z[z > 0], p.camera, p.T_wc1, p.T_wc2)
    h, w = p.gray2.shape
    inside = (z2 > 0) & (xy2[:, 0] >= 0) & (xy2[:, 0] < w) & (xy2[:, 1] >= 0) & (xy2[:, 1] < h)
    if not len(b):
        return np.zeros(int(inside.sum()), bool)
    return cKDTree(b).query(xy2[inside])[0] <= px


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("sequences", nargs="+", type=Path)
    ap.add_argument("--weights", type=Path, default=DEFAULT_WEIGHTS, help="FPFDCNN .onnx or .pt")
    ap.add_argument("--gap", type=int, default=3)
    ap.add_argument("--every", type=int, default=10)
    ap.add_argument("--max-pairs", type=int, default=30)
    ap.add_argument("--points", type=int, default=500)
    ap.add_argument("--px", type=float, default=3.0)
    args = ap.parse_args(argv)
    net = load_net(args.weights, "fpfdcnn")

    def fpfdcnn(gray: np.ndarray) -> np.ndarray:
        prob = net.run(gray[None, None])[0][0, 0]
        return select_points(prob, args.points, THRESHOLD, NMS_RADIUS)[0]

    def harris(gray: np.ndarray) -> np.ndarray:
        return select_points(harris_response(gray), args.points, 1e-6, NMS_RADIUS)[0]

    hits: dict[str, list[np.ndarray]] = {}
    for seq_dir in args.sequences:
        seq = FPSequence(seq_dir)
        for i, j in seq.pair_indices(args.gap, every=args.every)[:args.max_pairs]:
            for blurred in (False, True):
                p = seq.pair(i, j, blurred=blurred, seed=0)
                kind = "blurred" if blurred else "clear"
                for name, detect in (("fpfdcnn", fpfdcnn), ("harris", harris)):
                    a, b = detect(p.gray1), detect(p.gray2)
                    hits.setdefault(f"{name} {kind}", []).append(_found_again(p, a, b, args.px))
                    if name == "fpfdcnn":
                        hits.setdefault(f"fpfdcnn {kind}, strongest 100", []).append(
                            _found_again(p, a[:100], b, args.px))
    rows = {k: {"found_again": float(np.concatenate(v).mean()), "points": int(sum(map(len, v)))}
            for k, v in hits.items()}
    print(json.dumps({"weights": str(args.weights), "gap": args.gap, "px": args.px, "rows": rows}, indent=2))
    print(f"\n| detector, pairs {args.gap} frames apart | found again within {args.px:g} px | points |")
    print("|---|---:|---:|")
    for k, r in rows.items():
        print(f"| {k} | {100 * r['found_again']:.1f} % | {r['points']} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
