#!/usr/bin/env python
"""Benchmark: issue 42's visual-inertial targets, on EuRoC-layout renders with a simulated IMU
(200 Hz, EuRoC's ADIS16448 noise, seeded biases; ``semslam synth --imu --depth
--stereo-baseline 0.11``) over several seeds and the held-out room layouts.

    python benchmarks/inertial_targets.py [--work out/inertial_targets] [--jobs 2] [--json out.json]
    python benchmarks/inertial_targets.py --quick          # one seed
    python benchmarks/inertial_targets.py --no-speed       # accuracy only
    python benchmarks/inertial_targets.py --work out/inertial_val --pairs 31:1,32:2,33:1 \
        --kinds hard,hard_twin --no-speed                  # held-out seeds

Renders per (seed, layout): ``static`` (static_xyz), ``walking`` (walking_xyz, two people),
``blackout`` (blackout_xyz: the lens covered for 2 s from 2 s while the camera moves) and its
clean twin (no blackout), ``hard`` (walking_hard's fast turns with motion blur, a rolling
shutter, auto-exposure swings and a depth-colour delay; the first 300 frames) and its clean
twin (walking_turns). Each runs ``default`` through the CLI with ``--sequential``
(deterministic) as RGB-D (cam0 + depth0) and stereo (cam0 + cam1), and ``mono_dynamic`` (the
monocular dynamic front end) on cam0 alone, with the IMU and without (``--set imu.use=false``).
ATE is SE(3) (evo's convention, on the frames each run posed), but Sim(3) for monocular
visual only (its map has no metres); a monocular-inertial run's scale error is |1 - s| of the
Sim(3) alignment of its trajectory (all frames, the ones before the IMU made the map metric
included: they are scaled with their keyframes).

Speed: threaded runs (one at a time) of ``default`` with and without the IMU on the first
static render, interleaved ``--speed-repeats`` times: per-frame time (``ms_per_frame.median``)
and the tracking thread's CPU per frame; the target reads the median of the repeats' ratios.

Prints a JSON document, then markdown tables: per render and the targets with median and
worst over the renders.
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
from typing import Any

import numpy as np

from semslam.config.schema import ImuConfig
from semslam.experiments.bench import emit_json

BASELINE = 0.11
#: (seed, layout): layout 0 the office, 1 the lounge, 2 a random room (1 and 2 held out).
PAIRS = [(20, 0), (21, 1), (22, 2)]
QUICK_PAIRS = [(20, 0)]
#: kind -> (synth sequence, frames, extra synth flags).
KINDS: dict[str, tuple[str, int, list[str]]] = {
    "static": ("static_xyz", 200, []),
    "walking": ("walking_xyz", 200, []),
    "blackout": ("blackout_xyz", 180, ["--blackout-start-s", "2.0", "--blackout-s", "2.0"]),
    "blackout_twin": ("blackout_xyz", 180, ["--blackout-s", "0"]),
    "hard": ("walking_hard", 300, []),
    "hard_twin": ("walking_turns", 300, []),
}
SENSORS = ("rgbd", "stereo", "mono")
#: The preset each sensor runs: the dynamic-scene front end of each.
PRESETS = {"rgbd": "default", "stereo": "default", "mono": "mono_dynamic"}
MODES = ("imu", "vis")
#: A monocular scale this well shown is sure (the config's default, which the runs use).
SURE_SPREAD = ImuConfig().max_scale_spread


@dataclass(frozen=True)
class Render:
    name: str
    kind: str
    path: Path
    pair: str


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "semslam.cli.main", *args]


def _render(work: Path, kind: str, seed: int, layout: int) -> Render:
    """The render, made now unless ``sequence.json`` shows the same one."""
    seq, frames, extra = KINDS[kind]
    pair = f"s{seed}_l{layout}"
    name = f"{kind}_{pair}"
    path = work / "data" / name
    want = {"seed": seed, "layout": layout, "frames": frames, "stereo_baseline": BASELINE, "imu": True,
            "euroc_depth": True}
    meta = path / "sequence.json"
    have = json.loads(meta.read_text()).get("config", {}) if meta.is_file() else {}
    if any(have.get(k) != v for k, v in want.items()) or not (path / "mav0" / "imu0" / "data.csv").is_file():
        shutil.rmtree(path, ignore_errors=True)
        for old in (work / "runs").glob(f"{name}_*"):
            shutil.rmtree(old, ignore_errors=True)
        cmd = _cli("synth", str(path), "-s", seq, "-n", str(frames), "--seed", str(seed), "--layout", str(layout),
                   "--stereo-baseline", str(BASELINE), "--layout-format", "euroc", "--imu", "--depth", "-q", *extra)
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return Render(name, kind, path, pair)


def _run(render: Render, sensor: str, mode: str, work: Path, speed: bool = False) -> dict[str, Any] | None:
    """stats.json of one run (cached); None (and a line on stderr) if it failed."""
    out = work / ("speed" if speed else "runs") / f"{render.name}_{sensor}_{mode}"
    if speed or not (out / "stats.json").is_file():
        flags = ["--preset", PRESETS[sensor], "--sensor", sensor] + (["--set", "imu.use=false"] if mode == "vis" else [])
        extra = [] if speed else ["--sequential", "--map", "none"]
        cmd = _cli("run", str(render.path), "--out", str(out), *flags, *extra, "--quiet", "--no-report", "--overwrite")
        done = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        if done.returncode != 0:
            print(f"{render.name} {sensor} {mode}: failed: {done.stderr.strip()[-400:]}", file=sys.stderr)
            return None
    return json.loads((out / "stats.json").read_text())


def _ate_cm(s: dict[str, Any], sensor: str, mode: str) -> float | None:
    """SE(3) ATE, but Sim(3) for monocular visual only (its map has no metres)."""
    ate = s.get("ate_se3") if sensor == "mono" and mode == "imu" else s.get("ate")
    return ate["rmse"] * 100 if isinstance(ate, dict) else None


def _tilt_deg(render: Render, sensor: str, mode: str, s: dict[str, Any], work: Path) -> float | None:
    """Degrees between an IMU run's map z axis and the render's gravity (the map is turned
    to gravity after the inertial initialisation); None for a visual-only run or one whose
    map was never turned (a monocular scale never shown)."""
    if mode != "imu" or not s.get("imu_gravity_alignments"):
        return None
    from semslam.eval.gravity import gravity_tilt_deg
    from semslam.io.sequence import open_sequence
    from semslam.io.trajectory import read_tum

    gt = open_sequence(render.path, kind="rgbd").groundtruth()
    assert gt is not None
    return gravity_tilt_deg(gt, read_tum(work / "runs" / f"{render.name}_{sensor}_{mode}" / "trajectory.txt"))


def _row(render: Render, sensor: str, mode: str, s: dict[str, Any], work: Path) -> dict[str, Any]:
    return {"render": render.name, "kind": render.kind, "pair": render.pair, "sensor": sensor, "mode": mode,
            "ate_cm": _ate_cm(s, sensor, mode), "tilt_deg": _tilt_deg(render, sensor, mode, s, work),
            "sim3_scale": s.get("ate_sim3_scale"),
            "imu_scales": s.get("imu_scales"), "frames": int(s["frames"]),
            "tracked": int(s["tracked_frames"]), "lost": int(s["lost_frames"]),
            "uninitialised": int(s.get("uninitialized_frames", 0)), "maps": s.get("maps"),
            "imu_only_frames": s.get("imu_only_frames"), "imu_init_frame": s.get("imu_init_frame"),
            "ms_per_frame": s["ms_per_frame"]["median"]}


def _sure(row: dict[str, Any]) -> bool:
    """A monocular-inertial run whose map got a sure scale (spread under imu.max_scale_spread),
    not only a provisional one."""
    return any(spread <= SURE_SPREAD for _, _, spread in row["imu_scales"] or [])


def _dist(values: list[float], worst: str = "max") -> str:
    if not values:
        return "-"
    w = max(values) if worst == "max" else min(values)
    return f"{np.median(values):.2f} / {w:.2f}"


def targets(rows: list[dict[str, Any]], speed: list[dict[str, Any]]) -> list[tuple[str, str, str, str]]:
    """(target, measured median / worst, bound, PASS / FAIL / reported / n/a)."""
    at = {(r["kind"], r["pair"], r["sensor"], r["mode"]): r for r in rows}

    def ratios(kind: str, twin: str, sensor: str, mode_a: str = "imu", mode_b: str = "imu") -> list[float]:
        out = []
        for (k, pair, s, m), r in at.items():
            other = at.get((twin, pair, sensor, mode_b))
            if k == kind and s == sensor and m == mode_a and other and r["ate_cm"] and other["ate_cm"]:
                out.append(r["ate_cm"] / other["ate_cm"])
        return out

    def verdict(values: list[float], ok: bool) -> str:
        return "n/a" if not values else ("PASS" if ok else "FAIL")

    sensors = [s for s in SENSORS if any(r["sensor"] == s for r in rows)]
    goals: list[tuple[str, str, str, str]] = []
    for sensor in sensors:
        lost = [float(r["frames"] - r["tracked"]) for r in rows if r["sensor"] == sensor and r["mode"] == "imu"]
        goals.append((f"{sensor}-inertial: frames without a pose, every render", _dist(lost), "0",
                      verdict(lost, bool(lost) and max(lost) == 0)))
        if sensor == "mono":  # the two-view initialisation's frames have no pose in any monocular SLAM
            after = [float(r["lost"]) for r in rows if r["sensor"] == sensor and r["mode"] == "imu"]
            goals.append(("mono-inertial: frames lost after the two-view initialisation", _dist(after), "0",
                          verdict(after, bool(after) and max(after) == 0)))
        lost_vis = [float(r["frames"] - r["tracked"]) for r in rows if r["sensor"] == sensor and r["mode"] == "vis"]
        goals.append((f"{sensor} visual only: frames without a pose", _dist(lost_vis), "reported", "reported"))
    for sensor in sensors:
        b = ratios("blackout", "blackout_twin", sensor)
        goals.append((f"{sensor}-inertial: 2 s blackout ATE / clean twin's", _dist(b), "<= 1.5",
                      verdict(b, bool(b) and max(b) <= 1.5)))
    for sensor in sensors:
        h = ratios("hard", "hard_twin", sensor)
        goals.append((f"{sensor}-inertial: hard imaging ATE / clean twin's", _dist(h), "<= 1.5",
                      verdict(h, bool(h) and max(h) <= 1.5)))
        hv = ratios("hard", "hard_twin", sensor, "vis", "vis")
        goals.append((f"{sensor} visual only: hard imaging ATE / clean twin's", _dist(hv), "reported", "reported"))
    for sensor in sensors:
        tilt = [r["tilt_deg"] for r in rows if r["sensor"] == sensor and r["tilt_deg"] is not None]
        goals.append((f"{sensor}-inertial: map's z axis to the render's gravity (degrees)", _dist(tilt),
                      "reported", "reported"))
    st = ratios("static", "static", "stereo", "imu", "vis")
    # "No worse": the same frames tracked from another search start differ in the 4th digit.
    goals.append(("stereo-inertial static ATE / stereo alone", _dist(st), "<= 1.0 (to 2 %)",
                  verdict(st, bool(st) and max(st) <= 1.02)))
    rg = ratios("static", "static", "rgbd", "imu", "vis")
    goals.append(("RGB-D-inertial static ATE / RGB-D alone", _dist(rg), "reported", "reported"))
    for sensor in sensors:
        if sensor != "mono":
            w = ratios("walking", "walking", sensor, "imu", "vis")
            goals.append((f"{sensor}: walking ATE with IMU / without", _dist(w), "reported", "reported"))
    per_frame = [s["ratio"] for s in speed]
    goals.append(("per-frame time with IMU / visual only (threaded; median of interleaved repeats)",
                  _dist(per_frame), "<= 1.3",
                  verdict(per_frame, bool(per_frame) and max(per_frame) <= 1.3)))
    if "mono" in sensors:
        mono = [r for r in rows if r["sensor"] == "mono" and r["mode"] == "imu"]
        metric = [r for r in mono if _sure(r) and r["sim3_scale"]]
        errors = [abs(1.0 - 1.0 / r["sim3_scale"]) * 100 for r in metric]
        goals.append((f"mono-inertial: scale error after initialisation, % ({len(metric)} of {len(mono)} runs "
                      "made metric)", _dist(errors), "<= 2 %",
                      verdict(errors, bool(errors) and len(metric) == len(mono) and max(errors) <= 2.0)))
        vs = [r["ate_cm"] / other["ate_cm"] for r in mono
              if (other := at.get((r["kind"], r["pair"], "stereo", "imu"))) and r["ate_cm"] and other["ate_cm"]]
        goals.append(("mono-inertial ATE (SE(3)) / stereo-inertial's", _dist(vs), "<= 2x",
                      verdict(vs, bool(vs) and max(vs) <= 2.0)))
    return goals


def _speed(renders: list[Render], work: Path, repeats: int, sensors: list[str]) -> list[dict[str, Any]]:
    """Per render and sensor: ``repeats`` threaded runs with and without the IMU, interleaved
    (a load that comes and goes then falls on both); the per-frame median and the tracking
    thread's CPU per frame of each, and their ratios' median over the repeats."""
    rows = []
    for render in renders:
        for sensor in sensors:
            runs: dict[str, list[tuple[float, float]]] = {m: [] for m in MODES}
            for _ in range(repeats):
                for mode in MODES:
                    s = _run(render, sensor, mode, work, speed=True)
                    if s is not None:
                        cpu = (s.get("tracking_thread_ms") or {}).get("cpu", float("nan"))
                        runs[mode].append((s["ms_per_frame"]["median"], cpu))
            n = min(len(runs["imu"]), len(runs["vis"]))
            if n == 0:
                continue
            imu, vis = np.array(runs["imu"][:n]), np.array(runs["vis"][:n])
            rows.append({"render": render.name, "sensor": sensor, "repeats": n,
                         "imu_ms": float(np.median(imu[:, 0])), "vis_ms": float(np.median(vis[:, 0])),
                         "ratio": float(np.median(imu[:, 0] / vis[:, 0])),
                         "ratios": [round(float(r), 3) for r in imu[:, 0] / vis[:, 0]],
                         "imu_cpu_ms": float(np.median(imu[:, 1])), "vis_cpu_ms": float(np.median(vis[:, 1])),
                         "load": round(os.getloadavg()[0], 2)})
    return rows


def _markdown(rows: list[dict[str, Any]], speed: list[dict[str, Any]], goals: list[tuple[str, str, str, str]]) -> str:
    lines = ["ATE (cm, SE(3), `--sequential`; preset `default`, monocular `mono_dynamic`, whose visual-only "
             "ATE is Sim(3)); frames without a pose in brackets; mono + IMU: the map's scale error", "",
             "| render | RGB-D + IMU | RGB-D | stereo + IMU | stereo | mono + IMU | mono (Sim(3)) | "
             "IMU-only frames (RGB-D / stereo / mono) |",
             "|---|---|---|---|---|---|---|---|"]
    at = {(r["render"], r["sensor"], r["mode"]): r for r in rows}
    for name in dict.fromkeys(r["render"] for r in rows):
        cells = []
        for sensor in SENSORS:
            for mode in MODES:
                r = at.get((name, sensor, mode))
                if r is None:
                    cells.append("-")
                    continue
                cell = "-" if r["ate_cm"] is None else f"{r['ate_cm']:.2f}"
                missing = r["frames"] - r["tracked"]
                cell += f" ({missing})" if missing else ""
                if sensor == "mono" and mode == "imu":
                    cell += (f", scale {100 * abs(1 - 1 / r['sim3_scale']):.1f} %" if _sure(r) and r["sim3_scale"]
                             else ", not metric")
                cells.append(cell)
        only = [str((at.get((name, s, "imu")) or {}).get("imu_only_frames", "-")) for s in SENSORS]
        lines.append(f"| {name} | {' | '.join(cells)} | {' / '.join(only)} |")
    if speed:
        lines += ["", "Speed (threaded, one run at a time, with and without the IMU interleaved): per-frame median "
                  "and the tracking thread's CPU per frame (ms), medians over the repeats", "",
                  "| render | sensor | repeats | with IMU | visual only | ratio (each repeat) | tracking CPU with / without | load |",
                  "|---|---|---|---|---|---|---|---|"]
        lines += [f"| {s['render']} | {s['sensor']} | {s['repeats']} | {s['imu_ms']:.1f} | {s['vis_ms']:.1f} | "
                  f"{s['ratio']:.2f} ({', '.join(f'{r:.2f}' for r in s['ratios'])}) | "
                  f"{s['imu_cpu_ms']:.1f} / {s['vis_cpu_ms']:.1f} | {s['load']} |" for s in speed]
    lines += ["", "| target | median / worst | bound | result |", "|---|---|---|---|"]
    lines += [f"| {t} | {m} | {b} | {ok} |" for t, m, b, ok in goals]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--work", type=Path, default=Path("out/inertial_targets"), help="renders and runs (cached)")
    ap.add_argument("--jobs", type=int, default=2, help="renders / accuracy runs at a time (speed runs: one)")
    ap.add_argument("--quick", action="store_true", help="one seed")
    ap.add_argument("--pairs", help="seed:layout pairs instead of the committed ones, e.g. 31:1,32:2 (held-out checks)")
    ap.add_argument("--kinds", help=f"a subset of {','.join(KINDS)}")
    ap.add_argument("--sensors", help=f"a subset of {','.join(SENSORS)}")
    ap.add_argument("--json", type=Path, help="also write the JSON here")
    ap.add_argument("--no-speed", action="store_true", help="accuracy only")
    ap.add_argument("--speed-repeats", type=int, default=3, help="interleaved speed runs per mode")
    args = ap.parse_args(argv)
    pairs = QUICK_PAIRS if args.quick else PAIRS
    if args.pairs:
        pairs = [(int(a), int(b)) for a, b in (p.split(":") for p in args.pairs.split(","))]
    kinds = args.kinds.split(",") if args.kinds else list(KINDS)
    unknown = [k for k in kinds if k not in KINDS]
    if unknown:
        ap.error(f"--kinds: unknown {', '.join(unknown)} (known: {', '.join(KINDS)})")
    sensors = args.sensors.split(",") if args.sensors else list(SENSORS)
    if any(s not in SENSORS for s in sensors):
        ap.error(f"--sensors: known are {', '.join(SENSORS)}")
    chosen = [(kind, seed, layout) for seed, layout in pairs for kind in kinds]
    with ThreadPoolExecutor(args.jobs) as pool:
        renders = list(pool.map(lambda c: _render(args.work, *c), chosen))
    jobs = [(r, s, m) for r in renders for s in sensors for m in MODES]
    with ThreadPoolExecutor(args.jobs) as pool:
        results = list(pool.map(lambda j: _run(j[0], j[1], j[2], args.work), jobs))
    rows = [_row(r, s, m, st, args.work) for (r, s, m), st in zip(jobs, results) if st is not None]
    speed = [] if args.no_speed else _speed([r for r in renders if r.kind == "static"][:1], args.work,
                                           args.speed_repeats, sensors)
    goals = targets(rows, speed)
    emit_json({"baseline_m": BASELINE, "cpus": os.cpu_count(), "rows": rows, "speed": speed,
               "targets": [{"target": t, "median_worst": m, "bound": b, "result": ok} for t, m, b, ok in goals]},
              args.json)
    print()
    print(_markdown(rows, speed, goals))
    return 0


if __name__ == "__main__":
    sys.exit(main())
