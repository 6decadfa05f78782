"""``semslam bench``: benchmarks on the synthetic sequences (options of semslam/bench.py)."""

from __future__ import annotations

import typer


def register(app: typer.Typer) -> None:
    @app.command("bench", add_help_option=False,
                 context_settings={"allow_extra_args": True, "ignore_unknown_options": True})
    def bench(ctx: typer.Context) -> None:
        """Render synthetic sequences, run presets, print JSON + a markdown table (--ablation: STDC-SLAM Table 1)."""
        from semslam.bench import main

        code = main(list(ctx.args))
        if code:
            raise typer.Exit(code)
