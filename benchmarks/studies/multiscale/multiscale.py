"""Multi-scale SVBRDF benchmark (Timonen et al. 2025, Sec. 5.2): fit models to prefiltered SVBRDFs and
evaluate them on the planar scene over scales x directional lights x cameras.

For each texture set and model: fit with the model's recipe (steps / batch / footprint samples overridable:
full-size runs belong on a GPU), then render the plane (one sample through each pixel centre, the material
filters by the pixel footprint, light sampling of a directional light) for `--scales` texture scales
(geometric, from 1/8 texel to the whole texture per pixel) x 4 lights x 3 camera tilts, against the
reference SVBRDF with `--ref-samples` footprint samples. Texture sets are downscaled to `--max-size`, or with
`--crop N` cut to N x N texels at full resolution (native texel density: normal and roughness detail of the
full-size set), at the top-left corner, with `--crop-at detail` where the set has the most detail, or with `--crop-at ROW,COL`
at that texel. Training footprints follow the paper's Eq. 9 distribution in texels of the
trained texture (`--footprints texel`, the default: the "footprint" sampler's range shifted by log2(1024 / S))
or, with `--footprints uv`, the paper's uv range whatever the size (most footprints below a texel on small sets).
Prints per-scale FLIP, a Table-6-style table
(SSIM, FLIP, RMSE, MAE on tone-mapped images, RMSE/MAE-HDR over random Sec. 4.2 queries), bytes (fp32)
and FLOPs (the models' analytic count, 2 per multiply-add, and the paper's, `neumat.metrics.flops.paper_flops`:
1 per multiply-add, 3 per SiLU), the regime statistics of each set (mean normal tilt, roughness spread), training
steps/s, and evaluations/s of each model against the principled GGX point evaluation
on the same batch.

Models are registry names, optionally with config overrides for ablations, e.g.
`multiscale:gating=false:shading_frame=false`. With `--markdown [PATH]` the tables are also written to PATH
(default benchmarks/studies/multiscale/results/multiscale.md) and the per-scale FLIP chart (the paper's Fig. 4) beside it
(<stem>_flip.png).
A long run can be split across processes by --models, each with `--save part.json`, then reported together
with `--merge a.json b.json --markdown`. Every (texture set, model) pair is one job (`fit_pair`, from fresh
seeded sources, so its scores do not depend on the other pairs): one after another in this process, or with
`--engine ray` as Ray tasks (`neumat.cli.fit_engines`, as `neumat fit-many`) on a local instance (`--workers N`)
or a cluster (`--address` / $RAY_ADDRESS). A pair that fails is left out of the means and named under the
tables; the others finish.

    python benchmarks/studies/multiscale/multiscale.py --quick
    python benchmarks/studies/multiscale/multiscale.py --quick --engine ray --workers 2
    python benchmarks/studies/multiscale/multiscale.py --device cuda --steps 100000 --batch 65536 --max-size 1024
"""
from __future__ import annotations

import argparse
import json
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

from neumat.cli.fit_engines import RunProgress, add_engine_arguments, run_jobs
from neumat.core.material import Material
from neumat.fit.footprint_queries import footprint_queries
from neumat.fit.method import recipe_for
from neumat.fit.trainer import fit
from neumat.io.texture_set import load_texture_set
from neumat.metrics.flops import model_flops, paper_flops
from neumat.metrics.hdr import reflectance_errors
from neumat.metrics.image import image_metrics
from neumat.models.registry import build_model
from neumat.reflectance.microfacet import principled_eval
from neumat.reflectance.svbrdf import SVBRDF
from neumat.reflectance.texture_statistics import texture_statistics
from neumat.render.scale_series import LIGHTS, TILTS, plane_scales, render_scale_series

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "svbrdf"
RESULTS = Path(__file__).resolve().parent / "results"
#: the paper's models: its NeuMIP baseline is "neumip-offset" (with the offset module, as Sec. 5.2 implements it);
#: "neumip" (without it) stays as a reference
ALL_MODELS = ["multiscale", "tripleplane", "neumip-frame", "neumip-offset", "neumip", "nbrdf-uv", "ggx-mipmap"]


