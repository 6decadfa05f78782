#!/usr/bin/env python
"""Benchmark: issue 40's monocular targets, on renders of several seeds and held-out room
layouts and on the real TUM fr2_desk frames.

    python benchmarks/mono_targets.py [--work out/mono_targets] [--jobs 2] [--json out.json]
    python benchmarks/mono_targets.py --quick       # two renders and fr2_desk only

Per sequence, through the CLI with ``--sequential`` (deterministic):

* ``rgbd``  - the ORB core with the sensor's depth (``--preset orb``), SE(3) ATE;
* ``mono``  - the plain monocular ORB core (``--preset mono``, no depth at all): the frame
  it initialised at, frames lost after that, keyframes per minute, Sim(3) ATE;
* ``sdf``   - the same core with SDF-SLAM's networks (``--preset sdf``: SDFCNN's depth as a
  checked prior, slam/orb/depth_prior.py, and its classes masking people): Sim(3) ATE and the
  Sim(3) scale (1 when the map is metric), whether the initial map was made metric.

Renders (``semslam synth``, cached under ``--work``): static_xyz and walking_xyz, 150
frames, seeds 0-2 in the office (layout 0) and seeds in the lounge and room 2 (layouts 1 and
2, which the shipped networks were not trained in). Prints a JSON document, then markdown
tables: per sequence, and the targets with median and worst over the sequences.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
FR2_DESK = SHARED / "rgbd_dataset_freiburg2_desk_first50"
FRAMES = 150

#: (name, synth sequence, seed, layout)
RENDERS = [
    ("static_s0_l0", "static_xyz", 0, 0), ("static_s1_l0", "static_xyz", 1, 0), ("static_s2_l0", "static_xyz", 2, 0),
    ("static_s3_l1", "static_xyz", 3, 1), ("static_s4_l2", "static_xyz", 4, 2),
    ("walking_s0_l0", "walking_xyz", 0, 0), ("walking_s5_l1", "walking_xyz", 5, 1), ("walking_s6_l2", "walking_xyz", 6, 2),
]
QUICK = ["static_s0_l0", "static_s3_l1"]

RUNS: dict[str, list[str]] = {
    "rgbd": ["--preset", "orb"],
    "mono": ["--preset", "mono"],
    "sdf": ["--preset", "sdf"],
}


@dataclass(frozen=True)
class Sequence:
    name: str
    path: Path
    static: bool
    real: bool = False


def _render(work: Path, name: str, synth: str, seed: int, layout: int) -> Sequence:
    path = work / "data" / name
    if not (path / "groundtruth.txt").is_file():
        cmd = [sys.executable, "-m", "semslam.cli.main", "synth", str(path), "-s", synth, "-n", str(FRAMES),
               "--seed", str(seed), "--layout", str(layout)]
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return Sequence(name, path, static=synth.startswith("static"))


def _run(seq: Sequence, kind: str, work: Path) -> dict[str, Any] | None:
    out = work / "runs" / f"{seq.name}_{kind}"
    if not (out / "stats.json").is_file():
        cmd = [sys.executable, "-m", "semslam.cli.main", "run", str(seq.path), "--out", str(out), *RUNS[kind],
               "--sequential", "--quiet", "--no-report", "--overwrite"]
        done = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        if done.returncode != 0:
            print(f"{seq.name} {kind}: failed: {done.stderr.strip()[-300:]}", file=sys.stderr)
            return None
    return json.loads((out / "stats.json").read_text())


def _row(seq: Sequence, stats: dict[str, dict[str, Any] | None]) -> dict[str, Any]:
    rgbd, mono, prior = stats["rgbd"], stats["mono"], stats["sdf"]
    row: dict[str, Any] = {"sequence": seq.name, "static": seq.static, "real": seq.real}
    if rgbd:
        row["rgbd_ate_cm"] = rgbd["ate"]["rmse"] * 100
    if mono:
        init = int(mono["uninitialized_frames"])
        minutes = mono["frames"] / 30.0 / 60.0
        row.update(mono_init_frame=init, mono_lost_after_init=int(mono["frames"] - init - mono["tracked_frames"]),
                   mono_keyframes=int(mono["keyframes"]), mono_keyframes_per_min=mono["keyframes"] / minutes,
                   mono_ate_cm=mono["ate"]["rmse"] * 100)
    if prior:
        row.update(prior_ate_cm=prior["ate"]["rmse"] * 100, prior_scale=prior.get("ate_sim3_scale"),
                   prior_metric_init=prior.get("depth_prior_metric_init"),
                   prior_keyframes=prior.get("depth_prior_keyframes"))
    if rgbd and mono:
        row["mono_vs_rgbd"] = row["mono_ate_cm"] / row["rgbd_ate_cm"]
    if mono and prior:
        row["prior_vs_mono"] = row["prior_ate_cm"] / row["mono_ate_cm"]
    return row


def _dist(values: list[float], worst: str) -> str:
    if not values:
        return "-"
    w = max(values) if worst == "max" else min(values)
    return f"{np.median(values):.2f} / {w:.2f}"


def targets(rows: list[dict[str, Any]]) -> list[tuple[str, str, str, bool]]:
    """(target, measured median / worst, bound, met)."""
    def col(key: str, sel: Any = lambda r: True) -> list[float]:
        return [float(r[key]) for r in rows if key in r and r[key] is not None and sel(r)]

    renders = lambda r: not r["real"]  # noqa: E731
    static = lambda r: r["static"] and not r["real"]  # noqa: E731
    init = col("mono_init_frame")
    ratio = col("mono_vs_rgbd", static)
    lost = col("mono_lost_after_init", static)
    kpm = col("mono_keyframes_per_min")
    prior = col("prior_vs_mono")
    scale = [abs(1 - s) for s in col("prior_scale", renders)]
    real_scale = col("prior_scale", lambda r: r["real"])
    return [
        ("plain mono initialises within 30 frames (all)", _dist(init, "max"), "<= 30", bool(init) and max(init) <= 30),
        ("plain mono Sim(3) ATE / RGB-D ATE (static renders)", _dist(ratio, "max"), "<= 2", bool(ratio) and max(ratio) <= 2),
        ("frames lost after initialisation (static renders)", _dist(lost, "max"), "0", bool(lost) and max(lost) == 0),
        ("keyframes per minute (all)", _dist(kpm, "max"), "tens, not one per frame (< 600)",
         bool(kpm) and max(kpm) < 600),
        ("sdf: ATE / plain mono ATE (all)", _dist(prior, "max"), "<= 1.05", bool(prior) and max(prior) <= 1.05),
        ("sdf: scale error |1 - s| (renders)", _dist(scale, "max"), "<= 0.05", bool(scale) and max(scale) <= 0.05),
        ("sdf: scale s on real fr2_desk", _dist(real_scale, "max"), "reported", True),
    ]


def _markdown(rows: list[dict[str, Any]], goals: list[tuple[str, str, str, bool]]) -> str:
    def f(v: Any, fmt: str = "{:.2f}") -> str:
        return "-" if v is None else (fmt.format(v) if isinstance(v, float) else str(v))

    lines = ["| sequence | RGB-D ATE (cm) | mono init frame | lost after init | keyframes/min | mono Sim(3) ATE (cm) "
             "| sdf Sim(3) ATE (cm) | sdf scale | metric init |", "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['sequence']} | {f(r.get('rgbd_ate_cm'))} | {f(r.get('mono_init_frame'))} | "
                     f"{f(r.get('mono_lost_after_init'))} | {f(r.get('mono_keyframes_per_min'), '{:.0f}')} | "
                     f"{f(r.get('mono_ate_cm'))} | {f(r.get('prior_ate_cm'))} | {f(r.get('prior_scale'), '{:.3f}')} | "
                     f"{f(r.get('prior_metric_init'))} |")
    lines += ["", "| target | median / worst | bound | met |", "|---|---|---|---|"]
    lines += [f"| {t} | {m} | {b} | {'yes' if ok else 'NO'} |" for t, m, b, ok in goals]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--work", type=Path, default=Path("out/mono_targets"), help="renders and runs (cached)")
    ap.add_argument("--jobs", type=int, default=2, help="runs at a time")
    ap.add_argument("--quick", action="store_true", help=f"only {', '.join(QUICK)} and fr2_desk")
    ap.add_argument("--json", type=Path, help="also write the JSON here")
    args = ap.parse_args(argv)
    chosen = [r for r in RENDERS if not args.quick or r[0] in QUICK]
    with ThreadPoolExecutor(args.jobs) as pool:
        seqs = list(pool.map(lambda r: _render(args.work, *r), chosen))
    if FR2_DESK.is_dir():
        seqs.append(Sequence("real_fr2_desk_50", FR2_DESK, static=True, real=True))
    else:
        print(f"{FR2_DESK} not found: real fr2_desk left out", file=sys.stderr)
    jobs = [(s, k) for s in seqs for k in RUNS]
    with ThreadPoolExecutor(args.jobs) as pool:
        results = list(pool.map(lambda job: _run(job[0], job[1], args.work), jobs))
    by_seq: dict[str, dict[str, Any]] = {}
    for (seq, kind), stats in zip(jobs, results):
        by_seq.setdefault(seq.name, {})[kind] = stats
    rows = [_row(s, by_seq[s.name]) for s in seqs]
    goals = targets(rows)
    doc = {"rows": rows, "targets": [{"target": t, "median_worst": m, "bound": b, "met": ok} for t, m, b, ok in goals]}
    text = json.dumps(doc, indent=2)
    print(text)
    if args.json:
        args.json.write_text(text + "\n")
    print()
    print(_markdown(rows, goals))
    return 0


if __name__ == "__main__":
    sys.exit(main())
