"""Command-line interface: one module per command, registered on one Typer app."""
