"""`neumat demo`: the main job end to end — fit NeuBRDF to a material with the preset `neumat fit` uses, render
reference and the shipped model side by side with a FLIP error map, write an HTML report, `metrics.json` and the
model's web viewer page (the same shipped form).

The renders are lit by three directional lights: with delta lights every pixel sample of the direct
illumination is exact (no Monte Carlo noise; only the sub-pixel positions of anti-aliasing are random), so the
reference is converged at a few samples per pixel and the image metrics measure the model's error. The noise
floor printed beside them is the same metric between two renders of the reference with different seeds.
"""
from __future__ import annotations

import json
from pathlib import Path

import typer

from ..core.threads import shared_threads
from .common import SEED_RANGE, THREADS_HELP, console, device_option, parse_overrides, print_table, run_command

#: default material: a smooth analytic plastic (exact values, no table to interpolate)
DEFAULT_SOURCE = "plastic:diffuse=0.35/0.12/0.05,roughness=0.2,eta=1.5"
#: key, fill and rim lights of the renders: (direction towards the light, irradiance RGB)
LIGHTS = (((-0.6, 0.8, 0.9), (3.0, 2.8, 2.5)), ((0.9, 0.2, 0.5), (0.8, 0.9, 1.1)), ((0.3, 0.9, -0.4), (2.0, 2.0, 2.0)))
#: the paper's budget (Dou et al. 2024, Sec. 4; our recipe `neumat.methods.neubrdf.train`): N_side, steps, batch
PAPER_NSIDE, PAPER_STEPS, PAPER_BATCH = 64, 20000, 2 ** 14
#: SSIM the paper reports over MERL renders (Table 3)
PAPER_SSIM = 0.996


def register(app: typer.Typer) -> None:
    app.command()(demo)


