"""BRDF model benchmark: every BRDF model x measured (RGL) and analytic materials.

For each (model, material): fit with the model's recipe (`--steps` overrides the step count), then
  - RMSE-HDR, MAE-HDR over random cosine-weighted configurations (`neumat.metrics.hdr.reflectance_errors`),
  - image MAE / RMSE / SSIM / FLIP of a sphere under an environment map against the reference material's
    rendering (`neumat.render.render.render` + `neumat.metrics.image.image_metrics`). Both images use
    light (environment) sampling with the same seed, so they share their sample directions and the
    difference measures the BRDFs, not Monte Carlo noise; the exposure maps the reference's 99th
    percentile to 1,
  - FLOPs per evaluation (`neumat.metrics.flops.model_flops`), stored bytes (fp16), fit time, evaluations
    per second (no_grad, batches of 2^16 queries).
Prints rich tables (per pair, per model averaged over materials) beside the NeuBRDF paper's Table 3 (MERL
averages, image metrics following NBRDF), and writes them as Markdown (`--out`).

`--table4`: the homogeneous-BRDF comparison of Timonen et al. 2025 (Tables 3 and 4): the four FLOP-matched
"-t4" models (naive MLP, NBRDF, tripleplane, the gated model) on the shared RGL materials, with the paper's
numbers beside ours (written to benchmarks/studies/neubrdf/results/brdf_table4_rgl.md).

Every (material, model) pair is one job (`fit_pair`; it renders its own reference image): one after another
in this process, or with `--engine ray` as Ray tasks (`neumat.cli.fit_engines`, as `neumat fit-many`) on a
local instance (`--workers N`) or a cluster (`--address` / $RAY_ADDRESS). A pair that fails is left out of the
tables and named in the Markdown's settings; the others finish.

    python benchmarks/studies/neubrdf/brdf.py --quick
    python benchmarks/studies/neubrdf/brdf.py --quick --engine ray --workers 2
    python benchmarks/studies/neubrdf/brdf.py --models neubrdf,nbrdf --materials paper_white_rgb,plastic --steps 5000
    python benchmarks/studies/neubrdf/brdf.py --table4 --pool 262144 --batch-cap 8192 --steps 6000,nbrdf-t4=20000
"""
from __future__ import annotations

import argparse
import math
import os
import socket
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from rich.console import Console
from rich.table import Table

from neumat.core.query import Query
from neumat.fit.measured_samples import MeasuredSamples
from neumat.fit.method import recipe_for
from neumat.methods.latent_mlp.train import HOMOGENEOUS_RECIPE
from neumat.fit.trainer import fit
from neumat.catalog.open_material import open_material
from neumat.cli.fit_engines import RunProgress, add_engine_arguments, run_jobs
from neumat.io.shared_data import shared_data_dir
from neumat.metrics.flops import model_flops
from neumat.metrics.hdr import cosine_queries, reflectance_errors
from neumat.metrics.image import image_metrics
from neumat.models.registry import model_class
from neumat.render.render import render
from neumat.warp.hemisphere import sample_cosine_hemisphere

#: benchmark model name -> (registry name, config fields)
MODELS = {
    "neubrdf": ("neubrdf", {}),
    "neubrdf-dense": ("neubrdf", {"features": "dense"}),
    "neubrdf-lowbit": ("neubrdf", {"features": "lowbit"}),
    "naive-mlp": ("naive-mlp", {}),
    "nbrdf": ("nbrdf", {}),
    "ggx": ("ggx", {}),
    # Timonen et al. 2025, Table 3: homogeneous models at ~800-900 FLOPs per evaluation (our analytic count),
    # SiLU hidden layers and an exponential output (their Sec. 5 standardisation)
    "naive-mlp-t4": ("naive-mlp", {"hidden": 16, "hidden_layers": 2, "activation": "silu"}),
    "nbrdf-t4": ("nbrdf", {"hidden": 16, "hidden_layers": 2, "activation": "silu", "output": "exp"}),
    # 8-channel 16 x 48 angular textures as the gated model; the warps' FLOPs go to a wider MLP (16 -> 17 -> 3)
    "tripleplane-t4": ("tripleplane", {"homogeneous": True, "half_channels": 8, "diff_channels": 8,
                                        "angular_phi": 48, "hidden": 17, "hidden_layers": 1}),
    "multiscale-t4": ("multiscale", {"homogeneous": True, "angular_phi": 48}),
}

