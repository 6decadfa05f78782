"""``semslam train sdfcnn``: train SDF-SLAM's joint depth + segmentation network on CPU.

Joins the ``train`` group of :mod:`semslam.cli.train_cmd`; torch is imported only when the
command runs. Data: TUM-layout folders with depth and ``semantic/`` labels (``semslam
synth`` renders, or NYU-40 label folders). The command that made the shipped weights is in
``semslam/data/NETS.md`` and inside the checkpoint.
"""

from __future__ import annotations

import shlex
from pathlib import Path

import typer

from semslam.cli.train_cmd import train_app
from semslam.cli.train_nets_cmd import _size
from semslam.errors import ConfigError


def sdfcnn_command(
    ctx: typer.Context,
    out: Path = typer.Option(..., "--out", "-o", help="Checkpoint to write (.pt)."),
    data: list[Path] = typer.Option([], "--data", help="TUM-layout folder with depth and semantic/ (training); "
                                                      "repeatable."),
    val: list[Path] = typer.Option([], "--val", help="Held-out folder for validation; repeatable "
                                                    "(default: every 10th training frame)."),
    epochs: int = typer.Option(10, "--epochs", min=1),
    batch: int = typer.Option(8, "--batch", min=1),
    size: str = typer.Option("320x240", "--size", help="Training size WxH = Layer 0's size (paper: 400x300)."),
    width: float = typer.Option(0.5, "--width", help="Channel multiplier (1.0 = Table 13)."),
    lr: float = typer.Option(2e-3, "--lr", help="Peak learning rate (AdamW)."),
    lam: float = typer.Option(0.4, "--lambda", help="Eq. 21's weight of the segmentation loss."),
    every: int = typer.Option(1, "--every", min=1, help="Use every N-th frame of --data folders."),
    seed: int = typer.Option(0, "--seed", min=0),
    threads: int = typer.Option(0, "--threads", min=0, help="Torch threads (0 = all cores)."),
    minutes: float = typer.Option(0.0, "--minutes", min=0.0, help="Time budget; lr decays by time, then stop."),
    fp32: bool = typer.Option(False, "--fp32", help="Store float32 weights (default float16)."),
    camera: float = typer.Option(0.0, "--camera", min=0.0, max=1.0,
                                 help="Share of training samples given a real camera's defects (exposure, "
                                 "white balance, blur, noise, JPEG)."),
    init: Path = typer.Option(None, "--init", help="Start from these weights (same width)."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar."),
) -> None:
    """Train SDFCNN (SDF-SLAM, Table 13): 40 NYU classes + metric depth, loss eq. 21."""
    from semslam.nets.train_sdfcnn import SdfTrainConfig, train_sdfcnn

    if out.suffix != ".pt":
        raise ConfigError(f"train sdfcnn: --out must end in .pt, got {out}")
    cfg = SdfTrainConfig(out=out, data=list(data), val=list(val), epochs=epochs, batch=batch,
                         size=_size(size, "--size"), width=width, lr=lr, lam=lam, every=every, seed=seed,
                         threads=threads, minutes=minutes, half=not fp32, init=init, camera=camera,
                         command=command_line(ctx))
    say = (lambda msg: None) if quiet else (lambda msg: typer.echo(msg, err=True))
    meta = train_sdfcnn(cfg, progress=not quiet, say=say)
    v = meta["val"]
    typer.echo(
        f"{out}: sdfcnn width {meta['width']}, {meta['parameters']:,} parameters, {meta['epochs']} epochs / "
        f"{meta['steps']} steps in {meta['train_seconds']:.0f} s; val MPA {v['mpa']:.3f} MIoU {v['miou']:.3f} "
        f"RMS {v['rms']:.3f} m REL {v['rel']:.3f} delta1 {v['delta1']:.3f}; {out.stat().st_size / 1e6:.2f} MB"
    )


def command_line(ctx: typer.Context) -> str:
    """The command as run, rebuilt from its parsed options (also right when called as a function)."""
    args = ["semslam", "train", "sdfcnn"]
    for param in ctx.command.params:
        value = ctx.params.get(param.name or "")
        flag = param.opts[0]
        if value is None or value is False or value == []:
            continue
        if value is True:
            args.append(flag)
        else:
            args += [x for v in (value if isinstance(value, (list, tuple)) else [value]) for x in (flag, str(v))]
    return shlex.join(args)


def register(app: typer.Typer) -> None:
    """Add ``sdfcnn`` to the ``train`` group and make sure the group is on ``app``."""
    from semslam.cli import train_cmd

    if "sdfcnn" not in {c.name for c in train_app.registered_commands}:
        train_app.command("sdfcnn")(sdfcnn_command)
    train_cmd.register(app)
