"""Entry point of the ``semslam`` console script.

Each command lives in its own module and registers itself on the app. Errors the user can
cause (``SemslamError``) are printed as one line naming the file and the problem (exit 2);
a run stopped by a signal exits 128 + its number (Ctrl-C 130, SIGTERM 143).
"""

from __future__ import annotations

import sys

import typer

import semslam.runtime
from semslam.errors import RunInterrupted, SemslamError

app = typer.Typer(
    name="semslam",
    help="Semantic visual SLAM for dynamic scenes.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def _register_commands() -> None:
    from semslam.cli import (bench_cmd, eval_cmd, eval_features_cmd, eval_map_cmd, eval_sdfcnn_cmd, map_cmd,
                             run_cmd, synth_cmd, train_cmd, train_fpfdcnn_cmd, train_nets_cmd, train_sdfcnn_cmd)
    from semslam.cli import export_onnx_cmd

    for module in (run_cmd, map_cmd, eval_cmd, eval_map_cmd, synth_cmd, train_cmd, train_nets_cmd, bench_cmd,
                   train_sdfcnn_cmd, eval_sdfcnn_cmd, train_fpfdcnn_cmd, eval_features_cmd, export_onnx_cmd):
        module.register(app)
    from semslam.cli import dataset_cmd  # semslam dataset list | get | path
    dataset_cmd.register(app)
    from semslam.cli import batch_cmd  # semslam batch PLAN.yaml (issue 14)
    batch_cmd.register(app)
    from semslam.cli import train_reproduce_cmd  # semslam train reproduce sdfcnn|fpfdcnn
    train_reproduce_cmd.register(app)


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; return the process exit code (2 for user errors)."""
    semslam.runtime.limit_threads()  # before the commands import numpy
    _register_commands()
    try:
        # Typer/click handle usage errors themselves (message + exit code 2) and end with
        # SystemExit; only our own errors need catching.
        app(args=argv, prog_name="semslam")
    except SemslamError as exc:
        typer.secho(f"error: {exc}", fg=typer.colors.RED, err=True)
        return 2
    except RunInterrupted as exc:  # a command without stop_on_signals: its exit code all the same
        typer.secho(f"interrupted: {exc}", fg=typer.colors.YELLOW, err=True)
        return exc.exit_code
    except KeyboardInterrupt:  # Ctrl-C outside a run (SIGTERM there ends the process: 143 to the shell)
        typer.echo("interrupted", err=True)
        return 130
    except SystemExit as exc:
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