#: benchmark model name -> recipe, where it is not the registry model's default `RECIPE`
RECIPES = {"tripleplane-t4": HOMOGENEOUS_RECIPE, "multiscale-t4": HOMOGENEOUS_RECIPE}

#: --table4: Timonen et al. 2025 Tables 3 and 4 row -> our model; paper (FLOPs, total kB fp32) and
#: (SSIM, FLIP, RMSE, MAE, RMSE-HDR, MAE-HDR) over 30 MERL / RGL materials
TABLE4_MODELS = {"Naive MLP": "naive-mlp-t4", "NBRDF [SRRW21]": "nbrdf-t4", "Tripleplane [XMWY24]": "tripleplane-t4",
                 "Ours (gated)": "multiscale-t4"}
PAPER_MS_TABLE3 = {"Naive MLP": (831, 2.70), "NBRDF [SRRW21]": (791, 2.25), "Tripleplane [XMWY24]": (888, 50.9),
                   "Ours (gated)": (842, 50.6)}
PAPER_MS_TABLE4 = {
    "Naive MLP": (0.9928, 0.0184, 0.0055, 0.0024, 1.0743, 0.0024),
    "NBRDF [SRRW21]": (0.9939, 0.0158, 0.0044, 0.0020, 0.6534, 0.0020),
    "Tripleplane [XMWY24]": (0.9974, 0.0104, 0.0029, 0.0012, 0.8144, 0.0012),
    "Ours (gated)": (0.9972, 0.0107, 0.0028, 0.0012, 0.4801, 0.0012),
}
TABLE4_OUT = "benchmarks/studies/neubrdf/results/brdf_table4_rgl.md"

#: analytic materials (spec strings) beside the measured RGL files
ANALYTIC = {
    "plastic": "plastic:diffuse=0.6/0.3/0.15,roughness=0.3",
    "gold-ggx": "ggx:roughness=0.15,fresnel=conductor,material=gold",
    "principled-aniso": "principled:base_color=0.8/0.5/0.2,metallic=1,roughness=0.4,anisotropy=0.6",
}

#: NeuBRDF paper, Table 3: image MAE / RMSE / SSIM averaged over all MERL materials
PAPER_TABLE3 = {
    "GGX [Walter 2007]": (0.0189, 0.0206, 0.969),
    "Low et al.": (0.0080, 0.0088, 0.986),
    "Dupuy et al.": (0.0174, 0.0190, 0.976),
    "NPF": (0.0056, 0.0062, 0.990),
    "NBRDF [Sztrajman 2021]": (0.0028, 0.0033, 0.995),
    "NeuBRDF (ours in the paper)": (0.0017, 0.0031, 0.996),
}

#: --quick: few steps, small grids and images, two materials
QUICK = {"steps": 150, "batch_cap": 4096, "no_ema": True, "nside": 16, "hdr_n": 2 ** 15, "resolution": 48, "spp": 8,
         "materials": ["paper_white_rgb", "plastic"]}
FULL = {"steps": None, "batch_cap": None, "no_ema": False, "nside": None, "hdr_n": 2 ** 20, "resolution": 256,
        "spp": 64, "materials": None}
#: --pool N: the source is measured once at N cosine-distributed (wi, wo) pairs and every model is fitted by
#: replaying them (measured sources are slow to evaluate online); 0 = online targets
DEFAULT_POOL = 0

COLUMNS = ["rmse_hdr", "mae_hdr", "img_mae", "img_rmse", "img_ssim", "img_flip", "flops", "bytes_fp16", "fit_s",
           "evals_per_s"]
#: averaged per model beside COLUMNS, not shown in the generic tables
EXTRA = ["bytes_fp32"]


def parse_steps(text: str) -> tuple[int | None, dict[str, int]]:
    """`--steps`: "6000" (every model) or "6000,nbrdf-t4=20000" (per-model overrides, default optional)
    -> (default or None, {model: steps})."""
    default, per_model = None, {}
    for part in filter(None, (p.strip() for p in text.split(","))):
        name, _, value = part.rpartition("=")
        try:
            steps = int(value)
        except ValueError:
            raise argparse.ArgumentTypeError(f"--steps: expected N or MODEL=N, got {part!r}") from None
        if steps < 0:
            raise argparse.ArgumentTypeError(f"--steps: expected a step count >= 0, got {part!r}")
        if name:
            per_model[name] = steps
        else:
            default = steps
    return default, per_model


