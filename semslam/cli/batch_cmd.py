"""``semslam batch PLAN.yaml``: sequences x variants x repeats as Ray tasks (or in-process
with ``--no-ray``), each job's outputs in OUT/<sequence>/<variant>/r<k>/, and a summary
(median and min-max over repeats) in OUT/summary.{json,md,html}."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer


def register(app: typer.Typer) -> None:
    @app.command("batch")
    def batch(
        plan_path: Path = typer.Argument(..., metavar="PLAN.yaml", help="the plan: sequences, variants, repeats, ..."),
        out: Optional[Path] = typer.Option(None, "--out", "-o", help="batch output folder (default: out/batch/<plan name>)"),
        no_ray: bool = typer.Option(False, "--no-ray", help="run the jobs one after another in this process (same "
                                                            "jobs, same summary; no Ray needed)"),
        address: Optional[str] = typer.Option(None, "--address", help="an existing Ray cluster (e.g. ray://head:10001 or "
                                                                      "auto); default: a local Ray instance"),
        num_cpus: Optional[int] = typer.Option(None, "--num-cpus", min=1, help="CPUs of the local Ray instance "
                                                                               "(default: the machine's)"),
        repeats: Optional[int] = typer.Option(None, "--repeats", min=1, help="override the plan's repeats"),
        frames: Optional[int] = typer.Option(None, "--frames", min=2, help="override the plan's frames per run"),
        rerun: bool = typer.Option(False, "--rerun", help="run every job again, also those finished earlier"),
        quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress bar"),
    ) -> None:
        """Run a plan of SLAM jobs on Ray and summarise them; exit 1 if a job failed (the batch goes on)."""
        from semslam.experiments.batch import Executor, run_batch
        from semslam.experiments.batch_plan import load_plan

        if no_ray and address:
            raise typer.BadParameter("--address needs Ray; leave out --no-ray")
        plan = load_plan(plan_path, repeats=repeats, frames=frames)
        out_dir = out if out is not None else Path("out/batch") / plan_path.stem
        executor = Executor(ray=not no_ray, address=address, num_cpus=num_cpus)
        if no_ray:
            from semslam.cli.run_cmd import stop_on_signals

            with stop_on_signals():  # Ctrl-C / SIGTERM: this run writes what it has, the batch stops (130 / 143)
                summary = run_batch(plan, out_dir, executor, resume=not rerun, progress=not quiet)
        else:
            summary = run_batch(plan, out_dir, executor, resume=not rerun, progress=not quiet)
        typer.echo((out_dir / "summary.md").read_text())
        typer.echo(f"{summary['n_ok']} of {summary['n_jobs']} jobs ok ({summary['n_resumed']} finished earlier); "
                   f"{out_dir / 'summary.html'}")
        if summary["n_failed"]:
            typer.secho(f"{summary['n_failed']} jobs failed (errors in {out_dir / 'summary.md'})",
                        fg=typer.colors.RED, err=True)
            raise typer.Exit(1)
