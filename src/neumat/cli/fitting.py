"""`neumat fit` and `neumat eval`."""
from __future__ import annotations

import sys
import time
import warnings
from pathlib import Path

import typer

from ..core.errors import InputError
from ..core.threads import shared_threads
from .common import (SEED_RANGE, THREADS_HELP, default_device, device_option, output_option, parse_overrides,
                     print_json, print_table, run_command)


def register(app: typer.Typer) -> None:
    app.command()(fit)
    app.command("eval")(evaluate)


PRESET_HELP = ("a preset of the model (`neumat list MODEL`): recommended (the default: the best setting we "
               "measured, sized to the device), paper (the paper's model and recipe, sized for a GPU), cpu (the "
               "paper's model along the fastest CPU path) or one of the model's own")


def fit(sources: list[str] = typer.Argument(..., help="training source: a material file (.binary, .bsdf, .nmat, "
                                             ".json), a texture-set folder, a BTF (.nbtf, .btf), translucent "
                                             "observations (.npz) or an analytic spec; several for models that "
                                             "fit a set (shared-neubrdf)"),
        model: str = typer.Option(None, "--model", "-m",
                                  help="registered model name (`neumat list`); default: the recommended model for "
                                       "the source (neumat.cli.fitting.default_model: neubrdf for a BRDF, "
                                       "multiscale for a texture-set folder (on a CPU tripleplane for a flat, rough "
                                       "dielectric, neumip for one of more than 2 x 256^2 texels: "
                                       "neumat.methods.latent_mlp.regime), sparse-btf for a BTF, neupress for "
                                       "translucent observations, shared-neubrdf for several BRDFs)"),
        preset: str = typer.Option(None, "--preset", help=PRESET_HELP),
        recipe_alias: str = typer.Option(None, "--recipe", hidden=True, help="the same as --preset (old name)"),
        set_: list[str] = typer.Option(None, "--set", help="key=value: model.KEY (config field), recipe.KEY "
                                                           "(recipe field) or option.KEY (recipe option); a bare KEY "
                                                           "when only one of them has it; lists as a,b"),
        steps: int = typer.Option(None, min=0, help="optimiser steps (default: the preset's)"),
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
        out: Path = typer.Option(..., "-o", "--out", callback=output_option(".nmat"),
                                 help="output model file (.nmat)")) -> None:
    """Fit MODEL to SOURCE through the one trainer with a preset (default: recommended, the best setting we
    measured, sized to the device; --preset paper for the paper's exact model and recipe), and save the model in
    its shipped (runtime) form as a .nmat file that records the preset, the recipe and the source's name and hash;
    training state lives only in --checkpoint. Models trained in stages run them as phases of the same fit."""

    def go():
        options = parse_overrides(source_option, "--source-option")
        preset_name = chosen_preset(preset, recipe_alias)
        chosen = model
        if model is None:
            chosen, why = default_model(sources, options, preset_name, resolve_device(device).type)
            if not quiet:
                print(f"model {chosen}: the default for this source{why} (`neumat list` for the others; "
                      "--model NAME)")
        run_fit(chosen, sources, preset_name, parse_overrides(set_), out, steps=steps,
                device=device, seed=seed, checkpoint=checkpoint, resume=resume, quiet=quiet, source_options=options)
    with shared_threads(threads):
        run_command(go)


def run_fit(model: str, sources: list[str], preset: str, overrides: dict, out: Path, *, steps: int | None = None,
            device: str | None = None, seed: int | None = None, checkpoint: Path | None = None, resume: bool = False,
            quiet: bool = False, source_options: dict | None = None) -> None:
    """What `neumat fit` does: fit `model` to `sources` with `preset` and `overrides`, save its shipped form to
    `out` with the preset, the recipe, the source and the metrics, and print what was written (with the method's
    report, e.g. a translucent fit's held-back error)."""
    from ..catalog.modelfile import save_model
    from ..fit.method import method_for
    from ..fit.preset import build_fit
    from ..fit.trainer import FitWarning
    from ..fit.trainer import fit as fit_model

    if out.suffix != ".nmat":
        raise InputError(f"-o/--out: model files end in .nmat, got {str(out)!r}")
    dev = resolve_device(device)
    src = open_training_source(model, sources, source_options or {})
    m, resolved = build_fit(model, preset, device=dev, source=src, overrides=overrides, seed=seed)
    if not quiet:
        print(preset_note(model, resolved, steps))
        note = target_samples_note(resolved.recipe.options, source_options or {}, src)
        if note:
            print(note)
    with warnings.catch_warnings():  # said once below, as one line
        warnings.simplefilter("ignore", FitWarning)
        result = fit_model(m, src, resolved.recipe, steps=steps, device=dev, progress=not quiet,
                           checkpoint=checkpoint, resume=resume)
    for text in result.warnings:
        print(f"warning: {text}", file=sys.stderr)
    last = result.history[-1] if result.history else {}
    cpu = result.cpu_seconds  # None: unknown after an old checkpoint
    metrics = {"final_loss": last.get("loss"), "fit_seconds": result.seconds, "fit_cpu_seconds": cpu}
    report = method_for(model).report
    extra, row = report(result.model, src, result) if report is not None else ({}, {})
    metrics.update(extra)
    shipped = result.model.runtime()
    save_model(shipped, out, recipe=result.recipe, source=sources[0] if len(sources) == 1 else sources,
               metrics=metrics, preset={"name": resolved.preset, "overrides": resolved.applied})
    spent = f"{result.seconds:.1f} s" + ("" if cpu is None else f", {cpu:.1f} CPU s")
    print(f"wrote {out} ({model}, preset {resolved.preset}, {result.steps} steps, {spent}, final "
          f"loss {metrics['final_loss']}; {out.stat().st_size:,} bytes on disk, {shipped.size_bytes('fp16'):,} "
          "bytes stored at fp16)")
    bound = getattr(shipped, "output_bound_values", lambda: None)()  # the gated model's (multiscale.Config)
    if bound is not None:
        print(f"its output is bounded by the largest target the fit saw: {', '.join(f'{b:.4g}' for b in bound)} "
              "(RGB; --set output_bound=false for none)")
    if row:
        print_table(f"{model} fit report", [row])