def demo(out: Path = typer.Option(Path("out/demo"), "-o", "--out", help="output folder"),
         source: str = typer.Option(DEFAULT_SOURCE, help="material to fit (a spec, or a MERL / RGL file)"),
         preset: str = typer.Option(None, "--preset", help="a NeuBRDF preset, as `neumat fit --preset` (default: "
                                                         "recommended, what we would ship)"),
         set_: list[str] = typer.Option(None, "--set", help="key=value, as `neumat fit --set`"),
         steps: int = typer.Option(None, min=1, help="training steps (default: the preset's)"),
         spp: int = typer.Option(16, min=1, help="samples per pixel of the renders (anti-aliasing only)"),
         resolution: int = typer.Option(256, min=16),
         device: str = typer.Option(None, callback=device_option,
                                   help="torch device (default: cuda if available, else cpu)"),
         seed: int = typer.Option(0, **SEED_RANGE),
         threads: int = typer.Option(None, min=1, help=THREADS_HELP),
         quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress output (the last line stays)")) -> None:
    """Fit NeuBRDF to a material as `neumat fit` does, render reference | shipped model | FLIP, write
    OUT/report.html, OUT/metrics.json and OUT/viewer.html."""
    with shared_threads(threads):
        run_command(lambda: run_demo(out, source, preset, parse_overrides(set_), steps, spp, resolution, device,
                                     seed, quiet))


def run_demo(out: Path, source: str, preset: str | None, overrides: dict, steps: int | None, spp: int,
             resolution: int, device: str | None, seed: int, quiet: bool = False) -> Path:
    """The demo job; returns the report path."""
    import time

    from ..catalog.modelfile import save_model
    from ..catalog.open_material import open_material
    from ..export.web.viewer import write_viewer
    from ..fit.preset import DEFAULT_PRESET, build_fit
    from ..fit.trainer import fit
    from ..io.images import write_image, write_image_ldr
    from ..metrics.hdr import reflectance_errors
    from ..metrics.image import image_metrics
    from ..viz.compare import compare_image
    from ..viz.report import write_report
    from ..viz.slices import brdf_slice_image, brdf_slice_range, polar_plot
    from .fitting import preset_note, resolve_device

    start = time.perf_counter()
    dev = resolve_device(device)
    reference = open_material(source)
    out.mkdir(parents=True, exist_ok=True)
    say = (lambda text, **kw: None) if quiet else console.print
    model, resolved = build_fit("neubrdf", preset or DEFAULT_PRESET, device=dev, source=reference,
                                overrides=overrides, seed=seed)
    say(f"[bold]neumat demo[/]: fitting NeuBRDF to {source} on {dev}")
    say(preset_note("neubrdf", resolved), markup=False)
    result = fit(model, reference, resolved.recipe, steps=steps, device=dev, progress=not quiet)
    model = result.model.runtime()  # the shipped form: what the file, the renders and the viewer hold
    errors = reflectance_errors(model, reference, n=2 ** 18, seed=seed, device=dev)
    model_path = save_model(model, out / "neubrdf.nmat", recipe=result.recipe, source=source,
                            metrics={**errors, "fit_seconds": result.seconds},
                            preset={"name": resolved.preset, "overrides": resolved.applied})
    viewer = write_viewer(model, out / "viewer.html", title=f"NeuBRDF fitted to {source}")
    cfg, recipe = model.cfg, result.recipe

    say(f"rendering reference (twice, for the noise floor) and model ({resolution}x{resolution}, {spp} spp)")
    images, times = {}, {}
    for name, material, s in (("reference", reference, seed), ("reference, seed + 1", reference, seed + 1),
                              ("NeuBRDF", model, seed + 2)):
        t0 = time.perf_counter()
        images[name] = _render(material, spp, resolution, s, dev)
        times[name] = time.perf_counter() - t0
    write_image(out / "reference.exr", images["reference"])
    write_image(out / "neubrdf.exr", images["NeuBRDF"])
    metrics = image_metrics(images["reference"], images["NeuBRDF"])
    floor = image_metrics(images["reference"], images["reference, seed + 1"])
    shown = {"flip": metrics["flip"], "noise floor flip": floor["flip"], "ssim": metrics["ssim"],
             "noise floor ssim": floor["ssim"]}
    picture = compare_image(images["reference"], {"NeuBRDF": images["NeuBRDF"]}, {"NeuBRDF": shown})
    write_image_ldr(out / "compare.png", picture)

    summary = {"source": source, "flip": metrics["flip"], "ssim": metrics["ssim"], "psnr": metrics["psnr"],
               "noise_floor_flip": floor["flip"], "noise_floor_ssim": floor["ssim"], "preset": resolved.preset,
               "nside": cfg.nside, "features": cfg.features, "direction_inputs": cfg.direction_inputs,
               "steps": result.steps, "batch": recipe.batch_size, "fit_seconds": result.seconds,
               "bytes_fp16": model.size_bytes("fp16"), **{f"brdf_{k}": v for k, v in errors.items()},
               "spp": spp, "resolution": resolution}
    budget = (f"Model: {resolved.describe()}: N_side {cfg.nside}, {cfg.features} features, direction inputs "
              f"{cfg.direction_inputs}, {model.size_bytes('fp16'):,} bytes at fp16. Budget: {result.steps} steps of "
              f"{recipe.batch_size} queries ({result.steps * recipe.batch_size / (PAPER_STEPS * PAPER_BATCH):.1%} of "
              f"the {PAPER_STEPS} x {PAPER_BATCH} target evaluations of the paper's recipe) in "
              f"{result.seconds:.0f} s on {dev}. The paper trains N_side {PAPER_NSIDE} with a 2^9-row codebook on a "
              f"GPU and reports SSIM {PAPER_SSIM} averaged over renders of the MERL materials; `--preset paper` "
              f"runs its exact model and recipe.")
    slice_range = brdf_slice_range([reference, model])
    summary["total_seconds"] = time.perf_counter() - start
    (out / "metrics.json").write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    print_table("NeuBRDF against its reference", [{"quantity": k, "value": v} for k, v in summary.items()])
    report = write_report(out / "report.html", f"neumat demo: NeuBRDF fitted to {source}", [
        {"heading": "Sphere under three directional lights",
         "text": f"Reference and model rendered identically ({resolution}x{resolution}, {spp} spp, key, fill and "
                 f"rim directional lights); the third panel is the FLIP error map. With delta lights each pixel "
                 f"sample is exact, so the reference is converged; the noise floor is the same metric between "
                 f"two reference renders with different seeds (only the anti-aliasing differs). "
                 f"Image FLIP {metrics['flip']:.4f} (noise floor {floor['flip']:.4f}), SSIM {metrics['ssim']:.4f} "
                 f"(noise floor {floor['ssim']:.4f}). Render times: reference {times['reference']:.1f} s, model "
                 f"{times['NeuBRDF']:.1f} s.\n\n{budget}",
         "images": [("reference | NeuBRDF | FLIP", picture)]},
        {"heading": "Numbers", "table": [{"quantity": k, "value": v} for k, v in summary.items()]},
        {"heading": "BRDF slices (theta_h x theta_d, phi_d = 90 deg, one shared log colour scale)",
         "images": [("reference", brdf_slice_image(reference, value_range=slice_range)),
                    ("NeuBRDF", brdf_slice_image(model, value_range=slice_range))]},
        {"heading": "In-plane BRDF (log scale)",
         "images": [("reference vs NeuBRDF", polar_plot({"reference": reference, "NeuBRDF": model}))]},
        {"heading": "Files", "text": f"model: {model_path.name} (the shipped runtime form, rendered above); "
                                     f"metrics.json; images: reference.exr, neubrdf.exr, compare.png; "
                                     f"{viewer.name}: the same model's GLSL export in an interactive WebGL 2 page"},
    ])
    console.print(f"[bold green]wrote[/] {report} ({summary['total_seconds']:.0f} s)")
    return report


def _render(material, spp: int, resolution: int, seed: int, device: str):
    """(H, W, 3) CPU image of the sphere under LIGHTS: the sum of one exact light-sampled render per light."""
    import torch

    from ..render.lights import DirectionalLight
    from ..render.render import render

    with torch.no_grad():
        return sum(render(material, scene="sphere", light=DirectionalLight(d, e, device=device), strategy="light",
                          spp=spp, resolution=resolution, seed=seed + 7 * k, device=device).cpu()
                   for k, (d, e) in enumerate(LIGHTS))