def available_materials(data: Path | None) -> dict[str, str]:
    """Benchmark material name -> what `open_material` opens: RGL files from shared data, then analytic specs."""
    out = {}
    if data is not None:
        for path in sorted((data / "rgl").glob("*.bsdf")):
            out[path.stem] = str(path)
    out.update(ANALYTIC)
    return out


def build_model(name: str, nside: int | None):
    registry, fields = MODELS[name]
    if nside is not None and registry == "neubrdf":
        fields = {**fields, "nside": nside}
    return model_class(registry)(**fields), registry


def evals_per_second(model, device, n: int = 2 ** 16, repeats: int = 5) -> float:
    gen = torch.Generator().manual_seed(0)
    q = Query(sample_cosine_hemisphere(torch.rand(n, 2, generator=gen)),
              sample_cosine_hemisphere(torch.rand(n, 2, generator=gen))).to(device)
    with torch.no_grad():
        model.eval(q)  # warm-up
        if device.type == "cuda":
            torch.cuda.synchronize()
        t0 = time.perf_counter()
        for _ in range(repeats):
            model.eval(q)
        if device.type == "cuda":
            torch.cuda.synchronize()
    return n * repeats / (time.perf_counter() - t0)


def sphere_image(material, light: str, settings: dict, device) -> np.ndarray:
    img = render(material, "sphere", light, spp=settings["spp"], resolution=settings["resolution"],
                 strategy="light", seed=0, device=device)
    return img.detach().cpu().numpy()


def run(args) -> tuple[list[dict], dict]:
    settings = dict(QUICK if args.quick else FULL)
    for key in ("nside", "pool", "resolution", "spp", "batch_cap"):
        if getattr(args, key) is not None:
            settings[key] = getattr(args, key)
    default_steps, model_steps = args.steps if args.steps is not None else (None, {})
    if default_steps is not None:
        settings["steps"] = default_steps
    if model_steps:
        settings["model_steps"] = model_steps
    device = torch.device(args.device or ("cuda" if torch.cuda.is_available() else "cpu"))
    data = shared_data_dir()
    known = available_materials(data)
    rgl = [m for m, spec in known.items() if spec.endswith(".bsdf")]
    default_materials = rgl if args.table4 else (settings["materials"] or list(known))
    names = args.materials.split(",") if args.materials else default_materials
    unknown = [m for m in names if m not in known]
    if unknown:
        sys.exit(f"unknown material(s) {', '.join(unknown)}; known: {', '.join(known)}")
    models = args.models.split(",") if args.models else list(TABLE4_MODELS.values() if args.table4 else MODELS)
    bad = [m for m in [*models, *model_steps] if m not in MODELS]
    if bad:
        sys.exit(f"unknown model(s) {', '.join(bad)}; known: {', '.join(MODELS)}")
    envmap = Path(args.envmap) if args.envmap else (data / "envmap" / "studio_small_03_1k.hdr" if data else None)
    light = f"env:{envmap}" if envmap is not None and envmap.is_file() else "env:sky"
    settings.update(materials=names, device=str(device), light=light)
    jobs = [{"material": m, "spec": known[m], "model": mn, "settings": settings, "progress": not args.no_progress}
            for m in names for mn in models]
    console = Console(stderr=True)
    progress = RunProgress(len(jobs), console)
    stream = run_jobs(args, jobs, fit_pair, progress, gpus_per_task=1.0 if device.type == "cuda" else 0.0,
                      lost=lost_pair, log=console.print)
    done = {(r["material"], r["model"]): r for r in stream}
    rows = [done[j["material"], j["model"]] for j in jobs]
    failed = [r for r in rows if r["status"] != "ok"]
    if failed:
        settings["failed"] = "; ".join(f"{r['model']} on {r['material']}: {r['error']}" for r in failed)
    return [r for r in rows if r["status"] == "ok"], settings


def fit_pair(job: dict) -> dict:
    """Fit and measure one (material, model) pair of `run`: its row, with status "ok", or "error" and the error."""
    t0 = time.perf_counter()
    row = {"name": job["material"], "material": job["material"], "model": job["model"], "status": "ok",
           "error": None, "worker": f"{socket.gethostname()}:{os.getpid()}"}
    try:
        row.update(measure_pair(job["material"], job["spec"], job["model"], job["settings"], job["progress"]))
    except Exception as e:  # noqa: BLE001 - one failing pair must not stop the table
        row.update(status="error", error=f"{type(e).__name__}: {e}")
    row["seconds"] = time.perf_counter() - t0
    return row


