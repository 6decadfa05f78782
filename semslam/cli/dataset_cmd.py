"""``semslam dataset list | get | path``: public RGB-D sequences by name (semslam/datasets)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.console import Console
from rich.table import Table

console = Console()

DATA_DIR_HELP = "data folder (default $SEMSLAM_DATA, else ~/.cache/semslam/datasets)"


def register(app: typer.Typer) -> None:
    dataset_app = typer.Typer(help="Public RGB-D sequences by name: TUM RGB-D, Bonn RGB-D Dynamic, ICL-NUIM.",
                              no_args_is_help=True)
    app.add_typer(dataset_app, name="dataset")

    @dataset_app.command("list")
    def list_(
        family: Optional[str] = typer.Argument(None, help="only this family: tum, bonn or icl"),
        data_dir: Optional[Path] = typer.Option(None, "--data-dir", help=DATA_DIR_HELP),
    ) -> None:
        """The names `semslam dataset get` and `semslam run` accept, and which are downloaded."""
        from semslam.datasets import CATALOGUE, FAMILIES, data_dir as default_dir, is_downloaded

        if family is not None and family not in FAMILIES:
            raise typer.BadParameter(f"unknown family {family!r} (known: {', '.join(FAMILIES)})")
        root = data_dir or default_dir()
        rows = [(entry.name, "yes" if is_downloaded(entry, root) else "", entry.folder, entry.url)
                for entry in CATALOGUE.values() if family is None or entry.family == family]
        if not console.is_terminal:  # piped: whole names, one per line, for grep / cut / xargs
            for row in rows:
                typer.echo("\t".join(value or "-" for value in row))
            return
        table = Table(title=f"datasets (data folder {root})")
        table.add_column("name", no_wrap=True)  # names are what users copy: never cut
        for col in ("downloaded", "folder", "archive"):
            table.add_column(col, overflow="fold")
        for row in rows:
            table.add_row(*row)
        console.print(table)

    @dataset_app.command("get")
    def get(
        names: list[str] = typer.Argument(..., help="dataset names, e.g. tum/fr3_walking_xyz bonn/balloon icl/lr_kt0"),
        data_dir: Optional[Path] = typer.Option(None, "--data-dir", help=DATA_DIR_HELP),
        mirror: Optional[str] = typer.Option(None, "--mirror", help="fetch the archives by their file names under "
                                                                    "this URL (default $SEMSLAM_DATASET_MIRROR, "
                                                                    "else the official URLs)"),
        keep_archive: bool = typer.Option(False, "--keep-archive", help="keep the downloaded archive"),
        force: bool = typer.Option(False, "--force", help="download and extract again even if present"),
        quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress bar"),
    ) -> None:
        """Download (resuming a partial download), verify and extract sequences into the data folder."""
        from semslam.datasets import archive_url, get as get_dataset, lookup
        from semslam.io.sequence import open_sequence

        entries = [lookup(n) for n in names]  # every name checked before the first download
        for entry in entries:
            if not quiet:
                console.print(f"{entry.name}: {archive_url(entry, mirror)}")
            folder = get_dataset(entry.name, data_dir, mirror=mirror, progress=not quiet,
                                 keep_archive=keep_archive, force=force)
            seq = open_sequence(folder)  # the reader accepts it: lists, images, calibration
            gt = "with ground truth" if seq.groundtruth_path is not None else "no ground truth"
            console.print(f"{entry.name}: {len(seq)} frames, {gt}, camera {seq.camera.source or 'given'}, in {folder}")

    @dataset_app.command("path")
    def path(
        name: str = typer.Argument(..., help="dataset name, e.g. tum/fr3_walking_xyz"),
        data_dir: Optional[Path] = typer.Option(None, "--data-dir", help=DATA_DIR_HELP),
    ) -> None:
        """Print the folder of a downloaded sequence (for scripts); error if not downloaded."""
        from semslam.datasets import resolve

        typer.echo(str(resolve(name, data_dir)))
