"""`neumat data`: inspect and convert material files."""
from __future__ import annotations

from pathlib import Path

import typer

from . import btf
from .common import output_option, print_json, print_table, run_command

app = typer.Typer(help="Inspect and convert material data.", no_args_is_help=True)


@app.command()
def info(file: str = typer.Argument(..., help="material file (.binary, .bsdf, .nmat), image or analytic spec"),
         json: bool = typer.Option(False, "--json", help="print one JSON object")) -> None:
    """Kind, resolution, value range, validity and size on disk of FILE."""
    from ..catalog.describe import describe

    def go():
        d = describe(file)
        print_json(d) if json else print_table(str(file), [{"field": k, "value": v} for k, v in d.items()])
    run_command(go)


@app.command()
def convert(source: str = typer.Argument(..., help="any BRDF: RGL .bsdf, NBRDF .h5, .nmat or analytic spec"),
            out: Path = typer.Option(..., "-o", "--out", callback=output_option(".binary"),
                                     help="output MERL .binary file"),
            quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress output")) -> None:
    """Tabulate any BRDF to the MERL layout and write it as .binary."""
    from ..io.merl import write_merl
    from ..catalog.open_material import open_material
    from ..reflectance.tabulate import tabulate_merl

    def go():
        if out.suffix.lower() != ".binary":
            from ..core.errors import InputError
            raise InputError(f"output {out}: only MERL .binary output is supported")
        table = tabulate_merl(open_material(source), progress=not quiet)
        write_merl(out, table)
        print(f"wrote {out} ({out.stat().st_size} bytes)")
    run_command(go)


btf.register_data(app)
