"""Real-Time Neural Appearance Models on SVBRDF texture sets: the full model against its ablations and the
neumip-frame baseline, at equal steps and batch.

    python benchmarks/studies/neural_appearance/neural_appearance.py                           # three shared texture sets at 64^2
    python benchmarks/studies/neural_appearance/neural_appearance.py --sets Metal027_1K --size 128 --steps 4000
    python benchmarks/studies/neural_appearance/neural_appearance.py --speed                   # evaluations / samples per second only
    python benchmarks/studies/neural_appearance/neural_appearance.py --coat --variants full,ggx-mipmap,neumip-frame   # layered sources (Fig. 3)

Variants (each `--steps` steps of `--batch` queries, loss log_cos, Adam 3e-3 halved at 50% / 75%):
  "full"          encoder phase (half the steps), bake, latent phase (`neumat.fit.trainer.fit`, recipe
                  `neumat.methods.neural_appearance.train`), 2 frames;
  "no encoder"    the latents optimised from random values for all the steps (the paper's Fig. 8 ablation);
  "1 frame"       as "full" with one learned shading frame;
  "neumip-frame"  the baseline of Timonen et al. (one frame, preconditioned pyramid, MLP 3 x 20) trained with
                  the shared trainer (its recipe: EMA, Adam betas 0.99) on the same loss, queries (Eq. 9
                  footprints), steps and batch; "neumip-frame (Eq. 10 loss)" with its recipe's own loss;
  "half-difference" as "full", directions uniform in Rusinkiewicz half and difference angles (the paper's);
  "blurred"       as "full", targets directionally blurred early (a 10-degree cone around wo shrinking to 0
                  at half of the steps, 4 directions each; the paper's schedule for narrow peaks);
  "roulette"      as "full", fractional mip levels read by Russian roulette (one level per query in training,
                  the two-level expectation in eval; the paper's Sec. 4.1) instead of trilinearly;
  "ggx-mipmap"    the analytic baseline: diffuse + anisotropic GGX with 12 textured, filtered parameters per
                  texel (`neumat.methods.latent_mlp.ggx_mipmap`), fitted the same way with its recipe and log_cos (the
                  paper's Fig. 3 compares its neural model with such a textured analytic fit).
--variants picks some of them (default: full, no encoder, 1 frame and the two neumip-frame rows). --coat puts every
texture set under a smudged clear coat (`neumat.reflectance.layered`: eta 1.5, GGX alpha 0.03 to 0.3 by a
procedural smudge mask), the kind of layered material the paper bakes; the encoder then reads 8 + 5 surface
parameters.
Scores on held-out queries: "point log_cos" / "point rel L1" at point queries (cosine-weighted wi, wo,
uniform uv), "filtered log_cos" at Eq. 9 footprints against the SVBRDF's filtered value (256 samples);
"sampler gain" = rel var of cosine-sampled / model-sampled one-sample albedo estimates at 45 degrees and
uniform uv (neural-appearance variants). The texture set is read at --size texels (`max_size`).
Every (texture set, variant) pair is one job (`fit_pair`, from fresh seeded sources, so its scores do not depend
on the other pairs): one after another in this process, or with `--engine ray` as Ray tasks
(`neumat.cli.fit_engines`, as `neumat fit-many`) on a local instance (`--workers N`) or a cluster (`--address` /
$RAY_ADDRESS). A pair that fails is left out of the table and named under it; the others finish.

--speed: evaluations per second on the CPU instead (no training; speed does not depend on the weights):
model.eval, model.sample and the SVBRDF reference's point value (`eval_point`) on the same 2^16 point
queries, and eval with a footprint (anisotropic filtering) against the SVBRDF's filtered value (--train-samples
positions per footprint; the paper's is 256); best of three. The models' shader exports on the footprint queries:
GLSL on this OpenGL (llvmpipe without a GPU) and the Slang module on slangpy's CPU device (marginal rates, so
compilation and uploads do not count).
"""
from __future__ import annotations

import argparse
import math
import os
import socket
import time
from dataclasses import replace
from pathlib import Path

import torch
from rich.console import Console

