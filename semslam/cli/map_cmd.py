"""``semslam map RUN_OUT``: rebuild the maps of a finished run from its final keyframe poses."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.console import Console

console = Console()


def register(app: typer.Typer) -> None:
    @app.command("map")
    def map_(
        run_dir: Path = typer.Argument(..., help="output folder of a finished `semslam run`"),
        sequence: Optional[Path] = typer.Option(None, "--sequence", help="the sequence folder, if it moved since "
                                                                          "the run (default: the one in stats.json)"),
        out: Optional[Path] = typer.Option(None, "--out", "-o", help="where to write the maps (default RUN_OUT/map)"),
        maps: Optional[str] = typer.Option(None, "--map", help="maps to build: a comma list of octree, cloud, mesh, "
                                                               "keyframe_cloud (default: the run's maps.builders)"),
        set_: list[str] = typer.Option([], "--set", help="override a config field, e.g. "
                                                         "maps.octree_resolution_m=0.1"),
        quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress bar"),
    ) -> None:
        """Rebuild OUT/map/ (octree, semantic cloud, mesh) of a run: inpainting and every map
        from the keyframes' images and their final poses, without tracking again."""
        from semslam.cli.run_cmd import run_overrides
        from semslam.core.results import MapBuildingCounters
        from semslam.offline_maps import rebuild_maps

        overrides = run_overrides(set_, None, True, False, maps=maps)
        bar = None
        if not quiet:
            from tqdm import tqdm

            bar = tqdm(unit="keyframe", desc="semslam map", dynamic_ncols=True)

        def step(done: int, total: int) -> None:
            if bar is not None:
                bar.total = total
                bar.update(done - bar.n)

        try:
            paths, stats = rebuild_maps(run_dir, sequence, out, overrides, progress=step)
        finally:
            if bar is not None:
                bar.close()
        for name, path in paths.items():
            console.print(f"{name}: {path}")
        filled = MapBuildingCounters.from_counters(stats).inpaint_filled_share
        if filled is not None:
            console.print(f"inpainting filled {100 * filled:.1f} % of the keyframes' dynamic pixels")
