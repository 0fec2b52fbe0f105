"""Real-Time Neural Appearance Models (Zeltner et al. 2024, Sec. 8.1) on our data: rendered-image metrics of
neural-appearance and the analytic ggx-mipmap baseline against the filtered reference, at several distances.

    python benchmarks/studies/neural_appearance/neural_appearance_images.py                     # 3 texture sets + 2 layered sources
    python benchmarks/studies/neural_appearance/neural_appearance_images.py --sources Wood092_1K --steps 400 --batch 512   # a smoke run

Sources: plain texture sets (`--sets`, read at --size texels) and layered ones (`--layered`): "coated:SET" puts
SET under a flat tinted clear coat (eta 1.5, GGX alpha 0.05, tint 0.92/0.85/0.7), "smudged:SET" under a coat
whose GGX alpha follows a procedural smudge mask (0.03 to 0.3), as `benchmarks/studies/neural_appearance/neural_appearance.py --coat`.
Each model is fitted with its recipe at --steps x --batch (targets filtered with 16 footprint samples):
neural-appearance (encoder phase, bake, latent phase; the paper's system), ggx-mipmap (diffuse + anisotropic GGX,
12 filtered texture parameters per texel; the textured analytic fit the paper's Fig. 3 compares with);
"no-encoder" is neural-appearance with its latents optimised directly from random values for all the steps
(phase_split (0, 1); the paper's Fig. 8 / 10 ablation).

Images: the plane scene (one sample through each pixel centre, the material filters by the pixel footprint), a
directional light per image (2 lights), a camera tilted 35 degrees, at --scales texture scales from ~1/4 texel
per pixel (near) to ~16 texels per pixel (far); --resolution pixels square. The reference is the source with
--ref-samples footprint samples; "noise floor" is the same reference rendered with another seed against the
first (its Monte Carlo footprint filtering is noisy; a model cannot be measured below it). Metrics: PSNR (dB,
clipped [0, 1] sRGB) and FLIP (LDR, `neumat.metrics.image.image_metrics`), averaged over the lights, per scale.
Bytes: the model at fp16 (`size_bytes("fp16")`); the reference's surface parameters at fp16
(sampling_feature_dim x texels x 2). Evaluations per second: eval with a footprint on 2^15 queries, one thread,
best of three (the reference with 16 footprint samples, as the training targets).
"""
from __future__ import annotations

import argparse
import math
import platform
import subprocess
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from .neural_appearance import rate

from neumat.fit.footprint_queries import footprint_queries
from neumat.fit.method import recipe_for
from neumat.methods.neural_appearance.train import config_for_source
from neumat.fit.trainer import fit
from neumat.io.shared_data import shared_data_dir
from neumat.metrics.image import image_metrics
from neumat.methods.latent_mlp.ggx_mipmap import GGXMipmap
from neumat.methods.neural_appearance.model import NeuralAppearance
from neumat.reflectance.layered import Coat, LayeredMaterial
from neumat.reflectance.smudge_map import smudge_map
from neumat.reflectance.svbrdf import SVBRDF
from neumat.render.render import render

LIGHTS = ["dir:0.3/1/0.2", "dir:-0.8/0.6/0.3"]
TILT, DISTANCE, FOV = 35.0, 3.0, 40.0


def open_source(spec: str, data: Path, size: int, samples: int, seed: int = 0):
    """'SET', 'coated:SET' or 'smudged:SET' (module docstring) with `samples` footprint samples."""
    kind, _, name = spec.rpartition(":")
    svbrdf = SVBRDF.from_folder(data / "svbrdf" / name, max_size=size, samples=samples, seed=seed)
    if not kind:
        return svbrdf
    if kind == "coated":
        coat = Coat(roughness=0.05, eta=1.5, tint=(0.92, 0.85, 0.7))
    elif kind == "smudged":
        coat = Coat(roughness=0.03 + 0.27 * smudge_map(min(svbrdf.textures.size), seed=1), eta=1.5)
    else:
        raise SystemExit(f"source {spec!r}: expected SET, coated:SET or smudged:SET")
    return LayeredMaterial(svbrdf, [coat], samples=samples, seed=seed, name=spec)


def texels(source) -> int:
    return max(source.texture_size if isinstance(source, LayeredMaterial) else source.textures.size)


def scales(n: int, resolution: int, size: int) -> list[float]:
    """uv_scale values from ~1/4 texel to ~16 texels per pixel at the image centre."""
    visible = 2 * DISTANCE * math.tan(math.radians(FOV) / 2)
    return list(np.geomspace(resolution / (4 * visible * size), 16 * resolution / (visible * size), n))