from neumat.cli.fit_engines import RunProgress, add_engine_arguments, run_jobs
from neumat.cli.common import print_table
from neumat.core.query import Query
from neumat.export.glsl import export_glsl
from neumat.export.slang import export_slang
from neumat.fit.footprint_queries import footprint_queries
from neumat.fit.losses import LogCosLoss
from neumat.methods.neural_appearance.train import config_for_source
from neumat.warp.uniform import uniform
from neumat.fit.method import recipe_for
from neumat.fit.trainer import fit
from neumat.io.shared_data import shared_data_dir
from neumat.color.tonemap import LUMINANCE
from neumat.methods.neural_appearance.model import NeuralAppearance
from neumat.methods.latent_mlp.ggx_mipmap import GGXMipmap
from neumat.methods.latent_mlp.neumip_frame import NeuMIPFrame
from neumat.reflectance.layered import Coat, LayeredMaterial
from neumat.reflectance.smudge_map import smudge_map
from neumat.reflectance.svbrdf import SVBRDF
from neumat.testing.parity import glsl_evals_per_second, opengl_available
from neumat.testing.slang_parity import slang_available, slang_evals_per_second

VARIANTS = ("full", "no encoder", "1 frame", "neumip-frame", "neumip-frame (Eq. 10 loss)", "ggx-mipmap",
            "half-difference", "blurred", "roulette")


def open_source(folder, size: int, samples: int, coat: bool):
    """The texture set at `size` texels, under a smudged clear coat with `coat`."""
    svbrdf = SVBRDF.from_folder(folder, max_size=size, samples=samples)
    if not coat:
        return svbrdf
    roughness = 0.03 + 0.27 * smudge_map(min(svbrdf.textures.size), seed=1)
    return LayeredMaterial(svbrdf, [Coat(roughness=roughness, eta=1.5)], samples=samples,
                           name=f"{svbrdf.name} + smudged coat")
from neumat.warp.hemisphere import sample_cosine_hemisphere


def held_out(source, n: int) -> dict:
    """Point and filtered held-out queries with their targets."""
    g = torch.Generator().manual_seed(12345)
    u = uniform(n, 6, g, "cpu")
    point = Query(sample_cosine_hemisphere(u[:, :2]), sample_cosine_hemisphere(u[:, 2:4]), uv=u[:, 4:6])
    filtered = footprint_queries(source)(n, g, "cpu")
    with torch.no_grad():
        return {"point": (point, source.eval(point)), "filtered": (filtered, source.eval(filtered))}


def scores(model, data: dict) -> dict:
    loss = LogCosLoss()
    out = {}
    with torch.no_grad():
        q, t = data["point"]
        p = model.eval(q)
        out["point log_cos"] = loss(p, t, q).item()
        out["point rel L1"] = ((p - t).abs().sum() / t.abs().sum()).item()
        q, t = data["filtered"]
        out["filtered log_cos"] = loss(model.eval(q), t, q).item()
    return out


def sampler_gain(model, n: int = 100_000) -> float:
    t = math.radians(45.0)
    u = torch.rand(n, 4, generator=torch.Generator().manual_seed(7))
    q = Query(torch.tensor([math.sin(t), 0.0, math.cos(t)]).expand(n, 3), uv=u[:, 2:])
    lum = torch.tensor(LUMINANCE)
    with torch.no_grad():
        cosine = (model.eval(q.with_wo(sample_cosine_hemisphere(u[:, :2]))) @ lum) * math.pi
        learned = model.sample(q, u[:, :2]).weight @ lum
    rel = [(x.var() / x.mean() ** 2).item() for x in (cosine, learned)]
    return rel[0] / rel[1]


def rate(fn, n: int) -> float:
    """Calls of fn() per second times n (best of three, after one warm-up)."""
    with torch.no_grad():
        fn()
        best = min(_timed(fn) for _ in range(3))
    return n / best


def _timed(fn) -> float:
    t = time.perf_counter()
    fn()
    return time.perf_counter() - t


