"""`neumat fit` and `neumat eval`."""
from __future__ import annotations

import difflib
import time
from dataclasses import fields
from pathlib import Path

import typer

from ..core.errors import InputError
from .common import (SEED_RANGE, THREADS_HELP, device_option, output_option, parse_overrides, print_json,
                     print_table, run_command, torch_threads)


def register(app: typer.Typer) -> None:
    app.command()(fit)
    app.command("eval")(evaluate)


def fit(sources: list[str] = typer.Argument(..., help="training source: a material file (.binary, .bsdf, .nmat, "
                                             ".json), a texture-set folder, a BTF (.nbtf, .btf), translucent "
                                             "observations (.npz) or an analytic spec; several for models that "
                                             "fit a set (shared-neubrdf)"),
        model: str = typer.Option("neubrdf", "--model", "-m", help="registered model name (`neumat list`)"),
        set_: list[str] = typer.Option(None, "--set", help="key=value: a model config field, else a recipe field, "
                                                           "else a recipe option; lists as a,b"),
        steps: int = typer.Option(None, min=0, help="optimiser steps (default: the recipe's)"),
        recipe_name: str = typer.Option(None, "--recipe", help="paper | cpu | a named recipe of the model (neumat "
                                        "list): the paper's recipe (sized for a GPU), the CPU-sized one (about 10 "
                                        "min on 2 cores) or e.g. neubrdf's dense; default: cpu on a CPU device when "
                                        "neither --steps nor --set steps=N is given, else paper"),
        device: str = typer.Option(None, callback=device_option,
                                  help="torch device (default: cuda if available, else cpu)"),
        seed: int = typer.Option(None, **SEED_RANGE,
                                help="seed of the model initialisation and the queries (default: recipe's)"),
        checkpoint: Path = typer.Option(None, help="checkpoint file, written during the fit"),
        resume: bool = typer.Option(False, "--resume", help="continue from --checkpoint if it exists"),
        quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress output"),
        threads: int = typer.Option(None, min=1, help=THREADS_HELP),
        source_option: list[str] = typer.Option(None, "--source-option",
                                                help="key=value passed to the source reader, e.g. max_size=256 "
                                                     "or samples=64 for a texture-set folder"),
        dictionary: Path = typer.Option(None, help="sparse-btf: a trained dictionary ensemble (.nmat); the same "
                                                   "as --set dictionary=PATH"),
        tau: str = typer.Option(None, help="sparse-btf: coefficients per data point tau_t, one value or Y,U,V; "
                                           "the same as --set tau=..."),
        out: Path = typer.Option(..., "-o", "--out", callback=output_option(".nmat"),
                                 help="output model file (.nmat)")) -> None:
    """Fit MODEL to SOURCE through the one trainer, with the model's recipe (the paper's on a GPU, the CPU-sized
    one on a CPU unless --steps or --recipe paper; --set overrides config fields, recipe fields and recipe
    options), and save the model in its shipped (runtime) form as a .nmat file that records the recipe and the
    source's name and hash; training state lives only in --checkpoint. Models trained in stages
    (neural-appearance: encoder then latents; neupress: appearance then sampler; sparse-btf: dictionary then
    coding) run them as phases of the same fit, with --device, --checkpoint and --resume."""

    def go():
        from ..fit.trainer import fit as fit_model
        from ..catalog.modelfile import save_model

        if out.suffix != ".nmat":
            raise InputError(f"-o/--out: model files end in .nmat, got {str(out)!r}")
        overrides = parse_overrides(set_)
        if dictionary is not None:
            overrides["dictionary"] = str(dictionary)
        if tau is not None:
            overrides.update(parse_overrides([f"tau={tau}"]))
        dev = resolve_device(device)
        machine = choose_recipe(recipe_name, model, dev, steps is not None or "steps" in overrides)
        src = open_training_source(model, sources, parse_overrides(source_option, "--source-option"))
        m, recipe = build_model_and_recipe(model, overrides, seed, source=src, machine=machine)
        if machine == "cpu" and recipe_name is None and not quiet:
            print(cpu_recipe_note(model, recipe))
        result = fit_model(m, src, recipe, steps=steps, device=dev, progress=not quiet,
                           checkpoint=checkpoint, resume=resume)
        last = result.history[-1] if result.history else {}
        metrics = {"final_loss": last.get("loss"), "fit_seconds": result.seconds}
        shipped = result.model.runtime()
        save_model(shipped, out, recipe=result.recipe, source=sources[0] if len(sources) == 1 else sources,
                   metrics=metrics)
        print(f"wrote {out} ({model}, {result.steps} steps, {result.seconds:.1f} s, final loss "
              f"{metrics['final_loss']}; {out.stat().st_size:,} bytes on disk, {shipped.size_bytes('fp16'):,} bytes "
              "stored at fp16)")
    with torch_threads(threads):
        run_command(go)


