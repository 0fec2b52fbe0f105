"""What NeuBRDF's runtime phase does to a model already fitted (issue 32): fine-tune a fitted NeuBRDF (.nmat) in
its 1/4-weight runtime form against the source averaged over each query's pixel pair
(`neumat.methods.neubrdf.pixel_pair_targets.PixelPairAverage`), the loop of the recipe's runtime phase (option
runtime_fraction) on its own: cosine_merl queries, batch 8192, the given loss, Adam (the model's row-sparse
optimiser) at --lr halved at 1/2 and 3/4, EMA 0.01. Scores the shipped form (`runtime()`) before, halfway and
after under the Table 3 protocol (`neumat.render.comparison`: sphere under the sky, 128^2, 512 spp, floor = the
reference at the next seed) and the held-out log error (2^16 cosine queries, seed 7).

    OMP_NUM_THREADS=1 PYTHONPATH=src python benchmarks/studies/neubrdf/neubrdf_runtime_finetune.py MODEL.nmat SOURCE \
        [--steps 1000] [--samples 8] [--lr 2.5e-3] [--loss log_cos_eps] [-o TUNED.nmat]
"""
from __future__ import annotations

import argparse
import copy
import time
from dataclasses import replace

import torch

from neumat.catalog.modelfile import load_model, save_model
from neumat.catalog.open_material import open_material
from neumat.fit.ema import EMA
from neumat.fit.losses import LOSSES
from neumat.methods.neubrdf.pixel_pair_targets import PixelPairAverage
from neumat.fit.query_samplers import QUERY_SAMPLERS
from neumat.metrics.hdr import reflectance_errors
from neumat.render.comparison import image_comparison, reference_renders

BATCH = 8192


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("model", help="a fitted NeuBRDF .nmat")
    ap.add_argument("source", help="the material it was fitted to")
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--samples", type=int, default=8, help="points per pixel pair of the targets")
    ap.add_argument("--lr", type=float, default=2.5e-3)
    ap.add_argument("--loss", default="log_cos_eps")
    ap.add_argument("--resolution", type=int, default=128)
    ap.add_argument("--spp", type=int, default=512)
    ap.add_argument("-o", "--out", help="save the fine-tuned model's shipped form here (.nmat)")
    a = ap.parse_args()
    torch.set_num_threads(1)
    source = open_material(a.source)
    renders = reference_renders(source, a.spp, a.resolution)
    model = load_model(a.model)
    print("| steps | log_err | image MAE | image RMSE | SSIM | FLIP | floor SSIM |\n|---|---|---|---|---|---|---|")

    def show(step: int, shadow) -> None:
        shipped = copy.deepcopy(shadow).runtime()
        err = reflectance_errors(shipped, source, n=2 ** 16, seed=7)
        img = image_comparison(shipped, source, a.spp, a.resolution, renders=renders)
        print(f"| {step} | {err['log_err']:.5f} | {img['mae']:.4f} | {img['rmse']:.4f} | {img['ssim']:.4f} | "
              f"{img['flip']:.4f} | {img['floor_ssim']:.4f} |", flush=True)

    model.train()
    model.requires_grad_(True)
    model.cfg = replace(model.cfg, interpolation="uniform", runtime_interpolation="uniform")
    show(0, model)
    targets = PixelPairAverage(source, model.cfg.nside, a.samples, torch.Generator().manual_seed(1))
    loss_fn = LOSSES.get(a.loss)()
    draw = QUERY_SAMPLERS.get("cosine_merl")(source, model)
    gen = torch.Generator().manual_seed(0)
    opt, ema = model.optimizer(a.lr), EMA(model, 0.01)
    model.train()
    t0 = time.perf_counter()
    for i in range(a.steps):
        rate = a.lr * 0.5 ** ((i >= a.steps // 2) + (i >= 3 * a.steps // 4))
        for group in opt.param_groups:
            group["lr"] = rate * group.get("lr_scale", 1.0)
        q = draw(BATCH, gen, torch.device("cpu"))
        with torch.no_grad():
            y = targets.eval(q)
        loss = loss_fn(model.eval(q), y, q)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        ema.update(model)
        if i + 1 == a.steps // 2:
            show(i + 1, ema.shadow)
    print(f"{a.steps} steps in {time.perf_counter() - t0:.0f} s", flush=True)
    show(a.steps, ema.shadow)
    if a.out:
        save_model(copy.deepcopy(ema.shadow).runtime(), a.out, source=a.source,
                   metrics={"finetune_steps": a.steps, "finetune_samples": a.samples})
        print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