def speed_rows(name: str, source, size: int, n: int) -> list[dict]:
    """--speed: evals / samples per second of the models and of the SVBRDF reference (module docstring)."""
    g = torch.Generator().manual_seed(3)
    u = uniform(n, 6, g, "cpu")
    point = Query(sample_cosine_hemisphere(u[:, :2]), sample_cosine_hemisphere(u[:, 2:4]), uv=u[:, 4:6])
    filtered = footprint_queries(source)(n, g, "cpu")
    models = {"neural-appearance": NeuralAppearance(spatial_size=size), "neumip-frame": NeuMIPFrame(spatial_size=size)}
    rows = []
    for label, m in models.items():
        m.eval()
        row = {"set": name, "model": label, "eval/s (point)": rate(lambda: m.eval(point), n),
               "eval/s (footprint)": rate(lambda: m.eval(filtered), n)}
        row["sample/s"] = rate(lambda: m.sample(point, u[:, :2]), n) if m.can_sample else float("nan")
        row["GLSL eval/s (llvmpipe)"] = glsl_evals_per_second(export_glsl(m), filtered) if opengl_available() \
            else float("nan")
        row["Slang eval/s (CPU)"] = slang_evals_per_second(export_slang(m), filtered) if slang_available() \
            else float("nan")
        rows.append(row | {"FLOPs": m.flops()})
    rows.append({"set": name, "model": f"SVBRDF reference ({source.samples} footprint samples)",
                 "eval/s (point)": rate(lambda: source.eval_point(point.wi, point.wo, point.uv), n),
                 "eval/s (footprint)": rate(lambda: source.eval(filtered), n),
                 "sample/s": rate(lambda: source.sample(point, u[:, :2]), n), "GLSL eval/s (llvmpipe)": float("nan"),
                 "Slang eval/s (CPU)": float("nan"), "FLOPs": float("nan")})
    return rows


#: the neural-appearance variants: config fields, phase split (encoder, latent) and recipe options
HALF = (0.5, 0.5)
NA_VARIANTS = {"full": ({}, HALF, {}), "no encoder": ({}, (0.0, 1.0), {}), "1 frame": ({"frames": 1}, HALF, {}),
               "half-difference": ({}, HALF, {"queries": "rusinkiewicz"}),
               "blurred": ({}, HALF, {"blur_degrees": 10.0, "blur_samples": 4, "blur_until": 0.5}),
               "roulette": ({"level_selection": "roulette"}, HALF, {})}
#: the baselines: model class and loss (None: the recipe's own)
BASELINES = {"neumip-frame": (NeuMIPFrame, "log_cos"), "neumip-frame (Eq. 10 loss)": (NeuMIPFrame, None),
             "ggx-mipmap": (GGXMipmap, "log_cos")}


def fit_pair(job: dict) -> dict:
    """One (texture set, variant) pair of the table: {"name": set, "model": variant, "status": "ok" with "row"
    (the table's row), or "error" and the error, "worker", "seconds"}."""
    t0 = time.perf_counter()
    out = {"name": job["set"], "model": job["variant"], "status": "ok", "error": None,
           "worker": f"{socket.gethostname()}:{os.getpid()}"}
    try:
        out["row"] = score_variant(job)
    except Exception as e:  # noqa: BLE001 - one failing pair must not stop the table
        out.update(status="error", error=f"{type(e).__name__}: {e}")
    out["seconds"] = time.perf_counter() - t0
    return out


def lost_pair(job: dict, error: BaseException) -> dict:
    """The row of a pair whose Ray task was lost (its worker died on every try)."""
    return {"name": job["set"], "model": job["variant"], "status": "error",
            "error": f"{type(error).__name__}: {error}", "worker": None, "seconds": 0.0}