def checked_recipe_name(recipe_name: str, model: str) -> str:
    """`recipe_name` if model `model` has a recipe of that name (a --recipe value: "paper", "cpu" or one of the
    model's named recipes, `neumat.fit.recipe.recipe_choices`), else InputError naming its choices."""
    from ..fit.recipe import recipe_choices

    choices = recipe_choices(model)
    if recipe_name not in choices:
        raise InputError(f"--recipe: model {model} has the recipes {', '.join(choices)}; got {recipe_name!r}")
    return recipe_name


def choose_recipe(recipe_name: str | None, model: str, device, budget_given: bool) -> str:
    """Which of the model's recipes a fit runs: `recipe_name` when given (checked against `model`'s), else "cpu"
    on a CPU device when the command line names no step budget, else "paper"."""
    if recipe_name is not None:
        return checked_recipe_name(recipe_name, model)
    return "cpu" if device.type == "cpu" and not budget_given else "paper"


def cpu_recipe_note(model: str, recipe) -> str:
    """The line `neumat fit` prints when it picks the CPU-sized recipe on its own: its budget, its expected time
    and the paper's recipe, with how to ask for it."""
    from ..fit.recipe import cpu_minutes, recipe_for

    paper, minutes = recipe_for(model, "paper"), cpu_minutes(model)
    time = "its time follows the source" if minutes is None else f"about {minutes:g} min"
    return (f"using the CPU-sized recipe of {model} ({recipe.steps} steps x {recipe.batch_size}, {time}); the "
            f"paper's is {paper.steps} steps x {paper.batch_size} (--recipe paper)")


def resolve_device(device: str | None):
    """The torch device `device` names (default: cuda if available, else cpu); InputError for a name torch does
    not know or a CUDA device this machine lacks."""
    import torch

    if device is None:
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        dev = torch.device(device)
    except (RuntimeError, ValueError):
        raise InputError(f"--device: {device!r} is not a torch device (cpu, cuda, cuda:1, mps, ...)") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise InputError(f"--device {device}: this machine has no CUDA GPU visible to torch; use --device cpu")
    return dev


def open_training_source(model: str, sources: list[str], options: dict):
    """What model `model` trains on, from the command line's SOURCE arguments, by the first of its
    `source_kinds`: one Material (brdf, svbrdf, btf), a list of Materials (brdf-set) or the Observations of a
    translucent object (translucent)."""
    from ..catalog.open_material import open_material
    from ..models.registry import model_class

    kind = model_class(model).source_kinds[0]
    if kind == "brdf-set":
        return [open_material(s, **options) for s in sources]
    if len(sources) != 1:
        raise InputError(f"model {model!r} fits one source ({kind}), got {len(sources)}: {', '.join(sources)}")
    if kind == "translucent":
        from ..fit.translucent_observations import Observations
        if options:
            raise InputError(f"--source-option: observation files take no reader options, got {sorted(options)}")
        return Observations.load(sources[0])
    return open_material(sources[0], **options)


def _unknown_keys(overrides: dict, known: set[str]) -> str:
    """The keys of `overrides` not in `known`, each with its closest known names ("" when all are known)."""
    hints = {k: difflib.get_close_matches(k, known, n=2) for k in overrides if k not in known}
    return "; ".join(f"{k!r}" + (f" (did you mean {', '.join(h)}?)" if h else "") for k, h in hints.items())


def build_model_and_recipe(model: str, overrides: dict, seed: int | None = None, source=None,
                           machine: str = "paper"):
    """A fresh model `model` and its recipe `machine` ("paper", "cpu" or a named one, see `recipe_for`) with `overrides`
    applied: model config fields first, then recipe fields, then recipe options (unknown keys raise). With a `source`, the recipe module's
    `config_for_source(source, options) -> dict` (if it has one) supplies config defaults that follow the source (e.g. the
    latent resolution of a texture set); overrides win. The model is initialised after seeding torch with the
    recipe's seed."""
    import torch

    from ..core.config import config_from_dict, config_to_dict
    from ..fit.recipe import Recipe, check_recipe, recipe_config_for_source, recipe_for
    from ..models.registry import model_class

    cls = model_class(model)
    config_keys = {f.name for f in fields(cls.Config)}
    recipe_keys = {f.name for f in fields(Recipe)} - {"options"}
    base = recipe_for(model, machine)
    option_keys = set(base.options)
    text = _unknown_keys(overrides, config_keys | recipe_keys | option_keys)
    if text:
        raise InputError(f"--set: unknown key(s) {text}: not a field of {model!r}'s config "
                         f"({', '.join(sorted(config_keys))}), of the recipe ({', '.join(sorted(recipe_keys))}) "
                         f"nor a recipe option ({', '.join(sorted(option_keys)) or 'none'})")
    rest = {k: v for k, v in overrides.items() if k not in config_keys}
    options = {**base.options, **{k: v for k, v in rest.items() if k in option_keys and k not in recipe_keys}}
    recipe = config_from_dict(Recipe, {**config_to_dict(base), **{k: v for k, v in rest.items() if k in recipe_keys},
                                       "options": options})
    if seed is not None:
        recipe.seed = seed
    check_recipe(recipe)
    derived = recipe_config_for_source(model, source, recipe.options) if source is not None else {}
    cfg = config_from_dict(cls.Config, {**derived, **{k: v for k, v in overrides.items() if k in config_keys}})
    torch.manual_seed(recipe.seed)
    return cls(config=cfg), recipe


