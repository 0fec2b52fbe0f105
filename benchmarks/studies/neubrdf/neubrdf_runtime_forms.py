"""A fitted NeuBRDF in its two runtime forms (issue 32): the paper's 1/4 corner weights (one feature per pixel) and
the inverse-distance weights it was trained with (`Config.runtime_interpolation="idw"`), side by side in one run:
reflectance errors, Table 3 image metrics (`neumat.render.comparison`: sphere under the sky, floor = the reference
at the next seed) and evaluations per second (one thread, batches of 2^16 cosine-weighted queries).

    OMP_NUM_THREADS=1 PYTHONPATH=src python benchmarks/studies/neubrdf/neubrdf_runtime_forms.py OUT/chrome.neubrdf.nmat \
        merl_tables/chrome.binary [--resolution 128] [--spp 512]
"""
from __future__ import annotations

import argparse
import time
from dataclasses import replace

import torch

from neumat.catalog.modelfile import load_model
from neumat.catalog.open_material import open_material
from neumat.core.query import Query
from neumat.metrics.hdr import reflectance_errors
from neumat.render.comparison import image_comparison, reference_renders
from neumat.warp.hemisphere import sample_cosine_hemisphere


def evals_per_second(model, n: int = 2 ** 16, repeats: int = 5) -> float:
    g = torch.Generator().manual_seed(3)
    q = Query(sample_cosine_hemisphere(torch.rand(n, 2, generator=g)),
              sample_cosine_hemisphere(torch.rand(n, 2, generator=g)))
    with torch.no_grad():
        model.eval(q)
        best = float("inf")
        for _ in range(repeats):
            t0 = time.perf_counter()
            model.eval(q)
            best = min(best, time.perf_counter() - t0)
    return n / best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("model")
    ap.add_argument("source")
    ap.add_argument("--resolution", type=int, default=128)
    ap.add_argument("--spp", type=int, default=512)
    args = ap.parse_args()
    torch.set_num_threads(1)
    src = open_material(args.source)
    renders = reference_renders(src, args.spp, args.resolution)
    print(f"{args.model} against {args.source}: {args.resolution}^2, {args.spp} spp")
    print("| runtime weights | log_err | image MAE | image RMSE | SSIM | FLIP | floor SSIM | evals/s |")
    print("|---|---|---|---|---|---|---|---|")
    for weights in ("uniform", "idw"):
        m = load_model(args.model)
        m.cfg = replace(m.cfg, runtime_interpolation=weights)
        m.runtime()
        e = reflectance_errors(m, src, n=2 ** 16, seed=7)
        i = image_comparison(m, src, args.spp, args.resolution, renders=renders)
        print(f"| {weights} | {e['log_err']:.5f} | {i['mae']:.4f} | {i['rmse']:.4f} | {i['ssim']:.4f} | "
              f"{i['flip']:.4f} | {i['floor_ssim']:.4f} | {evals_per_second(m):.3g} |", flush=True)


if __name__ == "__main__":
    main()
