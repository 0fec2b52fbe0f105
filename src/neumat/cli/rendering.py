"""`neumat render` and `neumat compare`."""
from __future__ import annotations

from pathlib import Path

import typer

from .common import (IMAGE_OUT, SEED_RANGE, device_option, output_option, parse_overrides, print_json, print_table,
                     run_command)

SCENE_HELP = "sphere | plane | mesh:PATH"
LIGHT_HELP = "point[:x/y/z] | dir[:x/y/z] | const:VALUE | env:PATH | env:sky"


def register(app: typer.Typer) -> None:
    app.command()(render)
    app.command()(compare)


def render(material: str = typer.Argument(..., help="material file (.binary, .bsdf, .nmat) or analytic spec"),
           scene: str = typer.Option("sphere", help=SCENE_HELP),
           light: str = typer.Option("env:sky", help=LIGHT_HELP),
           spp: int = typer.Option(64, min=1, help="samples per pixel"),
           resolution: int = typer.Option(256, min=8, help="image width and height in pixels"),
           strategy: str = typer.Option("mis", help="mis | light | material | mis-lobes (a fixed lobe mixture "
                                                    "instead of the material's sampler)"),
           sampler: str = typer.Option("random", help="random | sobol (shifted quasi-random points per pixel)"),
           device: str = typer.Option(None, callback=device_option,
                                                 help="torch device (default: cuda if available, else cpu)"),
           seed: int = typer.Option(0, **SEED_RANGE),
           quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress output"),
           out: Path = typer.Option(..., "-o", "--out", callback=output_option(*IMAGE_OUT),
                                    help="output image (.png, .exr, .hdr)")) -> None:
    """Render MATERIAL on a scene under a light and write the image."""
    from ..io.images import write_image
    from ..catalog.open_material import open_material
    from ..render.render import render as render_image

    def go():
        m = open_material(material)
        img = render_image(m, scene=scene, light=light, spp=spp, resolution=(resolution, resolution),
                           strategy=strategy, sampler=sampler, seed=seed, device=device, progress=not quiet)
        write_image(out, img)
        print(f"wrote {out}")
    run_command(go)


def compare(materials: list[str] = typer.Argument(..., help="reference first, then the materials to compare"),
            scene: str = typer.Option("sphere", help=SCENE_HELP),
            light: str = typer.Option("env:sky", help=LIGHT_HELP),
            spp: int = typer.Option(64, min=1),
            resolution: int = typer.Option(256, min=8),
            n_configs: int = typer.Option(2 ** 18, help="random (wi, wo) configurations for reflectance errors"),
            source_option: list[str] = typer.Option(None, "--source-option",
                                                    help="key=value passed to the reader of the reference (the "
                                                         "first material), as `neumat fit` takes them, e.g. "
                                                         "max_size=64"),
            device: str = typer.Option(None, callback=device_option),
            seed: int = typer.Option(0, **SEED_RANGE),
            json: bool = typer.Option(False, "--json", help="print one JSON object instead of a table"),
            quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress output"),
            out: Path = typer.Option(None, "-o", "--out", callback=output_option(".png", ".jpg", ".jpeg"),
                                    help="comparison picture (.png)")) -> None:
    """Render the reference and every other material identically (the same directions: a fixed lobe mixture and
    light sampling, quasi-random points); print image and reflectance metrics, and the reference against itself
    scored the same way (its noise floor: image errors near it are noise). Protocol: every material at --spp with
    --seed, scored against the reference at 16x --spp with the next seed (neumat.render.comparison)."""
    from ..core.errors import InputError
    from ..catalog.open_material import open_material
    from ..metrics.hdr import reflectance_errors
    from ..metrics.image import image_metrics
    from ..render.comparison import COMPARISON_SAMPLING, FLOOR_NAME, PROTOCOL, REFERENCE_FACTOR
    from ..render.render import render as render_image

    def go():
        if len(materials) < 2:
            raise InputError("compare needs a reference and at least one other material")
        options = parse_overrides(source_option, "--source-option")
        mats = {name: open_material(name, **(options if i == 0 else {})) for i, name in enumerate(materials)}
        opts = dict(scene=scene, light=light, spp=spp, resolution=(resolution, resolution), device=device,
                    progress=not (json or quiet), **COMPARISON_SAMPLING)
        imgs = {name: render_image(m, seed=seed, **opts) for name, m in mats.items()}
        ref_name = materials[0]
        converged = render_image(mats[ref_name], seed=seed + 1, **{**opts, "spp": REFERENCE_FACTOR * spp})
        floor = image_metrics(converged, imgs[ref_name])
        rows = []
        for name in materials[1:]:
            row = {"material": name, **image_metrics(converged, imgs[name])}
            row.update(reflectance_errors(mats[name], mats[ref_name], n=n_configs, seed=seed, device=device))
            rows.append(row)
        if out is not None:
            from ..viz.compare import compare_image
            from ..io.images import write_image_ldr
            values = {r["material"]: {k: v for k, v in r.items() if k != "material"} for r in rows}
            write_image_ldr(out, compare_image(imgs[ref_name], {n: imgs[n] for n in materials[1:]}, values))
        if json:
            print_json({"reference": ref_name, "results": rows, "floor": floor, "protocol": PROTOCOL})
        else:  # one row per metric, one column per material and the floor: readable at 80 columns
            print_table(f"against {ref_name} ({PROTOCOL})", [{"metric": k, **{r["material"]: r[k] for r in rows},
                                                 FLOOR_NAME: floor.get(k, "")} for k in rows[0] if k != "material"])
    run_command(go)