def lost_pair(job: dict, error: BaseException) -> dict:
    """The row of a pair whose Ray task was lost (its worker died on every try)."""
    return {"name": job["material"], "material": job["material"], "model": job["model"], "status": "error",
            "error": f"{type(error).__name__}: {error}", "worker": None, "seconds": 0.0}


def measure_pair(mat_name: str, spec: str, model_name: str, settings: dict, progress: bool) -> dict:
    """Fit `model_name` to material `spec` with the benchmark's settings and measure it (the COLUMNS)."""
    device = torch.device(settings["device"])
    source = open_material(spec)
    train_source, queries = source, None
    if settings.get("pool", DEFAULT_POOL):
        pool = cosine_queries(settings["pool"], torch.Generator().manual_seed(1), torch.device("cpu"))
        train_source, queries = MeasuredSamples.from_material(source, pool, name=mat_name), "replay"
    ref_img = sphere_image(source, settings["light"], settings, device)
    exposure = -math.log2(max(float(np.percentile(ref_img, 99)), 1e-6))
    torch.manual_seed(0)
    model, registry = build_model(model_name, settings["nside"])
    recipe = replace(RECIPES[model_name]) if model_name in RECIPES else recipe_for(registry)
    if settings["batch_cap"]:
        recipe = replace(recipe, batch_size=min(recipe.batch_size, settings["batch_cap"]))
    if settings["no_ema"]:  # an EMA of weight 0.01 would still hold ~20 % of the initial weights
        recipe = replace(recipe, ema=0.0)
    steps = settings.get("model_steps", {}).get(model_name, settings["steps"] or recipe.steps)
    result = fit(model, train_source, recipe, steps=steps, device=device, progress=progress, queries=queries)
    if hasattr(model, "runtime"):  # NeuBRDF is measured in the paper's runtime form (frozen indices)
        model = model.runtime()
    hdr = reflectance_errors(model, source, n=settings["hdr_n"], device=device)
    img = image_metrics(ref_img, sphere_image(model, settings["light"], settings, device), exposure=exposure)
    return {"rmse_hdr": hdr["rmse_hdr"], "mae_hdr": hdr["mae_hdr"], "img_mae": img["mae"], "img_rmse": img["rmse"],
            "img_ssim": img["ssim"], "img_flip": img["flip"], "flops": model_flops(model),
            "bytes_fp16": model.size_bytes("fp16"), "bytes_fp32": model.size_bytes("fp32"), "fit_s": result.seconds,
            "evals_per_s": evals_per_second(model, device), "steps": steps, "batch": recipe.batch_size}


def averages(rows: list[dict]) -> list[dict]:
    out = []
    for model in dict.fromkeys(r["model"] for r in rows):
        mine = [r for r in rows if r["model"] == model]
        out.append({"model": model, "material": f"mean of {len(mine)}",
                    **{c: float(np.mean([r[c] for r in mine])) for c in COLUMNS + EXTRA}})
    return out


def fmt(column: str, value) -> str:
    if isinstance(value, str):
        return value
    if column in ("bytes_fp16", "flops"):
        return f"{round(value):,}"
    if column == "evals_per_s":
        return f"{value:.3g}"
    if column == "fit_s":
        return f"{value:.1f}"
    return f"{value:.4f}"


def table4(rows: list[dict]) -> tuple[list[str], list[list[str]]]:
    """Timonen et al. 2025 Tables 3 + 4 layout: per method the paper's row, then ours (mean over materials)."""
    head = ["method", "source", "FLOPs", "kB fp32", "SSIM", "FLIP", "RMSE", "MAE", "RMSE-HDR", "MAE-HDR"]
    ours = {r["model"]: r for r in averages(rows)}
    body = []
    for method, model in TABLE4_MODELS.items():
        flops, kb = PAPER_MS_TABLE3[method]
        body.append([method, "paper (30 MERL/RGL)", f"{flops:,}", f"{kb:.2f}"] +
                    [f"{v:.4f}" for v in PAPER_MS_TABLE4[method]])
        if model in ours:
            r = ours[model]
            body.append([method, f"ours: {model}, {r['material']} RGL", fmt("flops", r["flops"]),
                         f"{r['bytes_fp32'] / 1000:.2f}"] +
                        [f"{r[c]:.4f}" for c in ("img_ssim", "img_flip", "img_rmse", "img_mae", "rmse_hdr", "mae_hdr")])
    return head, body