def score_variant(job: dict) -> dict:
    """Fit `job["variant"]` to texture set `job["set"]` (fresh seeded sources) and score it on held-out queries."""
    folder = Path(job["data_dir"]) / "svbrdf" / job["set"]
    train_src = open_source(folder, job["size"], job["train_samples"], job["coat"])
    size = 1 << (min(train_src.texture_size if job["coat"] else train_src.textures.size).bit_length() - 1)
    data = held_out(open_source(folder, job["size"], 256, job["coat"]), job["queries"])
    variant = job["variant"]
    torch.manual_seed(0)
    if variant in NA_VARIANTS:
        config, split, options = NA_VARIANTS[variant]
        model = NeuralAppearance(**{**config_for_source(train_src), **config})
        recipe = recipe_for("neural-appearance")
        fields = {k: options[k] for k in options if k == "queries"}  # a recipe field, not an option
        recipe = replace(recipe, batch_size=job["batch"], phase_split=split, **fields,
                         options={**recipe.options, **{k: v for k, v in options.items() if k not in fields}})
    else:
        kind, loss = BASELINES[variant]
        model = kind(spatial_size=size)
        recipe = replace(recipe_for(kind.name), batch_size=job["batch"], lr_decay_every=0)
        recipe.loss = loss or recipe.loss
    t = time.perf_counter()
    fit(model, train_src, recipe, steps=job["steps"], progress=False)
    seconds = time.perf_counter() - t
    gain = sampler_gain(model) if variant in NA_VARIANTS else float("nan")
    row = {"set": job["set"], "model": variant, **scores(model, data), "sampler gain": gain,
           "bytes (fp16)": model.size_bytes("fp16"), "FLOPs": model.flops(), "fit s": seconds}
    print(row, flush=True)
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sets", default="Metal027_1K,Leather05_1K_partial,Wood092_1K")
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--batch", type=int, default=2048)
    ap.add_argument("--train-samples", type=int, default=16, help="footprint samples of the training targets")
    ap.add_argument("--queries", type=int, default=4096, help="held-out queries of each kind")
    ap.add_argument("--speed", action="store_true", help="evaluations per second only (module docstring)")
    ap.add_argument("--coat", action="store_true", help="layered sources: a smudged clear coat over each set")
    ap.add_argument("--variants", default=",".join(VARIANTS[:5]), help=f"comma-separated, of: {', '.join(VARIANTS)}")
    add_engine_arguments(ap, "(set, variant) pair")
    args = ap.parse_args()
    chosen = args.variants.split(",")
    unknown = sorted(set(chosen) - set(VARIANTS))
    if unknown:
        raise SystemExit(f"--variants: unknown {', '.join(unknown)} (known: {', '.join(VARIANTS)})")
    data_dir = shared_data_dir()
    if data_dir is None:
        raise SystemExit("needs shared/data/svbrdf (set NEUMAT_SHARED_DATA or put shared/ beside the checkout)")
    rows, failed = [], []
    if args.speed:
        for name in args.sets.split(","):
            train_src = open_source(data_dir / "svbrdf" / name, args.size, args.train_samples, args.coat)
            size = 1 << (min(train_src.texture_size if args.coat else train_src.textures.size).bit_length() - 1)
            rows += speed_rows(name, train_src, size, 1 << 16)
    else:
        order = [v for v in VARIANTS if v in chosen]  # the table's order: neural-appearance variants, baselines
        order = [v for v in order if v in NA_VARIANTS] + [v for v in order if v in BASELINES]
        jobs = [{"set": name, "variant": v, "data_dir": str(data_dir), "size": args.size, "steps": args.steps,
                 "batch": args.batch, "train_samples": args.train_samples, "queries": args.queries,
                 "coat": args.coat} for name in args.sets.split(",") for v in order]
        console = Console(stderr=True)
        progress = RunProgress(len(jobs), console)
        stream = run_jobs(args, jobs, fit_pair, progress, gpus_per_task=0.0, lost=lost_pair, log=console.print)
        done = {(r["name"], r["model"]): r for r in stream}
        results = [done[j["set"], j["variant"]] for j in jobs]
        rows = [r["row"] for r in results if r["status"] == "ok"]
        failed = [f"{r['model']} on {r['name']}: {r['error']}" for r in results if r["status"] != "ok"]
    what = "speed" if args.speed else f"{args.steps} steps x {args.batch}"
    sets = "texture sets under a smudged coat" if args.coat else "texture sets"
    print_table(f"neural-appearance on {args.size}^2 {sets}, {what} ({torch.get_num_threads()} threads)", rows,
                width=200)
    if failed:
        print("failed (not in the table): " + "; ".join(failed))


if __name__ == "__main__":
    main()
