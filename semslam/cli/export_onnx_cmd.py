"""``semslam export-onnx [CHECKPOINT ...]``: write networks' inference graphs as ONNX files,
which ONNX Runtime runs without torch (how the shipped ``semslam/data/*.onnx`` are made).

Without arguments it re-exports the shipped checkpoints (``semslam/data/*.pt``) next to
themselves. Needs torch and onnx (``pip install 'semslam[train]'``). Each file is checked
after writing: ONNX Runtime and torch run a random image at two sizes and the largest
output difference is printed.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from semslam.errors import ConfigError

#: The checkpoints shipped in ``semslam/data`` (the ``.onnx`` files are made from them).
SHIPPED = ("stdc_person.pt", "dunet_person.pt", "sdfcnn.pt", "fpfdcnn.pt")


def export_all(checkpoints: list[Path], out_dir: Path | None, half: bool) -> list[dict]:
    """Export each checkpoint to ``out_dir`` (default: its own folder) as ``<stem>.onnx``."""
    try:
        import onnx  # noqa: F401 - the exporter's file handling

        from semslam.nets.onnx_graphs import export_onnx
    except ImportError as exc:
        raise ConfigError(f"export-onnx needs torch and onnx ({exc.name} is missing): "
                          "pip install 'semslam[train]'") from None
    results = []
    for ckpt in checkpoints:
        if ckpt.suffix != ".pt":
            raise ConfigError(f"export-onnx: {ckpt} is not a .pt checkpoint")
        out = (out_dir or ckpt.parent) / f"{ckpt.stem}.onnx"
        results.append(export_onnx(ckpt, out, half=half))
    return results


def register(app: typer.Typer) -> None:
    @app.command("export-onnx")
    def export_onnx_command(
        checkpoints: Optional[list[Path]] = typer.Argument(None, help="checkpoints (.pt) to export; default: "
                                                                      "the shipped semslam/data/*.pt"),
        out: Optional[Path] = typer.Option(None, "--out", "-o", help="folder for the .onnx files (default: "
                                                                    "next to each checkpoint)"),
        fp32: bool = typer.Option(False, "--fp32", help="store every weight as float32 (default: float16 "
                                                       "where that is exact)"),
    ) -> None:
        """Export networks to ONNX for torch-free inference (needs the train extra)."""
        if not checkpoints:
            data = Path(__file__).resolve().parents[1] / "data"
            checkpoints = [data / name for name in SHIPPED]
        for r in export_all(list(checkpoints), out, half=not fp32):
            typer.echo(f"{r['path']}: {r['arch']}, {r['bytes'] / 1e6:.2f} MB, max |onnxruntime - torch| "
                       f"{r['max_abs_diff']:.1e}")