def tables(rows: list[dict], with_table4: bool = False) -> list[tuple[str, list[str], list[list[str]]]]:
    head = ["model", "material"] + COLUMNS
    per_pair = [[fmt(c, r[c]) for c in head] for r in rows]
    mean = [[fmt(c, r[c]) for c in head] for r in averages(rows)]
    out = [("Per model and material", head, per_pair), ("Per model, averaged over materials", head, mean)]
    if with_table4:
        return [("Timonen et al. 2025 Tables 3 and 4: paper vs ours", *table4(rows))] + out
    paper = [[name, f"{mae:.4f}", f"{rmse:.4f}", f"{ssim:.3f}"] for name, (mae, rmse, ssim) in PAPER_TABLE3.items()]
    return out + [("Reference: NeuBRDF paper Table 3 (MERL, image MAE / RMSE / SSIM)", ["method", "MAE", "RMSE", "SSIM"],
                   paper)]


def markdown(rows: list[dict], settings: dict, with_table4: bool = False) -> str:
    legend = ("rmse_hdr / mae_hdr: reflectance-space errors over cosine-weighted configurations; img_*: sphere "
              "under the environment map vs the reference's rendering (tone-mapped sRGB, FLIP mean); bytes at fp16; "
              "evals_per_s: model.eval throughput (no_grad, 2^16 queries); flops: model_flops (analytic, per "
              "evaluation).")
    lines = ["# BRDF benchmark", "", "Settings: " + ", ".join(f"{k}={v}" for k, v in settings.items()), "", legend,
             ""]
    fits = dict.fromkeys(f"{r['model']}: {r['steps']} steps x {r['batch']}" for r in rows)
    lines += ["Fits: " + "; ".join(fits), ""]
    for title, head, body in tables(rows, with_table4):
        lines += [f"## {title}", "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        lines += ["| " + " | ".join(r) + " |" for r in body]
        lines.append("")
    return "\n".join(lines)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--steps", type=parse_steps, default=None,
                   help="fit steps: N for every model, and/or MODEL=N overrides, comma-separated "
                        "(default: each recipe's)")
    p.add_argument("--batch-cap", type=int, default=None, help="cap every recipe's batch size (CPU budgets)")
    p.add_argument("--nside", type=int, default=None, help="N_side of the NeuBRDF variants (default: the paper's 64)")
    p.add_argument("--pool", type=int, default=None,
                   help="measure each source once at this many (wi, wo) pairs and fit by replaying them")
    p.add_argument("--resolution", type=int, default=None, help="sphere image size in pixels")
    p.add_argument("--spp", type=int, default=None, help="samples per pixel of the sphere images")
    p.add_argument("--materials", help="comma-separated material names (RGL file stems or analytic names)")
    p.add_argument("--models", help=f"comma-separated models (default all: {', '.join(MODELS)})")
    p.add_argument("--quick", action="store_true",
                   help="smoke run: 150 steps, batch <= 4096, no EMA, NeuBRDF nside 16, 48^2 px at 8 spp, 2 materials")
    p.add_argument("--table4", action="store_true",
                   help="Timonen et al. 2025 Table 4: the -t4 models on the RGL materials, paper numbers beside ours")
    p.add_argument("--out", default=None,
                   help=f"Markdown output file (default benchmarks/results/brdf.md, {TABLE4_OUT} with --table4)")
    p.add_argument("--device", default=None, help="torch device (default: cuda if available)")
    p.add_argument("--envmap", default=None, help="environment map (default: shared studio_small_03_1k.hdr)")
    p.add_argument("--no-progress", action="store_true", help="hide the fit progress bars")
    add_engine_arguments(p, "(material, model) pair")
    args = p.parse_args(argv)
    rows, settings = run(args)
    console = Console(width=None if sys.stdout.isatty() else 220)  # full columns in logs and pipes
    for title, head, body in tables(rows, args.table4):
        table = Table(title=title)
        for h in head:
            table.add_column(h, justify="left" if h in ("model", "material", "method", "source") else "right")
        for r in body:
            table.add_row(*r)
        console.print(table)
    out = Path(args.out or (TABLE4_OUT if args.table4 else "benchmarks/results/brdf.md"))
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(markdown(rows, settings, args.table4))
    console.print(f"wrote {out}")


if __name__ == "__main__":
    main()
