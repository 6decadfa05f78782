"""``semslam train reproduce sdfcnn|fpfdcnn --work DIR``: remake shipped weights in one command.

Runs a recipe of ``semslam.nets.recipes``: its renders (``semslam synth``, skipped when the
folder holds that very render, complete: ``synth.needs_render``), its training stages and the
ONNX export (each skipped when its output exists, so an interrupted run continues), each as its
own ``semslam`` process. ``--dry-run``
prints the commands instead. The results stay in DIR; copying them to ``semslam/data/``
ships them.
"""

from __future__ import annotations

import shlex
import subprocess
import sys
from pathlib import Path

import typer

from semslam.cli.train_cmd import train_app
from semslam.errors import ConfigError


def reproduce_command(
    name: str = typer.Argument(..., help="sdfcnn or fpfdcnn"),
    work: Path = typer.Option(..., "--work", "-w", help="Folder for the renders (WORK/data) and the weights."),
    dry_run: bool = typer.Option(False, "--dry-run", help="Print the commands, run nothing."),
) -> None:
    """Remake a shipped network's weights: render its data, train, export to ONNX."""
    from semslam.nets.recipes import RECIPES
    from semslam.synth import needs_render

    if name not in RECIPES:
        raise ConfigError(f"train reproduce: unknown recipe {name!r} (known: {', '.join(sorted(RECIPES))})")
    recipe = RECIPES[name]
    data = work / "data"
    commands: list[tuple[list[str], bool]] = []  # (argv after `semslam`, already done)
    for r in recipe.renders:
        commands.append((r.argv(data), not needs_render(data / r.name, r.config(data))))
    for step in recipe.steps:
        commands.append((step.resolve(data, work), (work / step.output).is_file()))
    if dry_run:
        for argv, done in commands:
            typer.echo(("# done: " if done else "") + shlex.join(["semslam", *argv]))
        return
    typer.echo(f"{name}: {len(recipe.renders)} renders and {len(recipe.steps)} steps into {work} ({recipe.note})",
               err=True)
    work.mkdir(parents=True, exist_ok=True)
    if recipe.photos and not (data / recipe.photos).is_dir():  # photo textures (training-time packages)
        from semslam.synth.textures import collect_photos

        typer.echo(f"{len(collect_photos(data / recipe.photos))} photos in {data / recipe.photos}", err=True)
    for i, (argv, done) in enumerate(commands, 1):
        line = shlex.join(["semslam", *argv])
        if done:
            typer.echo(f"[{i}/{len(commands)}] done already: {line}", err=True)
            continue
        typer.echo(f"[{i}/{len(commands)}] {line}", err=True)
        rc = subprocess.call([sys.executable, "-m", "semslam.cli.main", *argv])
        if rc != 0:
            raise ConfigError(f"train reproduce {name}: step {i} failed (exit code {rc}): {line}; "
                              f"rerun the same command to continue from it")
    typer.echo(f"{name}: done; to ship: cp {' '.join(str(work / f) for f in recipe.shipped)} semslam/data/")


def register(app: typer.Typer) -> None:
    """Add ``reproduce`` to the ``train`` group and make sure the group is on ``app``."""
    from semslam.cli import train_cmd

    if "reproduce" not in {c.name for c in train_app.registered_commands}:
        train_app.command("reproduce")(reproduce_command)
    train_cmd.register(app)
