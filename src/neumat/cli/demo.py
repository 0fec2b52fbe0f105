"""`neumat demo`: the main job end to end — fit NeuBRDF to a measured material, render reference
and model side by side with a FLIP error map, write an HTML report and the model's web viewer page."""
from __future__ import annotations

from pathlib import Path

import typer

from .common import SEED_RANGE, console, device_option, print_table, run_command

#: RGL material fitted by default when the reference data is present
DEFAULT_RGL = "rgl/paper_white_rgb.bsdf"
#: environment map of the demo renders when the reference data is present (else the procedural sky)
DEFAULT_ENV = "envmap/studio_small_03_1k.hdr"
#: (wi, wo) pairs at which the reference is measured once before the fit
POOL_SIZE = 2 ** 18
#: measured-like fallback: an analytic plastic tabulated to the MERL layout
FALLBACK_SPEC = "plastic:diffuse=0.35/0.12/0.05,roughness=0.15,eta=1.5"


def register(app: typer.Typer) -> None:
    app.command()(demo)


def demo(out: Path = typer.Option(Path("out/demo"), "-o", "--out", help="output folder"),
         source: str = typer.Option(None, help="material to fit (default: a shared RGL material, else a "
                                                "MERL tabulation of an analytic plastic)"),
         steps: int = typer.Option(1000, min=1, help="training steps"),
         nside: int = typer.Option(16, min=1, help="HEALPix N_side of the NeuBRDF grids"),
         spp: int = typer.Option(32, min=1, help="samples per pixel of the renders"),
         resolution: int = typer.Option(256, min=16),
         device: str = typer.Option(None, callback=device_option,
                                   help="torch device (default: cuda if available, else cpu)"),
         seed: int = typer.Option(0, **SEED_RANGE)) -> None:
    """Fit NeuBRDF to a measured material, render reference | model | FLIP, write OUT/report.html."""
    run_command(lambda: run_demo(out, source, steps, nside, spp, resolution, device, seed))


def run_demo(out: Path, source: str | None, steps: int, nside: int, spp: int, resolution: int,
             device: str | None, seed: int) -> Path:
    """The demo job; returns the report path."""
    import time

    import torch

    from ..fit.measured_samples import MeasuredSamples
    from ..fit.recipe import recipe_for
    from ..fit.trainer import fit
    from ..io.images import write_image, write_image_ldr
    from ..catalog.modelfile import save_model
    from ..io.shared_data import shared_data_dir
    from ..export.web.viewer import write_viewer
    from ..metrics.hdr import cosine_queries, reflectance_errors
    from ..metrics.image import image_metrics
    from ..models.neubrdf import NeuBRDF
    from ..render.render import render
    from ..viz.compare import compare_image
    from ..viz.report import write_report
    from ..viz.slices import brdf_slice_image, polar_plot

    dev = device or ("cuda" if torch.cuda.is_available() else "cpu")
    data = shared_data_dir()
    reference, source_name = _reference(source, data, out)
    out.mkdir(parents=True, exist_ok=True)
    light = f"env:{data / DEFAULT_ENV}" if data is not None and (data / DEFAULT_ENV).is_file() else "env:sky"
    console.print(f"[bold]neumat demo[/]: fitting NeuBRDF (N_side {nside}) to {source_name} on {dev}")

    # measured sources are slow to evaluate: measure once on a pool of cosine-distributed queries, then replay it
    pool = cosine_queries(POOL_SIZE, torch.Generator().manual_seed(seed), torch.device("cpu"))
    samples = MeasuredSamples.from_material(reference, pool, name=source_name)
    torch.manual_seed(seed)
    model = NeuBRDF(nside=nside)
    recipe = recipe_for("neubrdf")
    recipe.seed = seed
    result = fit(model, samples, recipe, steps=steps, device=dev, progress=True, queries="replay")
    model = result.model.runtime()  # the paper's runtime form: frozen integer indices, 1/4 corner weights
    errors = reflectance_errors(model, reference, n=2 ** 18, seed=seed, device=dev)
    model_path = save_model(model, out / "neubrdf.nmat", recipe=recipe, source=source_name,
                            metrics={**errors, "fit_seconds": result.seconds})
    viewer = write_viewer(model, out / "viewer.html", title=f"NeuBRDF fitted to {source_name}")

    console.print(f"rendering reference and model ({resolution}x{resolution}, {spp} spp, {light})")
    images, times = {}, {}
    for name, material in (("reference", reference), ("NeuBRDF", model)):
        t0 = time.perf_counter()
        with torch.no_grad():
            images[name] = render(material, scene="sphere", light=light, spp=spp, resolution=resolution,
                                  seed=seed, device=dev, progress=True).cpu()
        times[name] = time.perf_counter() - t0
        write_image(out / f"{name.lower()}.exr", images[name])
    metrics = image_metrics(images["reference"], images["NeuBRDF"])
    picture = compare_image(images["reference"], {"NeuBRDF": images["NeuBRDF"]}, {"NeuBRDF": metrics})
    write_image_ldr(out / "compare.png", picture)

    summary = {"source": source_name, "nside": nside, "steps": result.steps, "fit_seconds": result.seconds,
               "bytes_fp16": model.size_bytes("fp16"), **errors, **{f"image_{k}": v for k, v in metrics.items()}}
    print_table("NeuBRDF against its reference", [{"quantity": k, "value": v} for k, v in summary.items()])
    report = write_report(out / "report.html", f"neumat demo: NeuBRDF fitted to {source_name}", [
        {"heading": "Sphere under an environment map",
         "text": f"Reference and model rendered identically ({resolution}x{resolution}, {spp} spp, {light}); "
                 f"the third panel is the FLIP error map. Render times: reference {times['reference']:.1f} s, "
                 f"model {times['NeuBRDF']:.1f} s.",
         "images": [("reference | NeuBRDF | FLIP", picture)]},
        {"heading": "Numbers", "table": [summary]},
        {"heading": "BRDF slices (theta_h x theta_d, phi_d = 90 deg, log scale)",
         "images": [("reference", brdf_slice_image(reference)), ("NeuBRDF", brdf_slice_image(model))]},
        {"heading": "In-plane BRDF (log scale)",
         "images": [("reference vs NeuBRDF", polar_plot({"reference": reference, "NeuBRDF": model}))]},
        {"heading": "Files", "text": f"model: {model_path.name}; images: reference.exr, neubrdf.exr, compare.png; "
                                     f"{viewer.name}: the model's GLSL export in an interactive WebGL 2 page"},
    ])
    console.print(f"[bold green]wrote[/] {report}")
    return report


def _reference(source: str | None, data: Path | None, out: Path):
    """(Material, display name): the user's source, a shared RGL file, or a MERL tabulation of a plastic."""
    from ..io.merl import write_merl
    from ..catalog.open_material import open_material
    from ..reflectance.tabulate import tabulate_merl

    if source is not None:
        return open_material(source), source
    if data is not None and (data / DEFAULT_RGL).is_file():
        path = data / DEFAULT_RGL
        return open_material(path), path.name
    path = out / "plastic.binary"
    if not path.is_file():
        out.mkdir(parents=True, exist_ok=True)
        write_merl(path, tabulate_merl(open_material(FALLBACK_SPEC), progress=True))
    return open_material(path, interpolate=True), f"{path.name} (MERL tabulation of {FALLBACK_SPEC})"
