"""``semslam train ...``: train the project's own models (the ORB vocabulary for now).

``train`` is a Typer sub-app so later modules (networks) add their own subcommands with
``from semslam.cli.train_cmd import train_app`` and ``@train_app.command("name")``.
"""

from __future__ import annotations

import shlex
import time
from pathlib import Path

import typer

from semslam.errors import ConfigError

train_app = typer.Typer(
    help="Train the project's own models (ORB vocabulary, STDC, DUNet, SDFCNN, FPFDCNN), or remake the shipped ones.",
    no_args_is_help=True,
    add_completion=False,
)


@train_app.command("vocab")
def vocab_command(
    out: Path = typer.Option(..., "--out", "-o", help="Vocabulary file to write (.npz)."),
    images: list[Path] = typer.Option(
        [], "--images", help="Image folder (searched recursively) or file; repeatable."
    ),
    exclude: list[str] = typer.Option(
        [], "--exclude", help="Shell pattern on the full path of images to skip; repeatable."
    ),
    video: list[Path] = typer.Option([], "--video", help="Video file; repeatable."),
    every: int = typer.Option(30, "--every", min=1, help="Take every N-th video frame."),
    synth: list[str] = typer.Option(
        [], "--synth", help="Synthetic sequence name to render frames from; repeatable."
    ),
    synth_frames: int = typer.Option(
        5, "--synth-frames", min=1, help="Frames spread along each --synth sequence."
    ),
    k: int = typer.Option(8, "--k", min=2, max=64, help="Branching factor."),
    levels: int = typer.Option(5, "--levels", min=1, max=8, help="Depth of the tree."),
    n_features: int = typer.Option(1000, "--n-features", min=50, help="ORB features per image."),
    max_descriptors: int = typer.Option(
        300_000, "--max-descriptors", min=1000, help="Cluster at most this many (random subset)."
    ),
    seed: int = typer.Option(0, "--seed", min=0, help="Seed of sampling and k-means++."),
    note: str = typer.Option("", "--note", help="Free text stored in the metadata (e.g. data versions)."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress messages."),
) -> None:
    """Train an ORB vocabulary tree (DBoW2-style) for loop closing and relocalisation."""
    from semslam.place.train_vocab import TrainingSources, train_vocabulary

    if not (images or video or synth):
        raise ConfigError("train vocab: give at least one --images, --video or --synth source")
    if out.suffix != ".npz":
        raise ConfigError(f"train vocab: --out must end in .npz, got {out}")
    sources = TrainingSources(list(images), list(exclude), list(video), every, list(synth), synth_frames)
    say = (lambda msg: None) if quiet else (lambda msg: typer.echo(msg, err=True))
    t0 = time.perf_counter()
    args = [*_rep("--images", images), *_rep("--exclude", exclude), *_rep("--video", video)]
    args += ["--every", str(every), *_rep("--synth", synth), "--synth-frames", str(synth_frames)]
    args += ["--k", str(k), "--levels", str(levels), "--n-features", str(n_features)]
    args += ["--max-descriptors", str(max_descriptors), "--seed", str(seed), "--out", str(out)]
    if note:
        args += ["--note", note]
    meta = {"command": shlex.join(["semslam", "train", "vocab", *args]), "note": note}
    vocab = train_vocabulary(
        sources.iter_images(), k=k, levels=levels, n_features=n_features, seed=seed,
        max_descriptors=max_descriptors, metadata=meta, progress=say,
    )
    vocab.metadata["sources"] = sources.describe()
    vocab.metadata["train_seconds"] = round(time.perf_counter() - t0, 1)
    out.parent.mkdir(parents=True, exist_ok=True)
    vocab.save(out)
    m = vocab.metadata
    typer.echo(
        f"{out}: {vocab.n_words} words (k={k}, levels={levels}) from {m['n_images']} images, "
        f"{m['n_descriptors']} descriptors, {out.stat().st_size / 1e6:.2f} MB, {m['train_seconds']} s"
    )


def _rep(flag: str, values: list[Path] | list[str]) -> list[str]:
    """``[flag, v1, flag, v2, ...]`` for the recorded command line."""
    return [x for v in values for x in (flag, str(v))]


def register(app: typer.Typer) -> None:
    """Add the ``train`` command group to the semslam CLI (once)."""
    if not any(g.typer_instance is train_app for g in app.registered_groups):
        app.add_typer(train_app, name="train")
