#!/usr/bin/env python
"""Benchmark: the structure of STDC-SLAM's Table 2 (feature quality and uniformity per
frame) for ORB-SLAM's extractor against the improved Qtree-ORB, plus ms per frame.

    python benchmarks/qtree_orb_table2.py [--repeats 10] [--features 1000] [--cv-threads N]
                                          [--json out.json] [--markdown out.md] [--no-blurred]

Per frame and extractor: H (kept keypoints whose FAST score >= T_H = 20), L (the others,
FAST score in [T_L, T_H) = [7, 20)), T = H + L and U, the variance of the point counts
in the 10 half-images of 5 divisions (``qtree_orb.distribution_uniformity``: left/right,
top/bottom, either side of each image diagonal, central half-area rectangle vs the rest;
larger = less uniform). The paper's reference for U (Yao et al. 2020) was not available;
this is the measure commonly used in that literature, see the function's doc.

Extractors:
- ``orb_slam``: ORB-SLAM's extractor (8 levels x 1.2, ORB-SLAM's budgets);
- ``improved``: the paper's improved Qtree-ORB (eq. 2: 6 levels at 640x480, eq. 5 budgets);
- ``improved_8lv``: the improved Algorithms 2 + 3 with ORB-SLAM's 8 levels and budgets, so
  that only detection and quadtree differ from ``orb_slam``.

Rows are given over all levels and for level 0 alone: the paper's T of ~218 per frame
equals ORB-SLAM's level-0 budget (217 of 1000), so its Table 2 most likely counts level 0.

Frames: the real 640x480 frames in ../shared/data (Kinect + TUM fr3), rendered frames of
the synthetic ``static_xyz`` sequence, and (unless ``--no-blurred``) the real frames
blurred with sigma 1.5 px, a texture-poor stress case where the low-threshold pass runs.
Timings: median wall and main-thread CPU ms over ``--repeats`` runs after a warm-up;
numbers come from this run on this machine (load average reported).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from semslam.core.types import Keypoints
from semslam.features.orb_slam2 import OrbSlamExtractor
from semslam.features.qtree_orb import QtreeOrbExtractor, distribution_uniformity, fast_quality
from semslam.experiments.bench import time_calls, timing_summary

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
T_HIGH = 20


def load_frames(n_synthetic: int, blurred: bool) -> dict[str, np.ndarray]:
    frames: dict[str, np.ndarray] = {}
    for sub in ("kinect_rgbd_5frames/color", "images_people"):
        for p in sorted((SHARED_DATA / sub).glob("*.png")):
            frames[f"{sub.split('/')[0]}/{p.stem}"] = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
    real = list(frames.items())
    from semslam.synth import SEQUENCES, Renderer

    renderer = Renderer(SEQUENCES["static_xyz"].replace(frames=max(n_synthetic, 1) * 30))
    for i in range(n_synthetic):
        frames[f"synthetic/static_xyz_{30 * i}"] = cv2.cvtColor(renderer.render(30 * i).rgb, cv2.COLOR_RGB2GRAY)
    if blurred:
        for name, gray in real:
            frames[f"blurred1.5/{name.split('/', 1)[1]}"] = cv2.GaussianBlur(gray, (0, 0), 1.5)
    return frames


def stats(kp: Keypoints, quality: np.ndarray, shape: tuple[int, int], only_level0: bool) -> dict[str, float]:
    sel = kp.octave == 0 if only_level0 else np.ones(len(kp), bool)
    q = quality[sel]
    h, w = shape
    return {"H": int(q.sum()), "L": int((~q).sum()), "T": int(sel.sum()),
            "U": round(distribution_uniformity(kp.xy[sel], w, h), 1)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=10)
    ap.add_argument("--features", type=int, default=1000)
    ap.add_argument("--synthetic", type=int, default=3, help="rendered frames (static_xyz, every 30th)")
    ap.add_argument("--no-blurred", action="store_true", help="leave out the blurred real frames")
    ap.add_argument("--cv-threads", type=int, default=None, help="cv2.setNumThreads (default: OpenCV's)")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--markdown", type=Path, default=None)
    args = ap.parse_args(argv)
    if args.cv_threads is not None:
        cv2.setNumThreads(args.cv_threads)

    frames = load_frames(args.synthetic, not args.no_blurred)
    improved = QtreeOrbExtractor(args.features)
    extractors: dict[str, Any] = {
        "orb_slam": OrbSlamExtractor(args.features),
        "improved": improved,
        "improved_8lv": QtreeOrbExtractor(args.features, levels_from_image_size=False, budget="orb_slam"),
    }
    rows: list[dict[str, Any]] = []
    for name, gray in frames.items():
        row: dict[str, Any] = {"frame": name}
        for ex_name, ex in extractors.items():
            kp = ex.extract(gray)
            quality = ex.last_quality if isinstance(ex, QtreeOrbExtractor) else fast_quality(kp, T_HIGH)
            row[ex_name] = {"all": stats(kp, quality, gray.shape, False), "level0": stats(kp, quality, gray.shape, True)}
            if isinstance(ex, QtreeOrbExtractor):
                row[ex_name]["counts"] = ex.last_counts.as_dict()
            row[ex_name]["time"] = timing_summary(*time_calls(lambda ex=ex, gray=gray: ex.extract(gray), args.repeats))
        rows.append(row)
        print(f"{name}: " + "  ".join(f"{k} H/L/T/U {row[k]['all']['H']}/{row[k]['all']['L']}/{row[k]['all']['T']}/"
                                      f"{row[k]['all']['U']:.0f} {row[k]['time']['cpu_ms_p50']:.1f} ms"
                                      for k in extractors), flush=True)

    groups = sorted({r["frame"].split("/")[0] for r in rows}, key=lambda g: [r["frame"].split("/")[0]
                                                                              for r in rows].index(g))
    averages: dict[str, Any] = {}
    for group in [*groups, "all_unblurred"]:
        sel = [r for r in rows if (r["frame"].split("/")[0] == group if group != "all_unblurred"
                                   else not r["frame"].startswith("blurred"))]
        if not sel:
            continue
        averages[group] = {ex: {scope: {k: round(float(np.mean([r[ex][scope][k] for r in sel])), 1)
                                        for k in ("H", "L", "T", "U")} for scope in ("all", "level0")}
                           | {"time": {k: round(float(np.median([r[ex]["time"][k] for r in sel])), 2)
                                       for k in ("wall_ms_p50", "cpu_ms_p50")}}
                           for ex in extractors}

    doc = {
        "benchmark": "qtree_orb_table2",
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count(), "load_avg": os.getloadavg(),
                    "cv_threads": cv2.getNumThreads(), "opencv": cv2.__version__},
        "settings": {"features": args.features, "repeats": args.repeats, "t_high": T_HIGH,
                     "improved_levels_640x480": improved.levels_for(640, 480),
                     "improved_budgets_640x480": improved.features_per_level(640, 480).tolist()},
        "frames": rows,
        "averages": averages,
    }
    text = json.dumps(doc, indent=1)
    print(text)
    if args.json:
        args.json.write_text(text + "\n")
    md = markdown(rows, averages, list(extractors))
    print(md)
    if args.markdown:
        args.markdown.write_text(md)
    return 0


def markdown(rows: list[dict[str, Any]], averages: dict[str, Any], names: list[str]) -> str:
    out = []
    for scope, title in (("all", "all levels"), ("level0", "level 0 only (the paper's T ~ 218)")):
        out.append(f"\n### H / L / T / U per frame, {title}\n")
        out.append("| frame | " + " | ".join(f"{n} H | L | T | U" for n in names) + " |")
        out.append("|---|" + "---:|" * (4 * len(names)))
        for r in rows:
            out.append(f"| {r['frame']} | " + " | ".join(
                f"{r[n][scope]['H']} | {r[n][scope]['L']} | {r[n][scope]['T']} | {r[n][scope]['U']:.0f}"
                for n in names) + " |")
        for group, avg in averages.items():
            out.append(f"| **average {group}** | " + " | ".join(
                f"{avg[n][scope]['H']:.0f} | {avg[n][scope]['L']:.0f} | {avg[n][scope]['T']:.0f} | "
                f"{avg[n][scope]['U']:.0f}" for n in names) + " |")
    out.append("\n### ms per frame (median over frames of the per-frame median; wall / main-thread CPU)\n")
    out.append("| frames | " + " | ".join(names) + " |")
    out.append("|---|" + "---:|" * len(names))
    for group, avg in averages.items():
        out.append(f"| {group} | " + " | ".join(
            f"{avg[n]['time']['wall_ms_p50']:.1f} / {avg[n]['time']['cpu_ms_p50']:.1f}" for n in names) + " |")
    return "\n".join(out) + "\n"


if __name__ == "__main__":
    raise SystemExit(main())
