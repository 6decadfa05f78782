#!/usr/bin/env python
"""Benchmark: issue 41's stereo targets, on stereo renders of several seeds and held-out room
layouts (a rectified pair, baseline 0.11 m, 640x480).

    python benchmarks/stereo_targets.py [--work out/stereo_targets] [--jobs 2] [--json out.json]
    python benchmarks/stereo_targets.py --quick            # two renders, 100 frames
    python benchmarks/stereo_targets.py --redo-speed       # repeat only the speed runs (cached accuracy)

Accuracy: per render, through the CLI with ``--sequential`` (deterministic), SE(3) ATE of
``orb`` and ``default``, each three ways:

* ``stereo`` - ``--sensor stereo``: the pair (ORB-SLAM2 stereo matching for keypoint depths, the
  dense SGBM depth for the dynamic front end);
* ``rgbd``   - the same preset on the render's ``depth/`` (Kinect-like noise and holes), the
  preset's own virtual ``bf``;
* ``bf``     - "render depth, stereo bf": ``depth/`` again, but with the pair's
  ``slam.bf = fx * 0.11`` (camera.yaml), so the close/far split and the BA weighting are the
  stereo run's: what the stereo matcher costs against (nearly) exact depth.

Accuracy runs build no maps (``--map none``: the maps are made from the poses, they do not
change them). Renders (``semslam synth``, cached under ``--work`` and reused while their
``sequence.json`` matches): static_xyz and walking_xyz, paired by seed and layout (layout 0 the
office, 1 and 2 held out).

Speed: one threaded run (not ``--sequential``, preset maps on) per preset and sensor on the
first renders, one at a time so they do not compete; per-frame time (``ms_per_frame.median``),
wall fps including image decoding (``fps``) and ``tracking_fps``; the load average before and
after each run is kept (``os.getloadavg``), and a warning printed when it was above 2.5.

Prints a JSON document, then markdown tables: per render, speed, and the targets with median
and worst over the renders.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

BASELINE = 0.11
FRAMES = 200
QUICK_FRAMES = 100
#: (synth sequence, seed, layout); static and walking paired by seed + layout.
PAIRS = [(0, 0), (1, 1), (2, 2), (3, 0)]
RENDERS = [(seq, seed, layout) for seed, layout in PAIRS for seq in ("static_xyz", "walking_xyz")]
QUICK = [("static_xyz", 0, 0), ("walking_xyz", 0, 0)]  # one pair
PRESETS = ("orb", "default")
MODES = ("stereo", "rgbd", "bf")
SPEED_RENDERS = 3  # static and walking of seed 0 (office), static of seed 1 (lounge)
LOAD_LIMIT = 2.5
#: External reference (issue 41): ORB-SLAM3 on a held-out path, stereo 7.0 cm, RGB-D 1.1 cm.
ORBSLAM3_STEREO_CM, ORBSLAM3_RGBD_CM = 7.0, 1.1


@dataclass(frozen=True)
class Render:
    name: str
    path: Path
    static: bool
    pair: str  # "s{seed}_l{layout}": pairs a static render with its walking one

    def bf(self) -> float:
        """camera.yaml's Camera1.fx times the baseline: the stereo runs' ``slam.bf``."""
        for line in (self.path / "camera.yaml").read_text().splitlines():
            if line.startswith("Camera1.fx:"):
                return float(line.split(":", 1)[1]) * BASELINE
        raise SystemExit(f"{self.path / 'camera.yaml'}: no Camera1.fx")


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "semslam.cli.main", *args]


def _render(work: Path, seq: str, seed: int, layout: int, frames: int) -> Render:
    """The render, made now unless ``sequence.json`` shows the same one (then its runs are kept)."""
    pair = f"s{seed}_l{layout}"
    name = f"{seq.split('_')[0]}_{pair}_n{frames}"
    path = work / "data" / name
    want = {"seed": seed, "layout": layout, "frames": frames, "stereo_baseline": BASELINE, "width": 640, "height": 480}
    meta = path / "sequence.json"
    have = json.loads(meta.read_text()).get("config", {}) if meta.is_file() else {}
    if any(have.get(k) != v for k, v in want.items()) or not (path / "groundtruth.txt").is_file():
        shutil.rmtree(path, ignore_errors=True)
        for old in (work / "runs").glob(f"{name}_*"):
            shutil.rmtree(old, ignore_errors=True)  # runs of an earlier, different render
        cmd = _cli("synth", str(path), "-s", seq, "-n", str(frames), "--seed", str(seed), "--layout", str(layout),
                   "--stereo-baseline", str(BASELINE), "-q")
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return Render(name, path, static=seq.startswith("static"), pair=pair)


def _flags(render: Render, preset: str, mode: str) -> list[str]:
    flags = ["--preset", preset]
    if mode == "stereo":
        flags += ["--sensor", "stereo"]
    elif mode == "bf":
        flags += ["--set", f"slam.bf={render.bf():.6f}"]
    return flags


def _run(render: Render, preset: str, mode: str, work: Path, speed: bool = False,
         redo: bool = False) -> dict[str, Any] | None:
    """stats.json of one run (cached in ``work/runs``); None (and a line on stderr) if it failed."""
    out = work / ("speed" if speed else "runs") / f"{render.name}_{preset}_{mode}"
    if redo or not (out / "stats.json").is_file():
        extra = [] if speed else ["--sequential", "--map", "none"]
        cmd = _cli("run", str(render.path), "--out", str(out), *_flags(render, preset, mode), *extra,
                   "--quiet", "--no-report", "--overwrite")
        done = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        if done.returncode != 0:
            print(f"{render.name} {preset} {mode}: failed: {done.stderr.strip()[-400:]}", file=sys.stderr)
            return None
    return json.loads((out / "stats.json").read_text())


def _row(render: Render, stats: dict[tuple[str, str], dict[str, Any] | None]) -> dict[str, Any]:
    row: dict[str, Any] = {"sequence": render.name, "static": render.static, "pair": render.pair,
                           "bf": round(render.bf(), 3)}
    for (preset, mode), s in stats.items():
        if s is None:
            continue
        row[f"{preset}_{mode}_ate_cm"] = s["ate"]["rmse"] * 100
        row[f"{preset}_{mode}_tracked"] = int(s["tracked_frames"])
    for preset in PRESETS:
        st, rg, bf = (row.get(f"{preset}_{m}_ate_cm") for m in MODES)
        if st is not None and rg:
            row[f"{preset}_stereo_vs_rgbd"] = st / rg
        if st is not None and bf:
            row[f"{preset}_stereo_vs_bf"] = st / bf
    row["frames"] = max((int(s["frames"]) for s in stats.values() if s), default=0)
    return row


def _speed(renders: list[Render], work: Path, redo: bool) -> list[dict[str, Any]]:
    """Threaded runs, one at a time, with the load average around each."""
    rows = []
    for render in renders:
        for preset in PRESETS:
            for mode in ("stereo", "rgbd"):
                before = os.getloadavg()[0]
                s = _run(render, preset, mode, work, speed=True, redo=redo)
                after = os.getloadavg()[0]
                if s is None:
                    continue
                rows.append({"sequence": render.name, "preset": preset, "mode": mode,
                             "ms_per_frame_median": s["ms_per_frame"]["median"], "fps": s["fps"],
                             "tracking_fps": s["tracking_fps"], "ate_cm": s["ate"]["rmse"] * 100,
                             "tracked": int(s["tracked_frames"]), "frames": int(s["frames"]),
                             "load_before": round(before, 2), "load_after": round(after, 2)})
    return rows


def _dist(values: list[float], worst: str = "max") -> str:
    if not values:
        return "-"
    w = max(values) if worst == "max" else min(values)
    return f"{np.median(values):.2f} / {w:.2f}"


def targets(rows: list[dict[str, Any]], speed: list[dict[str, Any]]) -> list[tuple[str, str, str, str]]:
    """(target, measured median / worst, bound, PASS / FAIL / reported / n/a without data)."""
    def col(key: str, sel: Callable[[dict[str, Any]], bool] = lambda r: True) -> list[float]:
        return [float(r[key]) for r in rows if r.get(key) is not None and sel(r)]

    def verdict(values: list[float], ok: bool) -> str:
        return "n/a" if not values else ("PASS" if ok else "FAIL")

    static = lambda r: r["static"]  # noqa: E731
    walking = lambda r: not r["static"]  # noqa: E731
    by_pair = {(r["pair"], r["static"]): r for r in rows}
    walk_ratio: dict[str, list[float]] = {p: [] for p in PRESETS}
    for (pair, is_static), r in by_pair.items():
        s = by_pair.get((pair, True))
        if is_static or s is None:
            continue
        for p in PRESETS:
            w_ate, s_ate = r.get(f"{p}_stereo_ate_cm"), s.get(f"{p}_stereo_ate_cm")
            if w_ate is not None and s_ate:
                walk_ratio[p].append(w_ate / s_ate)
    ref = ORBSLAM3_STEREO_CM / ORBSLAM3_RGBD_CM
    out: list[tuple[str, str, str, str]] = []
    for p in PRESETS:
        ratio = col(f"{p}_stereo_vs_rgbd", static)
        out.append((f"`{p}` stereo ATE / RGB-D ATE (static)", _dist(ratio), f"reported (ORB-SLAM3: {ref:.1f}x)",
                    "reported"))
    for p in PRESETS:
        ratio = col(f"{p}_stereo_vs_rgbd", walking)
        out.append((f"`{p}` stereo ATE / RGB-D ATE (walking)", _dist(ratio), "reported", "reported"))
    for p in PRESETS:
        out.append((f"`{p}` stereo ATE / render depth, stereo bf ATE (all)", _dist(col(f"{p}_stereo_vs_bf")),
                    "reported (the matcher's cost)", "reported"))
    bound = 0.7 * ORBSLAM3_STEREO_CM
    for p in PRESETS:
        ates = col(f"{p}_stereo_ate_cm", static)
        out.append((f"`{p}` stereo ATE cm (static; ORB-SLAM3's path is another one, indicative)", _dist(ates),
                    f"<= 0.7 x {ORBSLAM3_STEREO_CM} = {bound:.1f}", verdict(ates, bool(ates) and max(ates) <= bound)))
    wd = walk_ratio["default"]
    out.append(("`default` stereo: walking ATE / its static ATE (median over pairs)", _dist(wd), "<= 1.5",
                verdict(wd, bool(wd) and float(np.median(wd)) <= 1.5)))
    wo = walk_ratio["orb"]
    out.append(("`orb` stereo: walking ATE / its static ATE (drift with people)", _dist(wo), "reported", "reported"))
    out.append(("`orb` stereo ATE cm (walking)", _dist(col("orb_stereo_ate_cm", walking)), "reported", "reported"))
    for p in PRESETS:
        by_seq: dict[str, dict[str, float]] = {}
        for s in speed:
            if s["preset"] == p:
                by_seq.setdefault(s["sequence"], {})[s["mode"]] = s["ms_per_frame_median"]
        ratio = [v["stereo"] / v["rgbd"] for v in by_seq.values() if "stereo" in v and v.get("rgbd")]
        out.append((f"`{p}` ms/frame (median) stereo / RGB-D (threaded)", _dist(ratio), "<= 1.3",
                    verdict(ratio, bool(ratio) and max(ratio) <= 1.3)))
    fps = [s["fps"] for s in speed if s["preset"] == "default" and s["mode"] == "stereo"]
    out.append(("`default` stereo wall fps incl. decoding (threaded)", _dist(fps, "min"), ">= 30",
                verdict(fps, bool(fps) and min(fps) >= 30)))
    tfps = [s["tracking_fps"] for s in speed if s["preset"] == "default" and s["mode"] == "stereo"]
    out.append(("`default` stereo tracking fps (threaded)", _dist(tfps, "min"), "reported", "reported"))
    return out


def _markdown(rows: list[dict[str, Any]], speed: list[dict[str, Any]],
              goals: list[tuple[str, str, str, str]]) -> str:
    def f(v: Any, fmt: str = "{:.2f}") -> str:
        return "-" if v is None else (fmt.format(v) if isinstance(v, float) else str(v))

    head = " | ".join(f"`{p}` {m}" for p in PRESETS for m in ("stereo", "RGB-D", "render depth, stereo bf"))
    lines = ["ATE (cm, SE(3), `--sequential`); tracked frames in brackets where not all", "",
             f"| sequence | {head} | `orb` st/RGB-D | `default` st/RGB-D |", "|---" * 9 + "|"]
    for r in rows:
        cells = []
        for p in PRESETS:
            for m in MODES:
                ate, tracked = r.get(f"{p}_{m}_ate_cm"), r.get(f"{p}_{m}_tracked")
                cell = f(ate)
                if tracked is not None and tracked < r["frames"]:
                    cell += f" ({tracked})"
                cells.append(cell)
        lines.append(f"| {r['sequence']} | {' | '.join(cells)} | {f(r.get('orb_stereo_vs_rgbd'))} | "
                     f"{f(r.get('default_stereo_vs_rgbd'))} |")
    lines += ["", "Speed (threaded, one run at a time)", "",
              "| sequence | preset | input | ms/frame (median) | wall fps | tracking fps | ATE (cm) | load before / after |",
              "|---|---|---|---|---|---|---|---|"]
    for s in speed:
        lines.append(f"| {s['sequence']} | `{s['preset']}` | {'stereo' if s['mode'] == 'stereo' else 'RGB-D'} | "
                     f"{s['ms_per_frame_median']:.1f} | {s['fps']:.1f} | {s['tracking_fps']:.1f} | {s['ate_cm']:.2f} | "
                     f"{s['load_before']:.2f} / {s['load_after']:.2f} |")
    lines += ["", "| target | median / worst | bound | result |", "|---|---|---|---|"]
    lines += [f"| {t} | {m} | {b} | {ok} |" for t, m, b, ok in goals]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--work", type=Path, default=Path("out/stereo_targets"), help="renders and runs (cached)")
    ap.add_argument("--jobs", type=int, default=2, help="renders / accuracy runs at a time (speed runs: one)")
    ap.add_argument("--quick", action="store_true", help=f"two renders of {QUICK_FRAMES} frames, one speed render")
    ap.add_argument("--frames", type=int, help=f"frames per render (default {FRAMES}, --quick {QUICK_FRAMES})")
    ap.add_argument("--json", type=Path, help="also write the JSON here")
    ap.add_argument("--no-speed", action="store_true", help="accuracy only")
    ap.add_argument("--redo-speed", action="store_true", help="repeat the speed runs (e.g. on a quieter machine)")
    args = ap.parse_args(argv)
    frames = args.frames or (QUICK_FRAMES if args.quick else FRAMES)
    chosen = QUICK if args.quick else RENDERS
    with ThreadPoolExecutor(args.jobs) as pool:
        renders = list(pool.map(lambda r: _render(args.work, *r, frames), chosen))
    jobs = [(r, p, m) for r in renders for p in PRESETS for m in MODES]
    with ThreadPoolExecutor(args.jobs) as pool:
        results = list(pool.map(lambda j: _run(j[0], j[1], j[2], args.work), jobs))
    by_render: dict[str, dict[tuple[str, str], dict[str, Any] | None]] = {}
    for (render, preset, mode), stats in zip(jobs, results):
        by_render.setdefault(render.name, {})[(preset, mode)] = stats
    rows = [_row(r, by_render[r.name]) for r in renders]
    speed: list[dict[str, Any]] = []
    load = os.getloadavg()
    if not args.no_speed:
        speed = _speed(renders[:1 if args.quick else SPEED_RENDERS], args.work, args.redo_speed)
        busy = [s for s in speed if max(s["load_before"], s["load_after"]) > LOAD_LIMIT]
        if busy:
            print(f"warning: 1-min load average above {LOAD_LIMIT} around {len(busy)} of {len(speed)} speed runs "
                  "(it includes this benchmark's own previous run); if other jobs competed, repeat with "
                  "--redo-speed when the machine is quieter", file=sys.stderr)
    goals = targets(rows, speed)
    doc = {"frames": frames, "baseline_m": BASELINE, "cpus": os.cpu_count(),
           "load_average_before_speed": [round(v, 2) for v in load], "rows": rows, "speed": speed,
           "targets": [{"target": t, "median_worst": m, "bound": b, "result": ok} for t, m, b, ok in goals]}
    text = json.dumps(doc, indent=2)
    print(text)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(text + "\n")
    print()
    print(_markdown(rows, speed, goals))
    return 0


if __name__ == "__main__":
    sys.exit(main())
