"""`neumat fit` and `neumat eval`."""
from __future__ import annotations

import difflib
import time
from dataclasses import fields, replace
from pathlib import Path

import typer

from ..core.errors import InputError
from .common import parse_overrides, print_json, print_table, run_command


def register(app: typer.Typer) -> None:
    app.command()(fit)
    app.command("eval")(evaluate)


def fit(source: str = typer.Argument(..., help="material file (.binary, .bsdf, .nmat) or analytic spec"),
        model: str = typer.Option("neubrdf", "--model", "-m", help="registered model name"),
        set_: list[str] = typer.Option(None, "--set", help="key=value: a model config field, else a recipe field"),
        steps: int = typer.Option(None, min=0, help="optimiser steps (default: the recipe's)"),
        device: str = typer.Option(None, help="torch device (default: cuda if available, else cpu)"),
        seed: int = typer.Option(None, help="seed of the model initialisation and the queries (default: recipe's)"),
        checkpoint: Path = typer.Option(None, help="checkpoint file, written during the fit"),
        resume: bool = typer.Option(False, "--resume", help="continue from --checkpoint if it exists"),
        quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress bar"),
        source_option: list[str] = typer.Option(None, "--source-option",
                                                help="key=value passed to the source reader, e.g. max_size=256 "
                                                     "or samples=64 for a texture-set folder"),
        dictionary: Path = typer.Option(None, help="sparse-btf: the trained dictionary ensemble (.nmat)"),
        tau: str = typer.Option(None, help="sparse-btf: coefficients per data point tau_t, one value or Y,U,V"),
        out: Path = typer.Option(..., "-o", "--out", help="output model file (.nmat)")) -> None:
    """Fit MODEL to SOURCE with the model's recipe (overridable with --set) and save it as a .nmat file.
    `--model sparse-btf` codes a BTF (.nbtf) with a dictionary from `neumat fit-dictionary` instead;
    `--model neural-appearance` trains in two phases (encoder, then latents; half the steps each, default 4000)."""

    def go():
        import torch

        from ..catalog.modelfile import save_model
        from ..catalog.open_material import open_material
        from ..fit.trainer import fit as fit_model

        if out.suffix != ".nmat":
            raise InputError(f"-o/--out: model files end in .nmat, got {str(out)!r}")
        if model == "sparse-btf":
            return _code_sparse_btf(source, dictionary, tau, out)
        if model == "neural-appearance":
            return _fit_neural_appearance(source, parse_overrides(set_), steps, seed, quiet,
                                          parse_overrides(source_option, "--source-option"), out)
        m, recipe = build_model_and_recipe(model, parse_overrides(set_), seed)
        src = open_material(source, **parse_overrides(source_option, "--source-option"))
        dev = device or ("cuda" if torch.cuda.is_available() else "cpu")
        result = fit_model(m, src, recipe, steps=steps, device=dev, progress=not quiet, checkpoint=checkpoint,
                           resume=resume)
        metrics = {"final_loss": result.history[-1]["loss"] if result.history else None,
                   "fit_seconds": result.seconds}
        save_model(result.model, out, recipe=replace(recipe, steps=result.steps), source=source, metrics=metrics)
        print(f"wrote {out} ({result.steps} steps, {result.seconds:.1f} s, final loss {metrics['final_loss']})")
    run_command(go)


def _fit_neural_appearance(source: str, overrides: dict, steps: int | None, seed: int | None, quiet: bool,
                           source_options: dict, out: Path) -> None:
    """`neumat fit SOURCE --model neural-appearance`: `fit.neural_appearance.fit_neural_appearance` on the CPU.
    --set takes the model's config fields and batch_size, lr, directions, blur_degrees, blur_samples, blur_until,
    sampler_batch (`fit_neural_appearance`); spatial_size defaults to the texture's size."""
    import torch

    from ..fit.neural_appearance import fit_neural_appearance
    from ..catalog.modelfile import save_model
    from ..catalog.open_material import open_material
    from ..models.neural_appearance import Config, NeuralAppearance

    training = {"batch_size", "lr", "directions", "blur_degrees", "blur_samples", "blur_until", "sampler_batch"}
    known = {f.name for f in fields(Config)} | training
    unknown = _unknown_keys(overrides, known)
    if unknown:
        raise InputError(f"--set: unknown key(s) {unknown} for neural-appearance: {', '.join(sorted(known))}")
    src = open_material(source, **source_options)
    config = {k: v for k, v in overrides.items() if k not in training}
    size = getattr(getattr(src, "textures", None), "size", None) or getattr(src, "texture_size", None)
    if "spatial_size" not in config and size is not None:
        config["spatial_size"] = 1 << (min(size).bit_length() - 1)         # the texture's resolution (paper)
    if "surface_features" not in config and getattr(src, "sampling_feature_dim", None) is not None:
        config["surface_features"] = int(src.sampling_feature_dim)       # what the encoder reads: k(x)
    torch.manual_seed(0 if seed is None else seed)
    model = NeuralAppearance(**config)
    total = 4000 if steps is None else steps
    result = fit_neural_appearance(model, src, encoder_steps=total // 2, latent_steps=total - total // 2,
                                   batch=int(overrides.get("batch_size", 4096)), lr=float(overrides.get("lr", 3e-3)),
                                   seed=0 if seed is None else seed, progress=not quiet,
                                   directions=str(overrides.get("directions", "cosine")),
                                   blur_degrees=float(overrides.get("blur_degrees", 0.0)),
                                   blur_samples=int(overrides.get("blur_samples", 4)),
                                   blur_until=float(overrides.get("blur_until", 0.5)),
                                   sampler_batch=str(overrides.get("sampler_batch", "shared")))
    last = result.history[-1] if result.history else {}
    metrics = {"fit_seconds": result.seconds, "final_brdf_loss": last.get("brdf loss"),
               "final_sampler_loss": last.get("sampler loss")}
    save_model(model, out, source=source, metrics=metrics)
    print(f"wrote {out} (neural-appearance, {model.cfg.spatial_size}^2 latents, {total} steps, "
          f"{sum(result.seconds.values()):.1f} s, final log_cos {metrics['final_brdf_loss']})")


