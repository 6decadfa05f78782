"""Entry point of the ``semslam`` console script.

Each command lives in its own module and registers itself on the app. Errors the user can
cause (``SemslamError``) are printed as one line naming the file and the problem.
"""

from __future__ import annotations

import os
import sys

# SLAM runs its own threads (tracking, local mapping, loop closing) and a BA process; BLAS
# and OpenCV worker pools on top of them only compete for the cores (measured on 2 cores:
# 36 -> 28 ms/frame median). Must be set before numpy loads; the environment overrides.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import typer

from semslam.errors import SemslamError

app = typer.Typer(
    name="semslam",
    help="Semantic visual SLAM for dynamic scenes.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def _register_commands() -> None:
    from semslam.cli import eval_cmd, run_cmd, synth_cmd, train_cmd

    for module in (run_cmd, eval_cmd, synth_cmd, train_cmd):
        module.register(app)


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; return the process exit code (2 for user errors)."""
    _register_commands()
    import cv2

    cv2.setNumThreads(int(os.environ.get("SEMSLAM_OPENCV_THREADS", "1")))
    try:
        # Typer/click handle usage errors themselves (message + exit code 2) and end with
        # SystemExit; only our own errors need catching.
        app(args=argv, prog_name="semslam")
    except SemslamError as exc:
        typer.secho(f"error: {exc}", fg=typer.colors.RED, err=True)
        return 2
    except KeyboardInterrupt:
        typer.echo("interrupted", err=True)
        return 130
    except SystemExit as exc:
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
