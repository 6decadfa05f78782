"""Entry point of the ``semslam`` console script.

Each command lives in its own module and registers itself on the app. Errors the user can
cause (``SemslamError``) are printed as one line naming the file and the problem.
"""

from __future__ import annotations

import sys

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
    from semslam.cli import eval_cmd, run_cmd, synth_cmd

    for module in (run_cmd, eval_cmd, synth_cmd):
        module.register(app)


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; return the process exit code (2 for user errors)."""
    _register_commands()
    try:
        app(args=argv, standalone_mode=False)
    except SemslamError as exc:
        typer.secho(f"error: {exc}", fg=typer.colors.RED, err=True)
        return 2
    except KeyboardInterrupt:
        typer.echo("interrupted", err=True)
        return 130
    except typer.Exit as exc:  # pragma: no cover - typer's own exits
        return exc.exit_code
    except Exception as exc:  # click usage errors carry their own message
        import click

        if isinstance(exc, click.exceptions.ClickException):
            exc.show()
            return exc.exit_code
        if isinstance(exc, click.exceptions.Abort):
            return 1
        raise
    return 0


if __name__ == "__main__":
    sys.exit(main())
