"""`neumat translucent trace | fit | render`: NeuPreSS on a path-traced translucent object (Mitsuba 3)."""
from __future__ import annotations

from pathlib import Path

import typer

from .common import IMAGE_OUT, SEED_RANGE, device_option, output_option, print_table, run_command

app = typer.Typer(help="Translucent objects (NeuPreSS): trace observations with Mitsuba 3, fit, render.",
                  no_args_is_help=True)


def register(main: typer.Typer) -> None:
    """Add the `translucent` sub-app to the main app."""
    main.add_typer(app, name="translucent")


def object_shape(scene: str) -> str:
    """TranslucentConfig.shape of a --scene value: 'sphere', or the path of `mesh:PATH`."""
    if scene == "sphere":
        return scene
    if scene.startswith("mesh:") and scene[5:]:
        return scene[5:]
    from ..core.errors import InputError
    raise InputError(f"--scene: expected 'sphere' or mesh:PATH (a closed PLY mesh), got {scene!r}")


def environment_map(light: str) -> str:
    """'sky' or the map's path, from a --light value env:sky / env:PATH."""
    if light.startswith("env:") and light[4:]:
        return light[4:]
    from ..core.errors import InputError
    raise InputError(f"--light: translucent renders take an environment, env:sky or env:PATH (.hdr / .exr), "
                     f"got {light!r}")


