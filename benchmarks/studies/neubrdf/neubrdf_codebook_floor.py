"""What the paper's codebook costs a fitted dense NeuBRDF before any VQ step (issue 32): quantise its N_side 64 grid
into 2^b codewords (`NeuBRDF.quantize_from_dense`, plain k-means, and with --weights sensitivity the k-means weighted
by the CPU recipe's loss sensitivity, `neumat.methods.neubrdf.feature_sensitivity`) and score each codebook model, in the
training form and shipped (runtime, 1/4 weights), against the dense grid: held-out log error and relative error
(2^16 cosine queries, seed 7) and the Table 3 image protocol (`neumat.render.comparison`: sphere under the sky,
128^2, 512 spp; floor = the reference at the next seed). The former option --vq-steps (blocks of VQ steps from the
plain k-means start, trained by neubrdf_codebook_gap.py's own loop) was removed with that script; the version that
ran results/neubrdf_table3_codebook.md section 4 is at commit 906d5d7 (then in benchmarks/):
`git show 906d5d7:benchmarks/neubrdf_codebook_floor.py`, beside `git show 906d5d7:benchmarks/neubrdf_codebook_gap.py`.

    neumat fit SOURCE --model neubrdf --recipe cpu --set features=dense --set dense_warmup=0 --set vq_candidates=0 \\
        -o dense.nmat
    OMP_NUM_THREADS=1 PYTHONPATH=src python benchmarks/studies/neubrdf/neubrdf_codebook_floor.py dense.nmat SOURCE \\
        [--bits 9 10 12] [--weights uniform sensitivity]
"""
from __future__ import annotations

import argparse
import copy
import time
from dataclasses import replace

import torch

from neumat.catalog.modelfile import load_model
from neumat.catalog.open_material import open_material
from neumat.methods.neubrdf.feature_sensitivity import feature_sensitivity
from neumat.fit.phase import FitContext
from neumat.fit.method import recipe_for
from neumat.metrics.hdr import reflectance_errors
from neumat.methods.neubrdf.model import NeuBRDF
from neumat.render.comparison import image_comparison, reference_renders


def training_model(shipped: NeuBRDF) -> NeuBRDF:
    """The dense model of a shipped .nmat in its training form (inverse-distance weights, float32), eval mode."""
    if shipped.cfg.features != "dense":
        raise SystemExit(f"expected a dense NeuBRDF, got features={shipped.cfg.features!r}")
    model = NeuBRDF(config=replace(shipped.cfg, interpolation="idw"))
    state = {k: v.float() for k, v in shipped.state_dict().items() if k.startswith(("mlp.", "grid."))}
    model.load_state_dict(state, strict=False)
    return model.train(False)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("model", help="a fitted dense NeuBRDF (.nmat)")
    ap.add_argument("source", help="the material it was fitted to")
    ap.add_argument("--bits", type=int, nargs="+", default=[9, 10, 12])
    ap.add_argument("--weights", nargs="+", default=["uniform"], choices=["uniform", "sensitivity"])
    ap.add_argument("--resolution", type=int, default=128)
    ap.add_argument("--spp", type=int, default=512)
    a = ap.parse_args()
    torch.set_num_threads(1)
    source = open_material(a.source)
    model = training_model(load_model(a.model))
    renders = reference_renders(source, a.spp, a.resolution)
    print("| model | form | log_err | rel_err | image MAE | SSIM | floor SSIM | bytes | k-means s |\n"
          "|---|---|---|---|---|---|---|---|---|")

    def row(label: str, m: NeuBRDF, seconds: str = "") -> None:
        for form, scored in (("training", m), ("shipped", copy.deepcopy(m).runtime())):
            err = reflectance_errors(scored, source, n=2 ** 16, seed=7)
            img = image_comparison(scored, source, a.spp, a.resolution, renders=renders)
            print(f"| {label} | {form} | {err['log_err']:.5f} | {err['rel_err']:.4f} | {img['mae']:.4f} | "
                  f"{img['ssim']:.4f} | {img['floor_ssim']:.4f} | {scored.size_bytes():,} | {seconds} |", flush=True)

    row("dense", model)
    weights = {"uniform": None}
    if "sensitivity" in a.weights:
        recipe = recipe_for("neubrdf", "cpu")
        ctx = FitContext(model=model, source=source, recipe=recipe, device=torch.device("cpu"),
                         generator=torch.Generator().manual_seed(recipe.seed))
        weights["sensitivity"] = feature_sensitivity(ctx, ctx.opts.sensitivity_batches, recipe.seed + 2)
    for b in a.bits:
        for name in a.weights:
            t0 = time.perf_counter()
            vq = copy.deepcopy(model).quantize_from_dense(index_bits=b, weights=weights[name])
            row(f"{2 ** b} codewords, {name} k-means", vq.train(False), f"{time.perf_counter() - t0:.0f}")


if __name__ == "__main__":
    main()
