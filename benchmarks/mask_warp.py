#!/usr/bin/env python
"""How well a skipped frame's mask is recovered from the last segmented one (dynamics/warp.py).

    python benchmarks/mask_warp.py SEQ_DIR [SEQ_DIR ...] [--gap 1] [--json out.json]

On rendered sequences (exact ground-truth poses and person labels, semantic/): the person
mask of frame j is carried to frame k = j + gap, either as it is ("none") or warped with
j's depth (``warp_mask``: a plane at the mask's median depth) and the constant-velocity
prediction T_cw(k) = v^gap T_cw(j), v = T_cw(j) T_cw(j-1)^-1 - what tracking's motion
model gives - and grown by a margin per frame of the gap. Against the true mask of k:
recall (share of k's person pixels covered: keypoints there would be on a mover), its 5th
percentile over frames, and the excess (static pixels masked, % of the image: keypoints
lost for nothing). Ground-truth masks isolate the warp from the segmenter.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from semslam.dynamics.warp import relative_pose, warp_mask
from semslam.geometry.se3 import invert
from semslam.io.sequence import open_sequence
from semslam.io.trajectory import read_trajectory
from semslam.semantics.ground_truth import read_label_image, semantic_path

PERSON = 15
METHODS = [("none", m) for m in (0, 4, 8, 12)] + [("pose", m) for m in (0, 4, 8, 12)]


def measure(seq_dir: Path, gap: int, step: int) -> list[dict[str, Any]]:
    seq = open_sequence(seq_dir)
    gt = read_trajectory(seq_dir / "groundtruth.txt")
    T_cw = [invert(gt.poses[int(np.argmin(np.abs(gt.timestamps - t)))]) for t in seq.timestamps]
    rows: dict[tuple[str, int], dict[str, list[float]]] = {m: {"recall": [], "excess": [], "ms": []} for m in METHODS}
    for j in range(1, len(seq) - gap, step):
        src, dst = seq.load(j), seq.load(j + gap)
        m_src = read_label_image(semantic_path(Path(src.rgb_path))) == PERSON
        m_dst = read_label_image(semantic_path(Path(dst.rgb_path))) == PERSON
        if not m_dst.any() or not m_src.any():
            continue
        v = T_cw[j] @ invert(T_cw[j - 1])
        pred = np.linalg.matrix_power(v, gap) @ T_cw[j]
        for method, margin in METHODS:
            T_kj = relative_pose(T_cw[j], pred) if method == "pose" else None
            t0 = time.perf_counter()
            w = warp_mask(m_src, src.depth, seq.camera, T_kj, margin * gap)
            r = rows[(method, margin)]
            r["ms"].append((time.perf_counter() - t0) * 1e3)
            r["recall"].append(float((w & m_dst).sum() / m_dst.sum()))
            r["excess"].append(float((w & ~m_dst).mean() * 100))
    return [{"sequence": seq_dir.name, "gap": gap, "warp": k[0], "margin_px_per_frame": k[1], "pairs": len(r["recall"]),
             "recall_mean": float(np.mean(r["recall"])), "recall_p5": float(np.percentile(r["recall"], 5)),
             "excess_pct_mean": float(np.mean(r["excess"])), "ms_median": float(np.median(r["ms"]))}
            for k, r in rows.items()]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sequences", nargs="+", type=Path)
    ap.add_argument("--gap", type=int, default=1, help="frames between the segmented frame and the warped one")
    ap.add_argument("--step", type=int, default=3, help="use every step-th source frame")
    ap.add_argument("--json", type=Path)
    a = ap.parse_args()
    rows = [r for s in a.sequences for r in measure(s, a.gap, a.step)]
    if a.json:
        a.json.write_text(json.dumps(rows, indent=2))
    print("| sequence | gap | warp | margin px/frame | pairs | recall mean | recall p5 | excess % | ms |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['sequence']} | {r['gap']} | {r['warp']} | {r['margin_px_per_frame']} | {r['pairs']} | {r['recall_mean']:.3f} "
              f"| {r['recall_p5']:.3f} | {r['excess_pct_mean']:.2f} | {r['ms_median']:.1f} |")


if __name__ == "__main__":
    main()
