"""Record or check deterministic reference trajectories of the SLAM presets.

A refactor must not change what the system computes. This script renders two short
sequences (static and people walking), runs each preset (the RGB-D ones and the
monocular `sdf`, `sdf_paper` and `sdf_rgbd`) through the CLI with
``--sequential`` (single-threaded, deterministic) and either stores the trajectories
(``--record DIR``) or compares a new run against them (``--check DIR``), printing JSON
and a table with the largest position difference per preset and sequence.

    python benchmarks/trajectory_reference.py --record out/ref
    python benchmarks/trajectory_reference.py --check out/ref

The CLI is used (not the Python API) so the same script works across API changes.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

PRESETS = ["orb", "default", "stdc", "ddl", "sdf", "sdf_paper", "sdf_rgbd"]
SEQUENCES = {"static_xyz": 120, "walking_xyz": 150}


def _render(data: Path) -> dict[str, Path]:
    from semslam.synth import SEQUENCES as SYNTH
    from semslam.synth import render_sequence

    out = {}
    for name, frames in SEQUENCES.items():
        seq_dir = data / name
        if not (seq_dir / "groundtruth.txt").is_file():
            render_sequence(replace(SYNTH[name], frames=frames), seq_dir, progress=False)
        out[name] = seq_dir
    return out


def _run(seq_dir: Path, preset: str, out_dir: Path) -> Path:
    cmd = [sys.executable, "-m", "semslam.cli.main", "run", str(seq_dir), "--out", str(out_dir), "--preset", preset,
           "--sequential", "--quiet", "--no-report", "--overwrite"]
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    return out_dir / "trajectory.txt"


def _load(path: Path) -> np.ndarray:
    return np.loadtxt(path, ndmin=2)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    mode = ap.add_mutually_exclusive_group(required=True)
    mode.add_argument("--record", type=Path, help="store reference trajectories here")
    mode.add_argument("--check", type=Path, help="compare a new run against the references here")
    ap.add_argument("--data", type=Path, default=Path("out/reference/data"), help="rendered sequences (cached)")
    ap.add_argument("--presets", default=",".join(PRESETS))
    ap.add_argument("--work", type=Path, default=Path("out/reference/check"), help="where --check runs write")
    args = ap.parse_args(argv)
    seqs = _render(args.data)
    ref_dir = args.record or args.check
    rows = []
    for name, seq_dir in seqs.items():
        for preset in args.presets.split(","):
            if args.record:
                traj = _run(seq_dir, preset, ref_dir / preset / name)
                rows.append({"sequence": name, "preset": preset, "frames": len(_load(traj))})
                continue
            new = _load(_run(seq_dir, preset, args.work / preset / name))
            ref = _load(ref_dir / preset / name / "trajectory.txt")
            common, ia, ib = np.intersect1d(ref[:, 0], new[:, 0], return_indices=True)
            diff = float(np.abs(ref[ia, 1:4] - new[ib, 1:4]).max()) if len(common) else float("nan")
            qdiff = float(np.minimum(np.abs(ref[ia, 4:] - new[ib, 4:]), np.abs(ref[ia, 4:] + new[ib, 4:])).max()) if len(common) else float("nan")
            rows.append({"sequence": name, "preset": preset, "ref_frames": len(ref), "new_frames": len(new),
                         "common_frames": len(common), "max_position_diff_m": diff, "max_quaternion_diff": qdiff,
                         "identical": bool(len(ref) == len(new) and np.array_equal(ref, new))})
    print(json.dumps(rows, indent=2))
    if args.check:
        print("\n| sequence | preset | frames ref/new | max position diff (m) | identical |")
        print("|---|---|---|---|---|")
        for r in rows:
            print(f"| {r['sequence']} | {r['preset']} | {r['ref_frames']}/{r['new_frames']} | "
                  f"{r['max_position_diff_m']:.2e} | {r['identical']} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
