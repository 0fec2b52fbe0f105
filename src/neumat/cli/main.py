"""The `neumat` command line."""
from __future__ import annotations

import typer

from . import (bench, btf, check, data, demo, exporting, fit_clusters, fit_many, fitting, listing, mitsuba, rendering,
               translucent)
from ..core.allocator import retain_freed_memory
from .common import add_threads, run_command

app = typer.Typer(help="neumat: compact learned models of material appearance.", no_args_is_help=True,
                  pretty_exceptions_enable=False, add_completion=False)
app.add_typer(data.app, name="data")
for module in (rendering, mitsuba, fitting, fit_many, fit_clusters, btf, check, demo, exporting, translucent, listing,
               bench):
    module.register(app)
add_threads(app, skip=("list", "version", "info", "bench"))


def _print_version(value: bool) -> None:
    if value:
        from ..core.version import __version__
        print(f"neumat {__version__}")
        raise typer.Exit()


@app.callback()
def main(version: bool = typer.Option(False, "--version", callback=_print_version, is_eager=True,
                                      help="print the neumat version and exit")) -> None:
    """neumat: compact learned models of material appearance."""
    retain_freed_memory()  # every command: large temporaries reused, not faulted in afresh (core/allocator.py)


@app.command()
def version() -> None:
    """Print the neumat version."""
    from ..core.version import __version__
    run_command(lambda: print(__version__))


if __name__ == "__main__":
    app()