def _code_sparse_btf(source: str, dictionary: Path | None, tau: str | None, out: Path) -> None:
    """SparseBTF has no gradient training: project the BTF on the dictionary ensemble and save the codes."""
    from ..catalog.modelfile import save_model
    from ..models.sparse_btf import SparseBTF
    from ..reflectance.btf import read_btf
    from ..models.sparse_dictionary import BTFDictionary
    from .btf import parse_tau

    if dictionary is None:
        raise InputError("--model sparse-btf needs --dictionary (train one with `neumat fit-dictionary`)")
    t0 = time.perf_counter()
    model = SparseBTF.encode(read_btf(source), BTFDictionary.load(dictionary), None if tau is None else parse_tau(tau))
    seconds = time.perf_counter() - t0
    save_model(model, out, source=source, metrics={"coding_seconds": seconds, "bytes": model.size_bytes()})
    print(f"wrote {out} ({model.size_bytes()} bytes, coded in {seconds:.1f} s)")


def _unknown_keys(overrides: dict, known: set[str]) -> str:
    """The keys of `overrides` not in `known`, each with its closest known names ("" when all are known)."""
    hints = {k: difflib.get_close_matches(k, known, n=2) for k in overrides if k not in known}
    return "; ".join(f"{k!r}" + (f" (did you mean {', '.join(h)}?)" if h else "") for k, h in hints.items())


def build_model_and_recipe(model: str, overrides: dict, seed: int | None = None):
    """A fresh model `model` and its recipe with `overrides` applied (model config fields first, then recipe
    fields; unknown keys raise). The model is initialised after seeding torch with the recipe's seed."""
    import torch

    from ..core.config import config_from_dict, config_to_dict
    from ..fit.recipe import Recipe, check_recipe, recipe_for
    from ..catalog.modelfile import model_config_class
    from ..models.registry import model_class

    cls = model_class(model)
    config_cls = model_config_class(cls)
    config_keys = {f.name for f in fields(config_cls)}
    recipe_keys = {f.name for f in fields(Recipe)}
    text = _unknown_keys(overrides, config_keys | recipe_keys)
    if text:
        raise InputError(f"--set: unknown key(s) {text}: not a field of {model!r}'s config "
                           f"({', '.join(sorted(config_keys))}) nor of the recipe ({', '.join(sorted(recipe_keys))})")
    recipe = config_from_dict(Recipe, {**config_to_dict(recipe_for(model)),
                                       **{k: v for k, v in overrides.items() if k not in config_keys}})
    if seed is not None:
        recipe.seed = seed
    check_recipe(recipe)
    cfg = config_from_dict(config_cls, {k: v for k, v in overrides.items() if k in config_keys})
    torch.manual_seed(recipe.seed)
    return cls(config=cfg), recipe


def evaluate(model: Path = typer.Argument(..., help="model file (.nmat)"),
             against: str = typer.Option(..., "--against", help="reference: material file or analytic spec"),
             n: int = typer.Option(2 ** 20, "--n", min=1, help="random (wi, wo) configurations"),
             image: bool = typer.Option(True, "--image/--no-image", help="also compare sphere renderings"),
             spp: int = typer.Option(64, min=1, help="samples per pixel of the renderings"),
             resolution: int = typer.Option(256, min=8, help="rendering width and height"),
             device: str = typer.Option(None, help="torch device (default: cuda if available, else cpu)"),
             seed: int = typer.Option(0),
             json: bool = typer.Option(False, "--json", help="print one JSON object instead of a table")) -> None:
    """Compare MODEL with a reference: reflectance errors, rendered-image metrics, size and speed."""
    def go():
        import torch

        from ..catalog.modelfile import load_model
        from ..catalog.open_material import open_material
        from ..metrics.hdr import reflectance_errors

        dev = device or ("cuda" if torch.cuda.is_available() else "cpu")
        m = load_model(model, device=dev)
        ref = open_material(against)
        row = {"model": str(model), "against": against}
        row.update(reflectance_errors(m, ref, n=n, seed=seed, device=dev))
        if image:
            from ..metrics.image import image_metrics
            from ..render.render import render

            opts = dict(scene="sphere", spp=spp, resolution=(resolution, resolution), seed=seed, device=dev)
            row.update(image_metrics(render(ref, **opts), render(m, **opts)))
        row["bytes_fp16"] = int(m.size_bytes("fp16"))
        row["evals_per_second"] = evals_per_second(m, dev)
        if json:
            print_json(row)
        else:
            print_table(f"{model} against {against}", [{"metric": k, "value": v} for k, v in row.items()])
    run_command(go)


def evals_per_second(material, device, batch: int = 2 ** 16, min_seconds: float = 0.2) -> float:
    """Throughput of `material.eval` on batches of cosine-weighted queries (after one warm-up batch)."""
    import torch

    from ..fit.query_samplers import QUERY_SAMPLERS

    gen = torch.Generator().manual_seed(0)
    q = QUERY_SAMPLERS.get("cosine")(material, material)(batch, gen, device)
    sync = torch.cuda.synchronize if torch.device(device).type == "cuda" else (lambda: None)
    with torch.no_grad():
        material.eval(q)
        sync()
        count, t0 = 0, time.perf_counter()
        while time.perf_counter() - t0 < min_seconds:
            material.eval(q)
            count += batch
        sync()
        return count / (time.perf_counter() - t0)