#: the model `neumat fit` fits when --model is not given, by what the source is (a `neumat.catalog.sources` key,
#: "observations" for a translucent object's .npz, "several" for a set of sources): each kind's best model we
#: measured; a texture-set folder ("folder") gets the gated model, tripleplane or NeuMIP by its statistics and
#: size (`neumat.methods.latent_mlp.regime`)
DEFAULT_MODELS = {"several": "shared-neubrdf", "observations": "neupress", ".nbtf": "sparse-btf",
                  ".btf": "sparse-btf"}
#: ... and for every other source (a measured or analytic BRDF, a model file, a layered description)
DEFAULT_BRDF_MODEL = "neubrdf"


def default_model(sources: list[str], options: dict | None = None, preset: str | None = None,
                  device_type: str = "cpu") -> tuple[str, str]:
    """The model `neumat fit` fits to `sources` without --model (DEFAULT_MODELS; a texture-set folder, read with
    the reader `options` such as its crop, by `regime.model_for_texture_set` for `preset` on a `device_type`
    device) and why, as ": REASON" or "" (InputError for a missing or unsupported file)."""
    from ..catalog.open_material import material_source, open_material
    from ..catalog.sources import FOLDER, load_sources
    from ..methods.latent_mlp.regime import model_for_texture_set

    if len(sources) > 1:
        return DEFAULT_MODELS["several"], ""
    if Path(sources[0]).suffix.lower() == ".npz":
        return DEFAULT_MODELS["observations"], ""
    source, _ = material_source(sources[0])
    key = next(k for k, v in load_sources().items() if v is source)
    if key == FOLDER:
        name, why = model_for_texture_set(open_material(sources[0], **(options or {})).textures,
                                          chosen_preset(preset), device_type)
        return name, f": {why}"
    return DEFAULT_MODELS.get(key, DEFAULT_BRDF_MODEL), ""


def chosen_preset(preset: str | None, recipe_alias: str | None = None) -> str:
    """The preset a fit runs: --preset, else the old --recipe name, else `neumat.fit.preset.DEFAULT_PRESET`."""
    from ..fit.preset import DEFAULT_PRESET

    if preset is not None and recipe_alias is not None and preset != recipe_alias:
        raise InputError(f"--preset {preset} and --recipe {recipe_alias}: --recipe is the old name of --preset; "
                         "give one")
    return preset or recipe_alias or DEFAULT_PRESET


def preset_note(model: str, resolved, steps: int | None = None) -> str:
    """The line a fit prints before it starts: the preset it uses, the steps it will run (`steps` when --steps
    overrides the recipe's) and how to get the paper's exact model."""
    paper = ("" if resolved.preset in ("paper", "cpu") else
             "; the paper's exact model: --preset paper (its recipe, sized for a GPU) or --preset cpu")
    n = resolved.recipe.steps if steps is None else steps
    return f"{model}: {resolved.describe()}, {n} steps x {resolved.recipe.batch_size}{paper}"


def target_samples_note(options: dict, source_options: dict, source) -> str:
    """The line a fit prints when the recipe option target_samples replaces a --source-option samples=N for the
    training targets ("" otherwise): the user asked for N footprint positions and the fit trains on another
    count (`neumat.fit.footprint_queries.with_target_samples`)."""
    target, given = int(options.get("target_samples", 0) or 0), source_options.get("samples")
    if target <= 0 or given is None or not hasattr(source, "samples") or int(given) == target:
        return ""
    return (f"note: the training targets are filtered with {target} footprint positions (recipe option "
            f"target_samples), not --source-option samples={given}; --set option.target_samples={given} trains on "
            f"{given}")


def resolve_device(device: str | None):
    """The torch device `device` names (default: `common.default_device`); InputError for a name torch does not
    know or a CUDA device this machine lacks."""
    import torch

    if device is None:
        return torch.device(default_device())
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
             picture: Path = typer.Option(None, "--picture", callback=output_option(".png", ".jpg", ".jpeg"),
                                          help="also write the renderings scored: reference | model | FLIP error, "
                                               "and the floor's FLIP error (the reference rendered like the model)"),
             json: bool = typer.Option(False, "--json", help="print one JSON object instead of a table")) -> None:
    """Compare MODEL, as stored in its file, with a reference: reflectance errors, rendered-image metrics, size
    and speed. The defaults take about a minute on a CPU for a small model; raise --n, --spp and --resolution
    for final numbers. The sphere shows the texture at about one scale; --scales N scores filtering across
    scales (Timonen et al. 2025, Fig. 4 / Table 6) on the plane scene at --resolution."""
    def go():
        from ..catalog.modelfile import load_model
        from ..catalog.open_material import open_material
        from ..metrics.hdr import reflectance_errors

        if picture is not None and not image:
            raise InputError("--picture: it shows the sphere renderings, which --no-image turns off")
        dev = resolve_device(device)
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
            from ..render.comparison import PROTOCOL, compared_images

            scores, renders, test = compared_images(m, ref, spp, resolution, seed=seed, device=dev)
            row.update(scores, image_protocol=PROTOCOL)
            if picture is not None:
                from ..io.images import write_image_ldr
                from ..viz.compare import comparison_picture

                write_image_ldr(picture, comparison_picture(renders, test, Path(model).stem, scores))
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

