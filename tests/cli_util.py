"""Helpers shared by the CLI tests that run commands on a local typer app (independent of cli/main.py)."""
from __future__ import annotations

import typer

from neumat.cli import fitting


def output_text(result) -> str:
    """A CliRunner result's output with rich's line wrapping undone."""
    return " ".join(result.output.split())


def fitting_app() -> typer.Typer:
    """A typer app with only `neumat fit` and `neumat eval`."""
    app = typer.Typer(pretty_exceptions_enable=False, add_completion=False)
    fitting.register(app)
    return app