def images(material, uv_scales, resolution: int, seed: int = 0) -> list[torch.Tensor]:
    return [render(material, scene="plane", light=light, spp=1, resolution=resolution, strategy="light",
                   jitter=False, seed=seed, tilt=TILT, distance=DISTANCE, fov=FOV, uv_scale=float(s))
            for s in uv_scales for light in LIGHTS]


def per_scale(ref: list, test: list, n_scales: int) -> list[dict]:
    """Mean PSNR and FLIP over the lights, per scale."""
    metrics = [image_metrics(r.numpy(), t.numpy()) for r, t in zip(ref, test)]
    k = len(LIGHTS)
    return [{m: float(np.mean([x[m] for x in metrics[i * k:(i + 1) * k]])) for m in ("psnr", "flip")}
            for i in range(n_scales)]


def start_run() -> tuple[Path, str]:
    """The set-up every neural-appearance benchmark shares: one torch thread, the shared data folder (exit with
    a message when it is missing) and the short commit hash for the results header."""
    torch.set_num_threads(1)
    data = shared_data_dir()
    if data is None:
        raise SystemExit("needs shared/data/svbrdf (set NEUMAT_SHARED_DATA or put shared/ beside the checkout)")
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    return data, commit


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sources", default="Wood092_1K,Metal027_1K,Paper001_1K,coated:Wood092_1K,smudged:Metal027_1K")
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--batch", type=int, default=1024)
    ap.add_argument("--scales", type=int, default=3)
    ap.add_argument("--resolution", type=int, default=96)
    ap.add_argument("--ref-samples", type=int, default=64)
    ap.add_argument("--models", default="neural-appearance,ggx-mipmap")
    args = ap.parse_args()
    data, commit = start_run()
    print(f"# commit {commit}, {platform.node()}, {platform.processor() or platform.machine()}, 1 thread; "
          f"{args.steps} steps x {args.batch}, {args.size}^2, {args.resolution}^2 px, {args.ref_samples} ref samples",
          flush=True)
    rows = []
    for spec in args.sources.split(","):
        train = open_source(spec, data, args.size, 16)
        ref = open_source(spec, data, args.size, args.ref_samples, seed=1)
        ref2 = open_source(spec, data, args.size, args.ref_samples, seed=2)
        size = 1 << (texels(train).bit_length() - 1)
        uv_scales = scales(args.scales, args.resolution, texels(train))
        t = time.perf_counter()
        ref_imgs = images(ref, uv_scales, args.resolution, seed=0)
        floor = per_scale(ref_imgs, images(ref2, uv_scales, args.resolution, seed=0), args.scales)
        queries = footprint_queries(train)(1 << 15, torch.Generator().manual_seed(3), "cpu")
        ref_bytes = train.sampling_feature_dim * texels(train) ** 2 * 2
        rows.append({"source": spec, "model": "reference (noise floor)", "scales": floor, "bytes": ref_bytes,
                     "eval/s": rate(lambda: train.eval(queries), 1 << 15), "fit s": float("nan")})
        print(rows[-1], f"({time.perf_counter() - t:.0f} s)", flush=True)
        for name in args.models.split(","):
            torch.manual_seed(0)
            if name in ("neural-appearance", "no-encoder"):
                model = NeuralAppearance(**config_for_source(train))
            elif name == "ggx-mipmap":
                model = GGXMipmap(spatial_size=size)
            else:
                raise SystemExit(f"--models: unknown {name!r} (neural-appearance, no-encoder, ggx-mipmap)")
            recipe = replace(recipe_for(model.name), batch_size=args.batch)
            if name == "no-encoder":
                recipe = replace(recipe, phase_split=(0.0, 1.0))
            if name == "ggx-mipmap":
                recipe = replace(recipe, lr_decay_every=0, loss="log_cos")
            t = time.perf_counter()
            fit(model, train, recipe, steps=args.steps, progress=False)
            seconds = time.perf_counter() - t
            model.eval()
            rows.append({"source": spec, "model": name,
                         "scales": per_scale(ref_imgs, images(model, uv_scales, args.resolution), args.scales),
                         "bytes": model.size_bytes("fp16"), "eval/s": rate(lambda: model.eval(queries), 1 << 15),
                         "fit s": seconds})
            print(rows[-1], flush=True)
    head = " | ".join(f"PSNR / FLIP scale {i}" for i in range(args.scales))
    print(f"\n| source | model | {head} | bytes (fp16) | eval/s (footprint) | fit s |")
    print("|---|---|" + "---|" * args.scales + "---|---|---|")
    for r in rows:
        cells = " | ".join(f"{s['psnr']:.2f} / {s['flip']:.4f}" for s in r["scales"])
        print(f"| {r['source']} | {r['model']} | {cells} | {r['bytes']} | {r['eval/s']:.3g} | {r['fit s']:.0f} |")


if __name__ == "__main__":
    main()
