"""``semslam eval-map RUN_OUT SEQ``: a run's maps against a synthetic sequence's true scene."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import typer
from rich.console import Console
from rich.table import Table

console = Console()


def _pct(x: float | None) -> str:
    return "-" if x is None else f"{100 * x:.1f} %"


def register(app: typer.Typer) -> None:
    @app.command("eval-map")
    def eval_map(
        run_dir: Path = typer.Argument(..., help="output folder of `semslam run` (with map/)"),
        sequence: Path = typer.Argument(..., help="the synthetic sequence it ran on (scene.json, groundtruth.txt)"),
        tolerance: float = typer.Option(0.05, "--tolerance", help="metres from the true surface that count as "
                                                                  "accurate"),
        json_out: Optional[Path] = typer.Option(None, "--json", help="also write the numbers as JSON"),
    ) -> None:
        """Point accuracy, class accuracy (CA) and MPA of the semantic cloud and the octree,
        octree precision / recall and the share of occupied voxels left by movers (ghosts)."""
        from semslam.eval.map_eval import evaluate_map

        res = evaluate_map(run_dir, sequence, tolerance)
        table = Table(title=f"maps of {run_dir} (ATE {res.ate_cm:.2f} cm; tolerance {100 * tolerance:.0f} cm)")
        table.add_column("metric")
        table.add_column("semantic cloud")
        table.add_column("octree")
        table.add_column("mesh")
        table.add_row("points / occupied voxels / vertices", str(res.cloud_points), str(res.octree_occupied),
                      str(res.mesh_vertices))
        table.add_row("point accuracy", _pct(res.cloud_point_accuracy), _pct(res.octree_point_accuracy),
                      _pct(res.mesh_point_accuracy))
        table.add_row("MPA (mean class accuracy)", _pct(res.cloud_mpa), _pct(res.octree_mpa), "")
        for name in sorted(set(res.cloud_class_accuracy) | set(res.octree_class_accuracy)):
            c, o = res.cloud_class_accuracy.get(name), res.octree_class_accuracy.get(name)
            table.add_row(f"  CA {name}", "-" if c is None else f"{100 * c[1]:.1f} % of {c[0]}",
                          "-" if o is None else f"{100 * o[1]:.1f} % of {o[0]}", "")
        table.add_row("octree precision / recall", "", f"{_pct(res.octree_precision)} / {_pct(res.octree_recall)}",
                      "")
        table.add_row("ghost share (points / occupied voxels from movers)",
                      f"{_pct(res.cloud_ghost_share)} ({res.cloud_ghost_points})",
                      f"{_pct(res.octree_ghost_share)} ({res.octree_ghost_voxels})", "")
        console.print(table)
        if json_out is not None:
            json_out.parent.mkdir(parents=True, exist_ok=True)
            json_out.write_text(json.dumps(res.to_dict(), indent=2))
            console.print(f"wrote {json_out}")
