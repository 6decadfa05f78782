"""``semslam bench``: render synthetic sequences, run presets/variants on each (``--repeats``
times; a batch plan run by the batch runner), print a JSON document and a markdown table
(``--ablation``: the structure of STDC-SLAM's Table 1)."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Optional

import typer


def register(app: typer.Typer) -> None:
    @app.command("bench")
    def bench(
        presets: Optional[str] = typer.Option(None, "--presets", help="comma-separated presets (default f2kf,orb; none with --ablation)"),
        ablation: bool = typer.Option(False, "--ablation", help="STDC-SLAM Table 1 variants + ddl + default on the walking, static and walking_box sequences"),
        variant: list[str] = typer.Option([], "--variant", help="label:preset:key=value,... (repeatable)"),
        sequences: Optional[str] = typer.Option(None, "--sequences", help="comma-separated synthetic sequence names"),
        frames: Optional[int] = typer.Option(None, "--frames", min=2, help="frames per sequence (default: each sequence's own)"),
        data: Path = typer.Option(Path("out/bench/data"), "--data", help="where rendered sequences are cached"),
        out: Path = typer.Option(Path("out/bench/runs"), "--out", help="where run outputs go"),
        json_path: Optional[Path] = typer.Option(None, "--json", help="also write the JSON here"),
        profile: bool = typer.Option(False, "--profile", help="run each under py-spy: CPU per thread and stage, top functions"),
        rate: int = typer.Option(250, "--rate", min=10, max=2000, help="--profile: samples per second"),
        realtime: bool = typer.Option(False, "--realtime", help="feed frames at camera rate (semslam run --realtime): "
                                                                 "per-frame times as ORB-SLAM3's examples measure them"),
        repeats: int = typer.Option(1, "--repeats", min=1, help="runs per sequence x variant; the JSON's groups and "
                                                               "the second table give median and min-max"),
        ray: bool = typer.Option(False, "--ray", help="run the jobs as Ray tasks (2 CPUs each; default: one after "
                                                      "another in this process)"),
        address: Optional[str] = typer.Option(None, "--address", help="with --ray: an existing Ray cluster"),
    ) -> None:
        """Benchmark presets on the synthetic sequences: JSON + a markdown table of ATE and ms/frame."""
        from semslam.experiments.batch import Executor
        from semslam.experiments.batch_summary import markdown
        from semslam.experiments.bench import (
            ABLATION_SEQUENCES,
            ABLATION_VARIANTS,
            DEFAULT_SEQUENCES,
            Variant,
            document,
            markdown_table,
            run_benchmark,
        )

        if presets is None:
            presets = "" if ablation else "f2kf,orb"
        texts = [p for p in presets.split(",") if p] + list(variant) + (ABLATION_VARIANTS if ablation else [])
        variants = [Variant.parse(t) for t in texts]
        if realtime:
            variants = [Variant(v.label, v.preset, (*v.overrides, "slam.realtime=true")) for v in variants]
        names = [s.strip() for s in sequences.split(",") if s.strip()] if sequences else (
            ABLATION_SEQUENCES if ablation else DEFAULT_SEQUENCES)

        if profile:
            _profile(variants, names, data, out, frames, rate, json_path)
            return

        def report(row) -> None:  # type: ignore[no-untyped-def]
            r = row.result
            print(f"{row.variant} on {row.sequence}: ATE {r.ate_rmse}, {r.ms_per_frame['median']:.1f} ms/frame, "
                  f"loops {r.loop_closing.loops}", file=sys.stderr)

        if address and not ray:
            raise typer.BadParameter("--address needs --ray")
        bench_run = run_benchmark(variants, names, data, out, frames, on_row=report, repeats=repeats,
                                  executor=Executor(ray=ray, address=address))
        doc = document(bench_run.rows, names, bench_run.summary)
        text = json.dumps(doc, indent=2)
        print(text)
        if json_path:
            json_path.parent.mkdir(parents=True, exist_ok=True)
            json_path.write_text(text)
        print()
        print(markdown_table(bench_run.rows))
        if repeats > 1 or doc["failed"]:
            print()
            print(markdown(bench_run.summary), end="")
        for job in doc["failed"]:
            print(f"{job['variant']} on {job['sequence']} (r{job['repeat']}) failed: {job['error']}", file=sys.stderr)
        if doc["failed"]:
            raise typer.Exit(1)


def _profile(variants: list, names: list[str], data: Path, out: Path, frames: int | None, rate: int,  # type: ignore[type-arg]
             json_path: Path | None) -> None:
    """``semslam bench --profile``: each run under py-spy; JSON, then one table per run."""
    from semslam.experiments.profile import profile_table, profile_variants

    records = profile_variants(variants, names, data, out, frames, rate)
    doc = [{"variant": r["variant"], "sequence": r["sequence"],
            "ms_per_frame": r["result"].ms_per_frame, "stages_ms_median": r["result"].stages_ms_median,
            "ate_rmse_m": r["result"].ate_rmse, **r["profile"].to_dict()} for r in records]
    text = json.dumps(doc, indent=2)
    print(text)
    if json_path:
        json_path.parent.mkdir(parents=True, exist_ok=True)
        json_path.write_text(text)
    for r in records:
        res = r["result"]
        print(f"\n### {r['variant']} on {r['sequence']}: {res.frames} frames, "
              f"{res.ms_per_frame['median']:.1f} ms/frame median, {res.ms_per_frame['p95']:.1f} p95, "
              f"wall {res.wall_s:.1f} s (raw stacks: {res.out_dir / 'profile.raw.txt'})\n")
        print(profile_table(r["profile"], res.stages_ms_median))