def model_spec(text: str, size: int) -> dict:
    """`name[:key=json_value]...` -> a registry spec with the pyramid size `size`."""
    name, *options = text.split(":")
    spec = {"type": name, "spatial_size": size}
    for option in options:
        key, _, value = option.partition("=")
        spec[key] = json.loads(value)
    return spec


def evals_per_second(fn, n: int, device, repeats: int = 5) -> float:
    fn()  # warm-up
    if device.type == "cuda":
        torch.cuda.synchronize()
    t = time.perf_counter()
    for _ in range(repeats):
        fn()
    if device.type == "cuda":
        torch.cuda.synchronize()
    return n * repeats / (time.perf_counter() - t)


def plot_per_scale(curves: dict[str, np.ndarray], path: Path) -> None:
    """Per-scale FLIP chart (the paper's Fig. 4): one line per model, curves[name] (scales,), to `path` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 3.8))
    for name, curve in curves.items():
        ax.plot(np.arange(len(curve)), curve, label=name, marker="o", markersize=3)
    ax.set_yscale("log")
    ax.set_xlabel("scale (fine -> coarse)")
    ax.set_ylabel("FLIP (log scale)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(loc="center left", bbox_to_anchor=(1.02, 0.5), fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def fit_and_score(args, folders: list[Path], device) -> dict:
    """Fit every model of args.models to every texture set and score it, each (texture set, model) pair one job
    (`fit_pair`) run by `args.engine`. Returns {"materials": [names], "models": [specs], "per_scale": {model:
    [per-scale FLIP (scales,) per material, None where the pair failed]}, "rows": {model: [metrics per material,
    or None]}, "settings": the budget, "failed": ["model on material: error"]}."""
    lights, tilts = (LIGHTS[:2], TILTS[1:2]) if args.quick else (LIGHTS, TILTS)
    settings = {"steps": args.steps, "batch": args.batch, "samples": args.samples, "ref_samples": args.ref_samples,
                "max_size": args.max_size, "crop": args.crop, "crop_at": args.crop_at, "footprints": args.footprints,
                "resolution": args.resolution, "scales": args.scales,
                "hdr_queries": args.hdr_queries, "short_run_optimiser": args.short_run_optimiser,
                "lights": len(lights), "cameras": len(tilts), "device": device.type, "seed": args.seed}
    jobs = [{"folder": str(folder), "model": name, "settings": settings, "lights": lights, "tilts": tilts,
             "device": str(device)} for folder in folders for name in args.models]
    console = Console(stderr=True)
    progress = RunProgress(len(jobs), console)
    stream = run_jobs(args, jobs, fit_pair, progress, gpus_per_task=1.0 if device.type == "cuda" else 0.0,
                      lost=lost_pair, log=console.print)
    done = {(r["folder"], r["model"]): r for r in stream}
    materials, pyramids, failed, regimes = [], [], [], []
    per_scale: dict[str, list] = {m: [] for m in args.models}
    rows: dict[str, list] = {m: [] for m in args.models}
    for folder in folders:
        mine = [done[str(folder), name] for name in args.models]
        ok = [r for r in mine if r["status"] == "ok"]
        materials.append(ok[0]["material"] if ok else folder.name)
        pyramids.extend(r["pyramid"] for r in ok[:1])
        regimes.extend(r["regime"] for r in ok[:1])
        for r in mine:
            per_scale[r["model"]].append(r["per_scale"] if r["status"] == "ok" else None)
            rows[r["model"]].append(r["metrics"] if r["status"] == "ok" else None)
            if r["status"] != "ok":
                failed.append(f"{r['model']} on {r['name']}: {r['error']}")
    return {"materials": materials, "pyramids": pyramids, "regimes": regimes, "models": list(args.models),
            "per_scale": per_scale,
            "rows": rows, "settings": settings, "failed": failed}


def fit_pair(job: dict) -> dict:
    """Fit and score one (texture set, model) pair of `fit_and_score`: its row, with status "ok" (per_scale,
    metrics, pyramid, material), or "error" and the error."""
    t0 = time.perf_counter()
    folder = Path(job["folder"])
    row = {"name": folder.name, "folder": job["folder"], "model": job["model"], "status": "ok", "error": None,
           "worker": f"{socket.gethostname()}:{os.getpid()}"}
    try:
        row.update(score_pair(folder, job["model"], job["settings"], job["lights"], job["tilts"],
                              torch.device(job["device"])))
    except Exception as e:  # noqa: BLE001 - one failing pair must not stop the tables
        row.update(status="error", error=f"{type(e).__name__}: {e}")
    row["seconds"] = time.perf_counter() - t0
    return row


def lost_pair(job: dict, error: BaseException) -> dict:
    """The row of a pair whose Ray task was lost (its worker died on every try)."""
    return {"name": Path(job["folder"]).name, "folder": job["folder"], "model": job["model"], "status": "error",
            "error": f"{type(error).__name__}: {error}", "worker": None, "seconds": 0.0}


#: (texture set, settings) -> reference images and the reference's generator state after rendering them, so that
#: the pairs of one texture set run in one process render them once and every pair scores the same
_REFERENCES: dict = {}


def score_pair(folder: Path, name: str, st: dict, lights: list[str], tilts: list[float], device) -> dict:
    """Fit model spec `name` to the texture set in `folder` with the budget `st` and score it: per-scale FLIP
    (scales,), the Table-6 metrics, the model's pyramid size and the material's name."""
    crop, origin = st.get("crop"), (0, 0)
    crop_at = st.get("crop_at", "top-left")
    if crop and crop_at != "top-left":
        full = load_texture_set(folder)
        origin = detail_origin(full, crop) if crop_at == "detail" else tuple(int(v) for v in crop_at.split(","))
        textures = full.crop(*origin, crop, crop).to(device)
    else:
        textures = load_texture_set(folder, max_size=None if crop else st["max_size"], crop=crop).to(device)
    texel_relative = st.get("footprints", "uv") == "texel"
    source = SVBRDF(textures, samples=st["samples"], seed=st.get("seed", 0))
    reference = SVBRDF(textures, samples=st["ref_samples"], seed=1)
    size = 1 << int(math.floor(math.log2(max(textures.size))))
    scales = plane_scales(st["scales"], st["resolution"], max(textures.size))
    key = (str(folder), json.dumps(st, sort_keys=True), tuple(lights), tuple(tilts), str(device))
    if key not in _REFERENCES:
        t = time.perf_counter()
        _REFERENCES.clear()  # one texture set's images at a time
        images = render_scale_series(reference, scales, lights, tilts, st["resolution"], device)
        _REFERENCES[key] = (images, reference.generator.get_state())
        print(f"{textures.name}: reference {len(images)} images in {time.perf_counter() - t:.0f} s")
    ref_images, state = _REFERENCES[key]
    reference.generator.set_state(state)
    torch.manual_seed(st.get("seed", 0))
    model = build_model(model_spec(name, size)).to(device)
    recipe = replace(recipe_for(model.name), steps=st["steps"], batch_size=st["batch"], seed=st.get("seed", 0))
    if st["short_run_optimiser"]:
        recipe = replace(recipe, lr=1e-2, betas=(0.9, 0.999), ema=0.02, lr_decay_every=0)
    result = fit(model, source, recipe, device=device, progress=True,
                 queries="footprint" if texel_relative else "footprint-uv")
    images = render_scale_series(result.model, scales, lights, tilts, st["resolution"], device)
    metrics = [image_metrics(r, m) for r, m in zip(ref_images, images)]
    per_img = len(lights) * len(tilts)
    per_scale = [float(np.mean([m["flip"] for m in metrics[i * per_img:(i + 1) * per_img]]))
                 for i in range(len(scales))]
    hdr = reflectance_errors(result.model, reference, n=st["hdr_queries"], device=device,
                             query_sampler=footprint_queries(reference, model, texel_relative=texel_relative))
    scores = {**{k: float(np.mean([m[k] for m in metrics])) for k in ("ssim", "flip", "rmse", "mae")},
              "rmse_hdr": hdr["rmse_hdr"], "mae_hdr": hdr["mae_hdr"], "steps_per_s": result.steps / result.seconds}
    print(f"{textures.name} / {name}: FLIP {scores['flip']:.4f}, fit {result.seconds:.0f} s")
    return {"per_scale": per_scale, "metrics": scores, "pyramid": size, "material": textures.name,
            "regime": {**regime_statistics(textures), "origin": list(origin)}}


def crop_position(text: str) -> str:
    """--crop-at: "top-left", "detail" or "ROW,COL" (two integers >= 0)."""
    parts = text.split(",")
    if text in ("top-left", "detail") or (len(parts) == 2 and all(p.strip().isdigit() for p in parts)):
        return text
    raise argparse.ArgumentTypeError(f"expected top-left, detail or ROW,COL, got {text!r}")


def detail_origin(textures, n: int, stride: int = 32) -> tuple[int, int]:
    """(row, col) of the n x n window, on a grid of `stride` texels, with the most normal and roughness detail:
    the largest mean normal tilt / its largest value over the windows + roughness standard deviation / its
    largest value (the two `regime_statistics` a crop has to represent)."""
    tilt = torch.rad2deg(torch.acos(textures.normal[..., 2].float().clamp(-1, 1)))[None, None]
    r = textures.roughness.float()[None, None]
    mean_tilt = torch.nn.functional.avg_pool2d(tilt, n, stride)[0, 0]
    mean_r = torch.nn.functional.avg_pool2d(r, n, stride)[0, 0]
    std_r = (torch.nn.functional.avg_pool2d(r * r, n, stride)[0, 0] - mean_r ** 2).clamp(min=0).sqrt()
    score = mean_tilt / mean_tilt.max().clamp(min=1e-12) + std_r / std_r.max().clamp(min=1e-12)
    row, col = divmod(int(score.argmax()), score.shape[1])
    return row * stride, col * stride


def regime_statistics(textures) -> dict:
    """Mean normal tilt (degrees from the geometric normal) and roughness spread (standard deviation, and the
    5-95 % range) of a texture set (`neumat.reflectance.texture_statistics`, without the separability rank): how
    much detail a fit has to represent."""
    stats = texture_statistics(textures, footprints=())
    return {k: stats[k] for k in ("size", "tilt_deg", "roughness_mean", "roughness_std", "roughness_p5_p95")}


def merge_results(paths: list[Path]) -> dict:
    """Results of several `--save` runs over the same texture sets and settings, their models side by side."""
    parts = [json.loads(Path(p).read_text()) for p in paths]
    first = parts[0]
    for path, part in zip(paths[1:], parts[1:]):
        for key in ("materials", "settings"):
            if part[key] != first[key]:
                raise SystemExit(f"--merge: {path} has other {key} than {paths[0]}: {part[key]} vs {first[key]}")
    merged = {"materials": first["materials"], "settings": first["settings"], "models": [], "per_scale": {},
              "pyramids": first.get("pyramids"), "regimes": first.get("regimes"),
              "rows": {}, "commands": [c for part in parts for c in part.get("commands", [])],
              "failed": [f for part in parts for f in part.get("failed", [])]}
    for part in parts:
        for name in part["models"]:
            if name in merged["per_scale"]:
                raise SystemExit(f"--merge: model {name!r} appears in more than one file")
            merged["models"].append(name)
            merged["per_scale"][name] = part["per_scale"][name]
            merged["rows"][name] = part["rows"][name]
    return merged


def report(results: dict, device, markdown: Path | None) -> None:
    """Print the per-scale FLIP, per-material FLIP and Table-6-style tables; with `markdown` (a .md path), also
    write them there and the per-scale chart beside it (<stem>_flip.png)."""
    st, materials = results["settings"], results["materials"]
    # a failed pair is None in per_scale / rows: means over the model's other materials; no pair left: no row
    models = [m for m in results["models"] if any(r is not None for r in results["rows"][m])]
    lines = [f"Per-scale FLIP (mean over {len(materials)} material(s), {st['lights']} lights, {st['cameras']} "
             "cameras; scale 0 = finest)", "", "| model | " + " | ".join(str(i) for i in range(st["scales"])) + " |",
             "|---" * (st["scales"] + 1) + "|"]
    for name in models:
        curve = np.mean([c for c in results["per_scale"][name] if c is not None], 0)
        lines.append(f"| {name} | " + " | ".join(f"{v:.4f}" for v in curve) + " |")
    if len(materials) > 1:
        lines += ["", "Mean FLIP per material", "", "| model | " + " | ".join(materials) + " |",
                  "|---" * (len(materials) + 1) + "|"]
        for name in models:
            lines.append(f"| {name} | " + " | ".join("failed" if r is None else f"{r['flip']:.4f}"
                                                     for r in results["rows"][name]) + " |")
    print("\n" + "\n".join(lines))

    n = 1 << 16
    g = torch.Generator().manual_seed(0)
    # the speed models get the largest pyramid the fits used (files saved before "pyramids" existed: --max-size)
    size = max(results.get("pyramids") or [1 << int(math.floor(math.log2(st.get("crop") or st["max_size"])))])
    # Sec. 4.2 queries with footprints; the draw only asks its source whether it is a surface (any Material is)
    q = footprint_queries(Material())(n, g, "cpu").to(device)
    params = (torch.rand(n, 3, device=device), torch.rand(n, device=device), torch.rand(n, device=device),
              torch.zeros(n, device=device))
    with torch.no_grad():
        ggx_rate = evals_per_second(lambda: principled_eval(q.wi, q.wo, *params), n, device)
    table6 = len(lines)
    lines += ["", f"Table 6 style ({st['steps']} steps of {st['batch']} queries per model, {st['samples']}-sample "
              "targets; paper: ~500k steps of 65536)", "",
              "| model | SSIM | FLIP | RMSE | MAE | RMSE-HDR | MAE-HDR | kB fp32 | FLOPs | FLOPs (paper) | steps/s | "
              "eval/s | x GGX |", "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for name in models:
        model = build_model(model_spec(name, size)).to(device)
        with torch.no_grad():
            rate = evals_per_second(lambda: model.eval(q), n, device)
        counted = paper_flops(model, q[:4096])
        rows = [row for row in results["rows"][name] if row is not None]
        r = {k: float(np.mean([row[k] for row in rows])) for k in rows[0]}
        lines.append(f"| {name} | {r['ssim']:.4f} | {r['flip']:.4f} | {r['rmse']:.4f} | {r['mae']:.4f} | "
                     f"{r['rmse_hdr']:.4f} | {r['mae_hdr']:.4f} | {model.size_bytes('fp32') / 1e3:.1f} | "
                     f"{model_flops(model)} | {counted:.0f} | {r['steps_per_s']:.2f} | {rate:.3g} | "
                     f"{ggx_rate / rate:.1f} |")
    lines += ["", f"principled GGX point evaluation: {ggx_rate:.3g} eval/s; \"x GGX\" = GGX evaluations per second "
              f"/ the model's (same batch of 65536 queries; models with {size}^2 pyramids). FLOPs: the models' "
              "analytic count (2 per multiply-add, 9 per texture-read channel); FLOPs (paper): counted as the paper "
              "does (EDM2's prices: 1 per multiply-add, 3 per SiLU, 4 per bilinear-read channel; no spatial fetch)."]
    if results.get("regimes"):
        lines += ["", "Regime of the trained texture sets (origin: the crop's first row, column)", "",
                  "| material | texels | origin | mean normal tilt (deg) | roughness mean | roughness std | roughness 5-95 % |",
                  "|---|---|---|---|---|---|---|"]
        for name, g in zip(materials, results["regimes"]):
            lines.append(f"| {name} | {g['size'][1]}x{g['size'][0]} | {tuple(g.get('origin', (0, 0)))} | {g['tilt_deg']:.2f} | {g['roughness_mean']:.3f} "
                         f"| {g['roughness_std']:.3f} | {g['roughness_p5_p95'][0]:.3f}-"
                         f"{g['roughness_p5_p95'][1]:.3f} |")
    if results.get("failed"):
        lines += ["", "Failed pairs (left out of the means): " + "; ".join(results["failed"])]
    print("\n".join(lines[table6:]))
    if markdown:
        chart = markdown.with_name(markdown.stem + "_flip.png")
        sets = f"cropped to {st['crop']}^2 at full resolution" if st.get("crop") else f"at most {st['max_size']}^2"
        footprints = ("texels of the trained texture (the paper's 1024^2 distribution)"
                      if st.get("footprints") == "texel" else "uv units (the paper's range)")
        header = [f"# Multi-scale SVBRDF benchmark ({', '.join(materials)})", "",
                  "Commands: " + "; ".join(f"`{c}`" for c in results["commands"])
                  + f" on {st['device']}; texture sets {sets}, training footprints in {footprints}, model "
                  f"pyramids {size}^2, "
                  f"{st['scales']} scales x {st['lights']} lights x {st['cameras']} cameras at "
                  f"{st['resolution']} px, references with {st['ref_samples']} footprint samples; HDR errors over "
                  f"{st['hdr_queries']} Sec. 4.2 queries. Training budget: {st['steps']} steps x {st['batch']} queries"
                  + (" (short-run optimiser: Adam (0.9, 0.999), lr 1e-2, EMA 0.02)" if st["short_run_optimiser"]
                     else " (paper recipe)") + ".", "", f"![per-scale FLIP]({chart.name})", ""]
        markdown.write_text("\n".join(header + lines) + "\n")
        plot_per_scale({name: np.mean(results["per_scale"][name], 0) for name in models}, chart)
        print(f"wrote {markdown} and {chart}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--materials", nargs="*", default=None, help="texture-set folders (default: all shared sets)")
    ap.add_argument("--models", nargs="*", default=ALL_MODELS, help="model specs name[:key=value]...")
    ap.add_argument("--steps", type=int, default=3000)
    ap.add_argument("--batch", type=int, default=8192)
    ap.add_argument("--samples", type=int, default=16, help="footprint samples of the training targets")
    ap.add_argument("--ref-samples", type=int, default=256, help="footprint samples of the reference images")
    ap.add_argument("--max-size", type=int, default=256, help="downscale the texture sets to this size")
    ap.add_argument("--crop", type=int, default=None,
                    help="instead of --max-size: N x N texels of each set at full resolution (see --crop-at)")
    ap.add_argument("--crop-at", type=crop_position, default="top-left",
                    help="where --crop cuts: top-left, detail (the window on a 32-texel grid with the most "
                         "normal-tilt and roughness detail, detail_origin) or ROW,COL (that texel)")
    ap.add_argument("--footprints", choices=("texel", "uv"), default="texel",
                    help="training footprints: the paper's distribution in texels of the trained texture (texel), "
                         "or its range in uv units (uv)")
    ap.add_argument("--resolution", type=int, default=64)
    ap.add_argument("--scales", type=int, default=21)
    ap.add_argument("--hdr-queries", type=int, default=2 ** 16)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--seed", type=int, default=0, help="seed of the model's initialisation and training targets")
    ap.add_argument("--short-run-optimiser", action="store_true",
                    help="Adam (0.9, 0.999), lr 1e-2, EMA 0.02 instead of the paper's long-run settings")
    ap.add_argument("--quick", action="store_true", help="smoke run: 1 material, 200 steps, 5 scales, 32 px")
    ap.add_argument("--save", type=Path, default=None, help="also write the fitted models' scores to this JSON file")
    ap.add_argument("--merge", type=Path, nargs="+", default=None,
                    help="fit nothing: report the scores of several --save files (e.g. runs split by --models)")
    add_engine_arguments(ap, "(texture set, model) pair")
    ap.add_argument("--markdown", type=Path, nargs="?", const=RESULTS / "multiscale.md", default=None,
                    help="write the tables to this .md file (default benchmarks/studies/multiscale/results/multiscale.md) and the "
                         "per-scale chart beside it (<stem>_flip.png)")
    args = ap.parse_args()
    if args.quick:
        args.materials = args.materials or [str(DATA / "Wood092_1K")]
        args.steps, args.batch, args.samples, args.ref_samples = 200, 1024, 4, 32
        args.max_size = args.max_size if args.crop else 64
        args.resolution, args.scales, args.hdr_queries = 32, 5, 4096
        args.short_run_optimiser = True
    device = torch.device(args.device)
    command = "python benchmarks/studies/multiscale/multiscale.py " + " ".join(sys.argv[1:])
    RESULTS.mkdir(exist_ok=True)
    if args.merge:
        results = merge_results(args.merge)
        results["commands"].append(command)
    else:
        folders = [Path(m) for m in (args.materials or sorted(p for p in DATA.iterdir() if p.is_dir()))]
        results = fit_and_score(args, folders, device)
        results["commands"] = [command]
        if args.save:
            args.save.write_text(json.dumps(results, indent=1))
    report(results, device, args.markdown)


if __name__ == "__main__":
    main()