@app.command()
def trace(out: Path = typer.Option(..., "-o", "--out", callback=output_option(".npz"),
                               help="observations file to write (.npz)"),
          scene: str = typer.Option("sphere", help="the object: 'sphere' or mesh:PATH (a closed PLY triangle mesh)"),
          media: str = typer.Option("marble,ketchup", help="the two Jensen et al. media the noise mixes, A,B"),
          size_mm: float = typer.Option(4.0, help="millimetres across the bounding-box diagonal (smaller: more "
                                                   "translucent)"),
          roughness: float = typer.Option(0.3, help="GGX alpha of the dielectric surface"),
          images: int = typer.Option(1500, min=1, help="views, each with its own light direction"),
          resolution: int = typer.Option(32, min=1, help="rays per side of each view"),
          spp: int = typer.Option(32, min=1, help="paths per ray (Mitsuba calls cost ~20 ms each: "
                                                  "32 is ~1.7x the time of 8)"),
          seed: int = typer.Option(0, **SEED_RANGE),
          quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress output")) -> None:
    """Path-trace training observations of S_hat under random directional lights (NeuPreSS Sec. 4.2)."""
    def go():
        from ..core.config import config_to_dict
        from ..fit.translucent_observations import collect_observations
        from ..reflectance.translucent import TranslucentConfig, TranslucentObject

        _check_suffix(out, ".npz", "trace OUT")
        cfg = TranslucentConfig(shape=object_shape(scene), media=tuple(m.strip() for m in media.split(",")), size_mm=size_mm,
                                roughness=roughness)
        obj = TranslucentObject(cfg, spp=spp, seed=seed)
        obs = collect_observations(obj, images, resolution, seed=seed, progress=not quiet)
        obs.save(out, source={"object": config_to_dict(cfg), "spp": spp, "seed": seed,
                              "bbox": [obj.bbox_min.tolist(), obj.bbox_max.tolist()]})
        print(f"wrote {out}: {len(obs)} observations x {spp} paths ({obj.describe()})")
    run_command(go)


@app.command()
def fit(observations: Path = typer.Argument(..., help="observations file from `neumat translucent trace`"),
        out: Path = typer.Option(..., "-o", "--out", callback=output_option(".nmat"),
                                 help="model file to write (.nmat)"),
        set_: list[str] = typer.Option(None, "--set", help="key=value: a NeuPreSS config field (feature_mean=18 "
                                                          "feature_std=1 for the paper's Fourier scale), a recipe "
                                                          "field (batch_size, lr, phase_split, ...) or a recipe "
                                                          "option (sampler_batch, grid, ...)"),
        steps: int = typer.Option(None, min=0, help="optimiser steps of both phases, split by the recipe's "
                                                    "phase_split (default: the recipe's, fit/recipes/neupress.py)"),
        validation: float = typer.Option(None, help="fraction held back; the fit keeps the best weights on it "
                                                    "(default: the recipe's validation_fraction)"),
        device: str = typer.Option(None, help="torch device (default: cuda if available, else cpu)"),
        seed: int = typer.Option(None, help="seed of the model, the validation split and the batches "
                                            "(default: the recipe's)", **SEED_RANGE),
        checkpoint: Path = typer.Option(None, help="checkpoint file, written during the fit"),
        resume: bool = typer.Option(False, "--resume", help="continue from --checkpoint if it exists"),
        quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress bar")) -> None:
    """Fit NeuPreSS (appearance, then light sampler) to traced observations with its recipe and save it."""
    def go():
        from dataclasses import replace

        import torch

        from ..fit.recipe import recipe_for
        from ..fit.trainer import fit as fit_model
        from ..fit.translucent_fit import best_validation
        from ..fit.translucent_observations import Observations
        from ..catalog.modelfile import save_model
        from .common import parse_overrides
        from .fitting import build_model_and_recipe

        _check_suffix(out, ".nmat", "fit --out")
        data = Observations.load(observations)
        source = Observations.load_source(observations) or {}
        overrides = {k: _value(v) for k, v in parse_overrides(set_, text=True).items()}
        known = recipe_for("neupress").options
        options = {k: overrides.pop(k) for k in list(overrides) if k in known}
        model, recipe = build_model_and_recipe("neupress", overrides, seed)
        recipe.options.update(options)
        if validation is not None:
            recipe.options["validation_fraction"] = validation
        if "bbox" in source and "bounds" not in options:  # the object's box, written by trace
            recipe.options["bounds"] = source["bbox"]
        dev = device or ("cuda" if torch.cuda.is_available() else "cpu")
        result = fit_model(model, data, recipe, steps=steps, device=dev, progress=not quiet, checkpoint=checkpoint,
                           resume=resume)
        kl = [r["kl"] for r in result.history if r["phase"] == "sampler"]
        metrics = {"sampler_kl": kl[-1] if kl else None, "fit_seconds": result.seconds}
        row = {"observations": len(data), "steps": result.steps}
        best = best_validation(result.history)
        if best is not None:
            held = data.split(recipe.options["validation_fraction"], seed=recipe.seed)[1]  # as the recipe splits
            variance = float(held.value.var())
            metrics.update(validation_mse=best["validation_mse"], validation_variance=variance,
                           best_step=best["step"])
            row.update({"validation": len(held), "best step": best["step"], "validation MSE": best["validation_mse"],
                        "relative to its variance": best["validation_mse"] / variance if variance > 0 else None})
        row["sampler KL"] = metrics["sampler_kl"]
        save_model(model.cpu(), out, recipe=replace(recipe, steps=result.steps), source=observations,
                   metrics=metrics)
        print_table(f"wrote {out} ({model.size_bytes('fp32') // 1024} KB fp32)", [row])
    run_command(go)


@app.command()
def render(model: Path = typer.Argument(..., help="NeuPreSS model file (.nmat)"),
           observations: Path = typer.Argument(..., help="its observations file (names the object it shows)"),
           out: Path = typer.Option(..., "-o", "--out", callback=output_option(*IMAGE_OUT),
                                    help="image (.png, .exr, .hdr); with --reference-spp a "
                                                            "comparison picture (.png)"),
           light: str = typer.Option("env:sky", help="the environment: env:sky or env:PATH (equirectangular .hdr / "
                                                     ".exr), as `neumat render --light`"),
           env_width: int = typer.Option(128, help="box-filter the map to this width first"),
           resolution: int = typer.Option(64, min=8, help="image width and height"),
           spp: int = typer.Option(64, min=1, help="samples per pixel"),
           strategy: str = typer.Option("light", help="light (environment importance sampling) | model (the "
                                                      "learned Gaussian lobe)"),
           reference_spp: int = typer.Option(0, min=0, help="also path-trace the reference at this many spp and "
                                                           "compare"),
           azimuth: float = typer.Option(30.0, help="camera azimuth in degrees"),
           elevation: float = typer.Option(20.0, help="camera elevation in degrees"),
           seed: int = typer.Option(0, **SEED_RANGE),
           device: str = typer.Option("cpu", "--device", callback=device_option,
                                      help="torch device the model is evaluated on")) -> None:
    """Render MODEL on the geometry of its object under an environment map (Eq. 5)."""
    def go():
        import time

        from ..core.config import config_from_dict
        from ..core.errors import InputError
        from ..fit.translucent_observations import Observations
        from ..io.images import write_image, write_image_ldr
        from ..catalog.modelfile import load_model
        from ..metrics.image import image_metrics
        from ..models.neupress import NeuPreSS
        from ..reflectance.translucent import TranslucentConfig, TranslucentObject
        from ..render.envmaps import downsample_envmap, read_envmap, sky_envmap
        from ..render.lights import EnvironmentMap
        from ..render.translucent import orbit_camera, render_translucent, render_translucent_reference
        from ..viz.compare import compare_image

        envmap = environment_map(light)
        m = load_model(model, device=device)
        if not isinstance(m, NeuPreSS):
            raise InputError(f"{model}: expected a NeuPreSS model, got {type(m).__name__}")
        source = Observations.load_source(observations)
        if source is None or "object" not in source:
            raise InputError(f"{observations}: no object description (write it with `neumat translucent trace`)")
        if reference_spp and out.suffix.lower() != ".png":
            raise InputError(f"--out {out}: the comparison picture of --reference-spp is a .png")
        obj = TranslucentObject(config_from_dict(TranslucentConfig, source["object"]), spp=1, seed=seed)
        image = sky_envmap(width=env_width) if envmap == "sky" else read_envmap(envmap)
        env = EnvironmentMap(downsample_envmap(image, env_width))
        camera = orbit_camera(obj, resolution, azimuth, elevation)
        t = time.perf_counter()
        img = render_translucent(m, obj, env, camera, resolution, spp=spp, strategy=strategy, seed=seed)
        seconds = time.perf_counter() - t
        if not reference_spp:
            write_image(out, img, tonemap="aces")
            print(f"wrote {out} ({seconds:.1f} s)")
            return
        t = time.perf_counter()
        reference = render_translucent_reference(obj, env, camera, resolution, spp=reference_spp, seed=seed + 1)
        ref_seconds = time.perf_counter() - t
        scores = image_metrics(reference.numpy(), img.numpy(), tonemap="aces")
        scores["mse"] = float(((img - reference) ** 2).mean())
        name = f"NeuPreSS, {strategy} IS, {spp} spp"
        write_image_ldr(out, compare_image(reference, {name: img}, {name: scores}, tonemap="aces"))
        print_table(f"wrote {out}: against a {reference_spp}-spp path-traced reference ({ref_seconds:.0f} s)",
                    [{"method": name, "seconds": seconds, "MSE": scores["mse"], "FLIP": scores["flip"],
                      "SSIM": scores["ssim"]}])
    run_command(go)


def _value(text: str):
    """A --set value: JSON for lists and null (grid=[32,64], phase_split=[0.9,0.1], bounds=null), else as
    `neumat fit` reads values."""
    import json

    from ..core.config import parse_value
    if text.strip().startswith("[") or text.strip() == "null":
        try:
            return json.loads(text)
        except ValueError:
            pass
    return parse_value(text)


def _check_suffix(path: Path, suffix: str, what: str) -> None:
    from ..core.errors import InputError
    if path.suffix.lower() != suffix:
        raise InputError(f"{what}: expected a {suffix} file, got {str(path)!r}")
