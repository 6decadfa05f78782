"""``semslam train fpfdcnn``: train SDF-SLAM's keypoint network on the FP dataset (CPU).

Joins the ``train`` group of :mod:`semslam.cli.train_cmd`; torch is imported only when
the command runs. The shipped ``semslam/data/fpfdcnn.pt`` was made by the command in
``semslam/data/NETS.md`` (also stored in the checkpoint's metadata).
"""

from __future__ import annotations

import shlex
from pathlib import Path

import typer

from semslam.cli.train_cmd import train_app
from semslam.errors import ConfigError


def _ints(text: str, flag: str) -> tuple[int, ...]:
    try:
        values = tuple(int(v) for v in text.split(","))
    except ValueError:
        raise ConfigError(f"{flag}: expected comma-separated integers such as 1,2,3, got {text!r}") from None
    if not values or min(values) < 1:
        raise ConfigError(f"{flag}: frame gaps must be >= 1, got {text!r}")
    return values


def fpfdcnn_command(
    out: Path = typer.Option(..., "--out", "-o", help="Checkpoint to write (.pt)."),
    data: list[Path] = typer.Option(..., "--data", help="TUM-layout folder with depth and groundtruth.txt; "
                                                        "repeatable."),
    val: list[Path] = typer.Option([], "--val", help="Held-out TUM-layout folder for validation; repeatable."),
    width: float = typer.Option(0.5, "--width", help="Channel multiplier (1.0 = Table 12)."),
    steps: int = typer.Option(2000, "--steps", min=1, help="Steps (unless --minutes)."),
    minutes: float = typer.Option(0.0, "--minutes", min=0.0, help="Time budget; the lr decays over it."),
    batch: int = typer.Option(4, "--batch", min=1, help="Frame pairs per step."),
    crop: str = typer.Option("320x240", "--crop", help="Training crop WxH (multiples of 16)."),
    gaps: str = typer.Option("1,2,3,4", "--gaps", help="Frame gaps of the pairs."),
    blur_p: float = typer.Option(0.5, "--blur-p", min=0.0, max=1.0, help="Chance each image is motion-blurred."),
    lr: float = typer.Option(1e-3, "--lr"),
    target: str = typer.Option("corners", "--target", help="Detector labels: corners (Gaussian bumps on Harris "
                                                           "corners), harris (dense Harris response) or cells "
                                                           "(SuperPoint's 8x8-cell softmax on Harris corners)."),
    pos_weight: float = typer.Option(20.0, "--pos-weight", min=0.0, help="Weight of the BCE's positive term."),
    repeat_weight: float = typer.Option(0.0, "--repeat-weight", min=0.0,
                                        help="Weight of the repeatability loss (the second view's keypoint logits "
                                             "warped onto the first with the true depth and poses; 0 = off)."),
    repeat_patch: int = typer.Option(8, "--repeat-patch", min=2, help="Patch side (px) of the repeatability loss."),
    seed: int = typer.Option(0, "--seed", min=0),
    threads: int = typer.Option(1, "--threads", min=0, help="Torch threads (0 = torch's default)."),
    init: Path | None = typer.Option(None, "--init", help="Continue from this checkpoint (.pt, same --width) "
                                                          "instead of random weights."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress messages."),
) -> None:
    """Train FPFDCNN (SDF-SLAM): BCE detector on Harris corners, hinge descriptor loss."""
    from semslam.features.range_matcher import RangeMatcher
    from semslam.nets.train_fpfdcnn import FPTrainConfig, train

    if out.suffix != ".pt":
        raise ConfigError(f"train fpfdcnn: --out must end in .pt, got {out}")
    try:
        w, h = (int(v) for v in crop.lower().split("x"))
    except ValueError:
        raise ConfigError(f"--crop: expected WxH such as 320x240, got {crop!r}") from None
    cfg = FPTrainConfig(out=out, data=list(data), val=list(val), width=width, steps=steps, minutes=minutes,
                        batch=batch, crop=(w, h), gaps=_ints(gaps, "--gaps"), blur_p=blur_p, lr=lr, seed=seed,
                        target=target, pos_weight=pos_weight, repeat_weight=repeat_weight,
                        repeat_patch=repeat_patch, threads=threads, init=init)
    args = [x for d in data for x in ("--data", str(d))] + [x for v in val for x in ("--val", str(v))]
    args += ["--out", str(out), "--width", str(width), "--steps", str(steps), "--minutes", str(minutes),
             "--batch", str(batch), "--crop", crop, "--gaps", gaps, "--blur-p", str(blur_p), "--lr", str(lr),
             "--target", target, "--pos-weight", str(pos_weight),
             *(["--repeat-weight", str(repeat_weight), "--repeat-patch", str(repeat_patch)] if repeat_weight > 0 else []),
             "--seed", str(seed), "--threads", str(threads)] + (["--init", str(init)] if init is not None else [])
    cfg.command = shlex.join(["semslam", "train", "fpfdcnn", *args])
    say = (lambda msg: None) if quiet else (lambda msg: typer.echo(msg, err=True))
    meta = train(cfg, say, RangeMatcher().match)
    val_text = ""
    if "val" in meta:
        v = meta["val"]
        val_text = f", held-out correct matches clear {v['clear']['rate']:.3f} / blurred {v['blurred']['rate']:.3f}"
    typer.echo(f"{out}: FPFDCNN width {width}, {meta['steps']} steps in {meta['train_seconds']:.0f} s"
               f"{val_text}, {out.stat().st_size / 1e6:.2f} MB")


def register(app: typer.Typer) -> None:
    """Add ``fpfdcnn`` to the ``train`` group and make sure the group is on ``app``."""
    from semslam.cli import train_cmd

    if "fpfdcnn" not in {c.name for c in train_app.registered_commands}:
        train_app.command("fpfdcnn")(fpfdcnn_command)
    train_cmd.register(app)
