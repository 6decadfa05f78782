#!/usr/bin/env python
"""Benchmark: place recognition with the shipped ORB vocabulary.

    python benchmarks/place_recognition.py [--vocab FILE] [--keyframes 500] [--json FILE]

Measures, on rendered frames (``loop`` and ``walking_xyz``, seeds not used in training):
  - transform time per 1000 descriptors (bag of words + feature vector; tree descent alone),
  - keyframe-database add / query / ORB-SLAM2 loop-candidate time with N keyframes indexed,
  - retrieval on the ``loop`` sequence: every 6th frame queries all frames more than 1 s
    away in time; a hit is a frame whose camera is within 25 cm and 15 deg of the query's.
    Precision@1 and @3 over the queries that have such a frame.
Prints a JSON document and a markdown table; nothing is hard-coded.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

from semslam.place import KeyframeDatabase, Vocabulary, detect_loop_candidates, load_default_vocabulary
from semslam.place.train_vocab import make_orb, orb_descriptors, to_gray
from semslam.synth import SEQUENCES, Renderer

GAP_FRAMES = 30  # 1 s at 30 fps: closer frames are temporal neighbours, not loop closures
HIT_DIST_M = 0.25
HIT_ANGLE_DEG = 15.0


def _median_ms(fn, n: int) -> float:  # type: ignore[no-untyped-def]
    fn()
    times = []
    for _ in range(n):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times) * 1000)


def _render(name: str, indices: np.ndarray, orb) -> tuple[list[np.ndarray], np.ndarray]:  # type: ignore[no-untyped-def]
    r = Renderer(SEQUENCES[name])
    desc = [orb_descriptors(to_gray(r.render(int(i)).rgb), orb) for i in indices]
    return desc, r.poses[indices]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--vocab", type=Path, default=None, help="vocabulary .npz (default: the shipped one)")
    ap.add_argument("--keyframes", type=int, default=500, help="keyframes in the database for query timing")
    ap.add_argument("--json", type=Path, default=None, help="also write the JSON here")
    args = ap.parse_args(argv)

    vocab = Vocabulary.load(args.vocab) if args.vocab else load_default_vocabulary()
    orb = make_orb(1000)
    t0 = time.perf_counter()
    loop_n = SEQUENCES["loop"].frames
    loop_idx = np.arange(0, loop_n, 2)
    loop_desc, loop_poses = _render("loop", loop_idx, orb)
    extra = max(args.keyframes - len(loop_idx), 0)
    walk_idx = np.linspace(0, SEQUENCES["walking_xyz"].frames - 1, extra).round().astype(int) if extra else np.zeros(0, int)
    walk_desc, _ = _render("walking_xyz", walk_idx, orb) if extra else ([], None)
    render_s = time.perf_counter() - t0
    print(f"rendered {len(loop_desc) + len(walk_desc)} frames in {render_s:.1f} s", file=sys.stderr)

    # Transform speed on exactly 1000 descriptors.
    d1000 = next(d for d in loop_desc if len(d) >= 1000)[:1000]
    transform_ms = _median_ms(lambda: vocab.transform(d1000), 100)
    descent_ms = _median_ms(lambda: vocab.leaf_nodes(d1000), 100)
    bow_ms = _median_ms(lambda: vocab.bow(d1000), 100)

    all_desc = (loop_desc + walk_desc)[: args.keyframes]
    bows = [vocab.bow(d) for d in all_desc]
    db = KeyframeDatabase()
    t = time.perf_counter()
    for i, b in enumerate(bows):
        db.add(i, b)
    add_ms = (time.perf_counter() - t) / len(bows) * 1000
    queries = bows[:: max(len(bows) // 50, 1)]
    qi = iter(range(10**9))
    query_ms = _median_ms(lambda: db.query(queries[next(qi) % len(queries)], max_results=10), 50)

    def covisibles(kf: int, n: int) -> list[int]:
        return [j for j in range(kf - n // 2, kf + n // 2 + 1) if j != kf and 0 <= j < len(bows)][:n]

    def loop_query() -> None:
        i = next(qi) % len(bows)
        detect_loop_candidates(db, i, bows[i], covisibles(i, 30), 0.05, covisibles)

    loop_cand_ms = _median_ms(loop_query, 50)
    t = time.perf_counter()
    for i in range(0, len(bows), 10):
        db.erase(i)
    erase_ms = (time.perf_counter() - t) / len(range(0, len(bows), 10)) * 1000

    # Retrieval on the loop sequence.
    sel = np.arange(0, len(loop_idx), 3)  # every 6th frame
    frames = loop_idx[sel]
    lb = [bows[i] for i in sel]
    centres, fwd = loop_poses[sel, :3, 3], loop_poses[sel, :3, 2]
    rdb = KeyframeDatabase()
    for j, b in enumerate(lb):
        rdb.add(j, b)
    hits1 = hits3 = n_q = 0
    for i in range(len(sel)):
        near = {j for j in range(len(sel)) if abs(int(frames[j]) - int(frames[i])) <= GAP_FRAMES}
        good = {
            j for j in range(len(sel))
            if j not in near
            and np.linalg.norm(centres[j] - centres[i]) < HIT_DIST_M
            and fwd[i] @ fwd[j] > np.cos(np.deg2rad(HIT_ANGLE_DEG))
        }
        if not good:
            continue
        ranked = [k for k, _ in rdb.query(lb[i], exclude=near, max_results=3)]
        n_q += 1
        hits1 += bool(ranked) and ranked[0] in good
        hits3 += bool(good & set(ranked))

    vfile = args.vocab or Path(__file__).resolve().parents[1] / "semslam" / "data" / "orb_vocab.npz"
    doc = {
        "machine": {"python": platform.python_version(), "cpu": platform.processor() or platform.machine()},
        "vocabulary": {
            "k": vocab.k, "levels": vocab.levels, "words": vocab.n_words, "nodes": vocab.n_nodes,
            "file_bytes": vfile.stat().st_size if vfile.exists() else None,
            "trained_on_images": vocab.metadata.get("n_images"),
        },
        "transform_ms_per_1000": transform_ms,
        "descent_ms_per_1000": descent_ms,
        "bow_ms_per_1000": bow_ms,
        "database": {
            "keyframes": len(bows),
            "mean_words_per_keyframe": float(np.mean([len(b) for b in bows])),
            "add_ms": add_ms, "query_ms": query_ms, "loop_candidates_ms": loop_cand_ms, "erase_ms": erase_ms,
        },
        "loop_retrieval": {
            "queries": n_q, "precision_at_1": hits1 / max(n_q, 1), "hit_at_3": hits3 / max(n_q, 1),
            "frames": len(sel), "gap_frames": GAP_FRAMES, "hit_dist_m": HIT_DIST_M, "hit_angle_deg": HIT_ANGLE_DEG,
        },
        "render_s": render_s,
    }
    text = json.dumps(doc, indent=2)
    print(text)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(text)
    d, r = doc["database"], doc["loop_retrieval"]
    print()
    print("| words | transform ms / 1000 desc | descent ms | keyframes | query ms | loop candidates ms | add ms | erase ms | loop P@1 | loop hit@3 |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    print(f"| {vocab.n_words} (k={vocab.k}, L={vocab.levels}) | {transform_ms:.2f} | {descent_ms:.2f} | {d['keyframes']} | "
          f"{d['query_ms']:.2f} | {d['loop_candidates_ms']:.2f} | {d['add_ms']:.2f} | {d['erase_ms']:.2f} | "
          f"{r['precision_at_1']:.2f} ({r['queries']} q) | {r['hit_at_3']:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
