"""NeuBRDF's CPU recipe and its variants on one material (issue 32): the paper's model through `CPU_RECIPE` (coarse
to fine, dense warm-up, VQ with 8 candidates), and the same steps with the training changes for sharp specular
materials (queries "cosine_merl", loss "log_cos_eps", option direction_features), ending with the codebook or
with the dense grid. Scored in the training form: held-out log / relative error (2^17 cosine queries, seed 7),
the MERL-table MSE (Table 4's metric) and images (64^2, 256 spp, comparison protocol, with the reference's floor).

    OMP_NUM_THREADS=1 PYTHONPATH=src python benchmarks/studies/neubrdf/neubrdf_recipe_variants.py merl_tables/chrome.binary \
        [--variants base qloss new newdense] [--seed 0] [--direction-scale 10] [--quantize]

Variants: "base" = CPU_RECIPE; "qloss" = base with queries cosine_merl and loss log_cos_eps; "new" = qloss with
direction_features = --direction-scale; "newdense" = new without the warm-up's switch to the codebook
(dense_warmup 0: coarse N_side 16, then dense N_side 64 to the end, 1.6 MB). --quantize: for dense variants also
the score right after k-means into the codebook (`quantize_from_dense`, 8 candidates), before any VQ step.
"""
from __future__ import annotations

import argparse
import copy
import time
from dataclasses import replace

import torch

from neumat.catalog.open_material import open_material
from neumat.methods.neubrdf.train import CPU_RECIPE
from neumat.fit.trainer import fit
from neumat.metrics.hdr import reflectance_errors
from neumat.methods.neubrdf.model import NeuBRDF
from neumat.reflectance.tabulate import merl_table_mse, tabulate_merl
from neumat.render.comparison import image_comparison, reference_renders

VARIANTS = ("base", "qloss", "new", "newdense")


def variant_recipe(variant: str, seed: int, direction_scale: float):
    recipe = replace(CPU_RECIPE, seed=seed, options=dict(CPU_RECIPE.options))
    if variant != "base":
        recipe = replace(recipe, queries="cosine_merl", loss="log_cos_eps")
    if variant in ("new", "newdense"):
        recipe.options["direction_features"] = direction_scale
    if variant == "newdense":
        recipe.options.update(dense_warmup=0.0, vq_candidates=0)
    return recipe


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("material")
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=VARIANTS)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--direction-scale", type=float, default=10.0)
    ap.add_argument("--quantize", action="store_true")
    a = ap.parse_args()
    torch.set_num_threads(1)
    source = open_material(a.material)
    renders = reference_renders(source, 256, 64)
    table = tabulate_merl(source)

    def row(label: str, model: NeuBRDF, seconds: str) -> None:
        model.train(False)
        err = reflectance_errors(model, source, n=2 ** 17, seed=7)
        img = image_comparison(model, source, 256, 64, renders=renders)
        print(f"| {label} | {model.cfg.features} | {seconds} | {err['log_err']:.5f} | {err['rel_err']:.3f} | "
              f"{merl_table_mse(model, table):.4g} | {img['mae']:.4f} | {img['ssim']:.4f} | {img['flip']:.4f} | "
              f"{img['floor_ssim']:.4f} |", flush=True)

    print("| variant | features | fit s | log_err | rel_err | MERL-table MSE | image MAE | SSIM | FLIP | floor SSIM |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for variant in a.variants:
        torch.manual_seed(a.seed)
        t0 = time.perf_counter()
        recipe = variant_recipe(variant, a.seed, a.direction_scale)
        model = fit(NeuBRDF(features="dense"), source, recipe, progress=False).model
        row(f"{variant}, seed {a.seed}", model, f"{time.perf_counter() - t0:.0f}")
        if a.quantize and model.cfg.features == "dense":
            row(f"{variant}, k-means into the codebook", copy.deepcopy(model).quantize_from_dense(candidates=8), "")


if __name__ == "__main__":
    main()
