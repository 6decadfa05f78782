"""``semslam train stdc`` / ``semslam train dunet``: train the segmentation networks on CPU.

Both subcommands join the ``train`` group of :mod:`semslam.cli.train_cmd`. Torch is
imported only when a command runs. Example (synthetic data rendered with ``semslam
synth``; one sequence held out for validation)::

    semslam train stdc --data /tmp/seq_a --data /tmp/seq_b --val /tmp/seq_c \\
        --out stdc_person.pt --epochs 8 --batch 8 --size 320x240 --width 0.375
"""

from __future__ import annotations

import shlex
import sys
from pathlib import Path

import typer

from semslam.cli.train_cmd import train_app
from semslam.errors import ConfigError


def _size(text: str, flag: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ConfigError(f"{flag}: expected WxH such as 320x240, got {text!r}") from None
    if w < 16 or h < 16:
        raise ConfigError(f"{flag}: {text} is too small")
    return w, h


def _run(arch: str, out: Path, data: list[Path], voc: list[Path], val: list[Path], epochs: int, batch: int,
         size: str, crop: str, width: float, lr: float, classes: str, other: str, every: int, seed: int,
         threads: int, minutes: float, fp32: bool, quiet: bool, init: Path | None,
         options: dict | None = None) -> None:
    from semslam.nets.datasets import ClassSet
    from semslam.nets.train import TrainConfig, train

    if out.suffix != ".pt":
        raise ConfigError(f"train {arch}: --out must end in .pt, got {out}")
    cfg = TrainConfig(
        arch=arch, out=out, data=list(data), voc=list(voc), val=list(val),
        classes=ClassSet.parse(classes, other), epochs=epochs, batch=batch,
        size=_size(size, "--size"), crop=_size(crop, "--crop") if crop else None, width=width, lr=lr,
        every=every, seed=seed, threads=threads, minutes=minutes, half=not fp32, options=options or {}, init=init,
        command=shlex.join(["semslam", *sys.argv[1:]]),
    )
    say = (lambda msg: None) if quiet else (lambda msg: typer.echo(msg, err=True))
    meta = train(cfg, progress=not quiet, say=say)
    names = ", ".join(f"{n} {v:.3f}" for n, v in zip(meta["class_names"], meta["val_iou"]) if v is not None)
    typer.echo(
        f"{out}: {meta['arch']} width {meta['width']}, {meta['inference_parameters']:,} parameters, "
        f"{meta['epochs']} epochs / {meta['steps']} steps in {meta['train_seconds']:.0f} s, "
        f"val mIoU {meta['val_miou']:.4f} ({names}), {out.stat().st_size / 1e6:.2f} MB"
    )


_DATA = typer.Option([], "--data", help="TUM-layout folder with semantic/ labels (training); repeatable.")
_VOC = typer.Option([], "--voc", help="VOC folder (JPEGImages/ + SegmentationClass/); repeatable.")
_VAL = typer.Option([], "--val", help="TUM-layout folder for validation; repeatable (default: hold out 1/10).")
_CLASSES = typer.Option("0:background,15:person", "--classes",
                        help="Classes as id:name list (ids of the label PNGs; first must be 0), or 'voc'.")
_OTHER = typer.Option("background", "--other", help="Label ids not in --classes: 'background' or 'ignore'.")


def stdc_command(
    out: Path = typer.Option(..., "--out", "-o", help="Checkpoint to write (.pt)."),
    data: list[Path] = _DATA,
    voc: list[Path] = _VOC,
    val: list[Path] = _VAL,
    epochs: int = typer.Option(10, "--epochs", min=1),
    batch: int = typer.Option(8, "--batch", min=1),
    size: str = typer.Option("320x240", "--size", help="Network input WxH (multiples of 8)."),
    crop: str = typer.Option("", "--crop", help="Training crop WxH (default: --size)."),
    width: float = typer.Option(0.5, "--width", help="Channel multiplier (1.0 = STDC1-Seg)."),
    lr: float = typer.Option(2e-3, "--lr", help="Peak learning rate (AdamW)."),
    classes: str = _CLASSES,
    other: str = _OTHER,
    every: int = typer.Option(1, "--every", min=1, help="Use every N-th frame of --data folders."),
    seed: int = typer.Option(0, "--seed", min=0),
    threads: int = typer.Option(0, "--threads", min=0, help="Torch threads (0 = all cores)."),
    minutes: float = typer.Option(0.0, "--minutes", min=0.0, help="Time budget; lr decays by time, then stop."),
    fp32: bool = typer.Option(False, "--fp32", help="Store float32 weights (default float16)."),
    init: Path = typer.Option(None, "--init", help="Start from these weights (same architecture/width)."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar."),
) -> None:
    """Train STDC1-Seg (STDC-SLAM's network) with detail guidance."""
    _run("stdc1", out, data, voc, val, epochs, batch, size, crop, width, lr, classes, other, every, seed,
         threads, minutes, fp32, quiet, init)


def dunet_command(
    out: Path = typer.Option(..., "--out", "-o", help="Checkpoint to write (.pt)."),
    data: list[Path] = _DATA,
    voc: list[Path] = _VOC,
    val: list[Path] = _VAL,
    epochs: int = typer.Option(10, "--epochs", min=1),
    batch: int = typer.Option(8, "--batch", min=1),
    size: str = typer.Option("320x240", "--size", help="Network input WxH (multiples of 16)."),
    crop: str = typer.Option("", "--crop", help="Training crop WxH (default: --size); smaller is much faster."),
    width: float = typer.Option(0.25, "--width", help="Channel multiplier (1.0 = 64..512 channels; "
                                                      "0.25 = the DUNet code's default)."),
    lr: float = typer.Option(2e-3, "--lr", help="Peak learning rate (AdamW)."),
    classes: str = _CLASSES,
    other: str = _OTHER,
    every: int = typer.Option(1, "--every", min=1, help="Use every N-th frame of --data folders."),
    seed: int = typer.Option(0, "--seed", min=0),
    threads: int = typer.Option(0, "--threads", min=0, help="Torch threads (0 = all cores)."),
    minutes: float = typer.Option(0.0, "--minutes", min=0.0, help="Time budget; lr decays by time, then stop."),
    fp32: bool = typer.Option(False, "--fp32", help="Store float32 weights (default float16)."),
    modulation: bool = typer.Option(False, "--modulation", help="DCNv2 blocks (default DCNv1, as Jin et al.)."),
    init: Path = typer.Option(None, "--init", help="Start from these weights (same architecture/width)."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar."),
) -> None:
    """Train DUNet (DDL-SLAM's deformable U-Net)."""
    _run("dunet", out, data, voc, val, epochs, batch, size, crop, width, lr, classes, other, every, seed,
         threads, minutes, fp32, quiet, init, {"modulation": modulation})


def register(app: typer.Typer) -> None:
    """Add ``stdc`` and ``dunet`` to the ``train`` group and make sure the group is on ``app``."""
    from semslam.cli import train_cmd

    have = {c.name for c in train_app.registered_commands}
    if "stdc" not in have:
        train_app.command("stdc")(stdc_command)
    if "dunet" not in have:
        train_app.command("dunet")(dunet_command)
    train_cmd.register(app)