def evaluate(model: Path = typer.Argument(..., help="model file (.nmat)"),
             against: str = typer.Option(..., "--against", help="reference: material file or analytic spec"),
             source_option: list[str] = typer.Option(None, "--source-option",
                                                     help="key=value passed to the reader of the reference, as "
                                                          "`neumat fit` takes them, e.g. max_size=64"),
             n_configs: int = typer.Option(2 ** 18, "--n-configs", min=1, help="random (wi, wo) configurations"),
             image: bool = typer.Option(True, "--image/--no-image",
                                        help="also compare sphere renderings (neumat.render.comparison): the model "
                                             "and the reference at --spp, each against the reference at 16x --spp "
                                             "(floor_*: the reference's score, what a perfect model gets)"),
             spp: int = typer.Option(16, min=1, help="samples per pixel of the renderings"),
             resolution: int = typer.Option(128, min=8, help="rendering width and height"),
             scales: int = typer.Option(0, "--scales", min=0,
                                        help="also score a spatially varying model on the benchmark's plane scene "
                                             "at N texture scales (1/8 texel to 2 textures per pixel) x 4 lights "
                                             "x 3 cameras: per-scale and mean FLIP, and the reference's own noise "
                                             "floor (render/scale_series.py); 0 = off"),
             device: str = typer.Option(None, callback=device_option,
                                       help="torch device (default: cuda if available, else cpu)"),
             seed: int = typer.Option(0, **SEED_RANGE),
             member: int = typer.Option(None, "--member", min=0,
                                        help="shared-neubrdf: evaluate material i of the set (its bytes: "
                                             "its own index grid plus its share of the codebook and MLP)"),
             json: bool = typer.Option(False, "--json", help="print one JSON object instead of a table")) -> None:
    """Compare MODEL, as stored in its file, with a reference: reflectance errors, rendered-image metrics, size
    and speed. The defaults take about a minute on a CPU for a small model; raise --n, --spp and --resolution
    for final numbers. The sphere shows the texture at about one scale; --scales N scores filtering across
    scales (Timonen et al. 2025, Fig. 4 / Table 6) on the plane scene at --resolution."""
    def go():
        import torch

        from ..catalog.modelfile import load_model
        from ..catalog.open_material import open_material
        from ..metrics.hdr import reflectance_errors

        dev = device or ("cuda" if torch.cuda.is_available() else "cpu")
        m = load_model(model, device=dev)
        if member is not None:
            if not callable(getattr(m, "material", None)):
                raise InputError(f"--member {member}: {model} holds one material ({m.name}), not a set "
                                 "(shared-neubrdf)")
            m = m.material(member)
        ref = open_material(against, **parse_overrides(source_option, "--source-option"))
        row = {"model": str(model), "against": against}
        row.update(reflectance_errors(m, ref, n=n_configs, seed=seed, device=dev))
        if image:
            from ..render.comparison import PROTOCOL, image_comparison

            row.update(image_comparison(m, ref, spp, resolution, seed=seed, device=dev), image_protocol=PROTOCOL)
        series = None
        if scales:
            from ..render.scale_series import score_scale_series

            series = score_scale_series(m, ref, n_scales=scales, resolution=resolution, device=dev)
            row.update(flip_scales_mean=series["flip_mean"], flip_scales_floor=series["floor_mean"])
        row["bytes_fp16"] = int(m.size_bytes("fp16"))
        row["evals_per_second"] = evals_per_second(m, dev)
        if json:
            print_json(row if series is None else {**row, "scales": series})
        else:
            print_table(f"{model} against {against}", [{"metric": k, "value": v} for k, v in row.items()])
            if series is not None:
                print_table("FLIP per texture scale (plane scene; floor: the reference against itself)",
                            [{"scale": i, "texels per pixel": t, "flip": f, "floor": g} for i, (t, f, g)
                             in enumerate(zip(series["texels_per_pixel"], series["flip"], series["floor"]))])
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

