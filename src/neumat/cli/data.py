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


@app.command("texture-set")
def texture_set(kind: str = typer.Argument(..., help="scratches, brushed, foil, chainmail (strong normal and "
                                           "roughness detail), polished (a near-mirror metal, roughness 0.09) or "
                                           "bumps, weave, bricks, dents, ridges"),
                out: Path = typer.Option(..., "-o", "--out", help="output texture-set folder (created)"),
                size: int = typer.Option(256, min=16, help="texels a side"),
                seed: int = typer.Option(0, min=0, help="the random layout")) -> None:
    """Write a procedural PBR texture set (colour, OpenGL normals, roughness, metalness, displacement) as a
    folder that `neumat fit`, `eval`, `data btf-generate` and the benchmarks read like a downloaded set."""
    from ..io.texture_set import write_texture_set
    from ..reflectance.detail_texture import DETAIL_KINDS, POLISHED_KINDS, detail_texture_set
    from ..reflectance.procedural_texture import KINDS, procedural_texture_set

    def go():
        detail = DETAIL_KINDS + POLISHED_KINDS
        if kind not in detail + KINDS:
            from ..core.errors import InputError
            raise InputError(f"texture-set: unknown kind {kind!r}; expected one of {', '.join(detail + KINDS)}")
        textures = detail_texture_set(kind, size, seed) if kind in detail else procedural_texture_set(kind, size, seed)
        folder = write_texture_set(textures, out)
        print(f"wrote {textures.name} ({size}x{size} texels) to {folder}")
    run_command(go)


@app.command("texture-stats")
def texture_stats(folder: Path = typer.Argument(..., help="texture-set folder"),
                  crop: int = typer.Option(None, min=1, help="the CROP x CROP texels at full resolution from the "
                                                             "top-left corner or from --crop-origin"),
                  crop_origin: str = typer.Option(None, "--crop-origin", help="ROW,COL of the crop's first texel "
                                                  "(as `neumat fit --source-option crop_origin=ROW,COL`)"),
                  max_size: int = typer.Option(None, "--max-size", min=1, help="downscale to at most this size"),
                  footprints: str = typer.Option("1,4,16", help="footprints (texels) of the separability rank"),
                  samples: int = typer.Option(16, min=1, help="footprint samples per filtered value"),
                  json: bool = typer.Option(False, "--json", help="print one JSON object")) -> None:
    """The regime of a texture set for a multi-scale fit: normal tilt, roughness spread and the separability rank
    of its filtered appearance at each footprint (`neumat.reflectance.texture_statistics`: 1 = separable, as
    simple averages of albedos; 0 = no spatial variation above the noise; larger = position and direction
    coupled)."""
    from ..core.errors import InputError
    from ..io.texture_set import load_texture_set
    from ..reflectance.texture_statistics import texture_statistics

    def go():
        try:
            sizes = tuple(float(f) for f in footprints.split(","))
        except ValueError:
            raise InputError(f"--footprints: expected numbers separated by commas, got {footprints!r}") from None
        if not sizes or any(not f > 0 for f in sizes):
            raise InputError(f"--footprints: expected positive numbers of texels, got {footprints!r}")
        origin = None
        if crop_origin is not None:
            try:
                origin = tuple(int(v) for v in crop_origin.split(","))
            except ValueError:
                raise InputError(f"--crop-origin: expected ROW,COL (two integers), got {crop_origin!r}") from None
        stats = texture_statistics(load_texture_set(folder, max_size=max_size, crop=crop, crop_origin=origin), sizes,
                                   samples=samples)
        if json:
            print_json(stats)
            return
        rows = [{"statistic": k, "value": v} for k, v in stats.items() if k != "separability_rank"]
        rows += [{"statistic": f"separability rank at {f} texel(s)", "value": r}
                 for f, r in stats["separability_rank"].items()]
        print_table(f"texture statistics: {folder}", rows)
    run_command(go)


btf.register_data(app)
