"""Is a Table 3 image error the model's or the renderer's noise? (issue 32) Fitted models against their reference
under the comparison protocol (`neumat.render.comparison`: sphere under the sky, the same directions for model and
reference) at several sample counts and seeds, beside the floor (the reference against itself at seed + 1).

Model and reference share their directions, so the noise of their difference scales with how different the two
BRDFs are, not with the floor, which compares two independent renderings. A model error below the floor is then
possible; it is the model's own if it holds at another seed and falls no further at 4x the samples (noise in
the difference only adds to the mean absolute error, so the converged error is at most the measured one).

    OMP_NUM_THREADS=1 PYTHONPATH=src python benchmarks/studies/neubrdf/image_error_convergence.py merl_tables/gold-paint.binary \
        OUT/gold-paint.neubrdf.nmat OUT/gold-paint.nbrdf.nmat [--runs 512:0 512:1 2048:0] [--resolution 128]
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch

from neumat.catalog.modelfile import load_model
from neumat.catalog.open_material import open_material
from neumat.render.comparison import image_comparison, reference_renders


def parse_run(text: str) -> tuple[int, int]:
    """'SPP:SEED' -> (spp, seed)."""
    try:
        spp, seed = (int(x) for x in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected SPP:SEED, e.g. 512:0, got {text!r}") from None
    if spp < 1 or seed < 0:
        raise argparse.ArgumentTypeError(f"SPP must be >= 1 and SEED >= 0, got {text!r}")
    return spp, seed


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("source", help="the reference material")
    ap.add_argument("models", nargs="+", help="fitted models (.nmat) of that material")
    ap.add_argument("--runs", type=parse_run, nargs="+", default=[(512, 0), (512, 1), (2048, 0)],
                    help="SPP:SEED of each comparison")
    ap.add_argument("--resolution", type=int, default=128)
    a = ap.parse_args()
    torch.set_num_threads(1)
    source = open_material(a.source)
    models = {Path(p).name: load_model(p) for p in a.models}
    print(f"{a.source}, sphere under the sky, {a.resolution}^2\n")
    print("| spp | seed | model | image MAE | image RMSE | SSIM | floor MAE | floor SSIM | s per render |\n"
          "|---|---|---|---|---|---|---|---|---|")
    for spp, seed in a.runs:
        t0 = time.perf_counter()
        renders = reference_renders(source, spp, a.resolution, seed)
        per_render = (time.perf_counter() - t0) / 2
        for name, model in models.items():
            m = image_comparison(model, source, spp, a.resolution, seed, renders=renders)
            print(f"| {spp} | {seed} | {name} | {m['mae']:.5f} | {m['rmse']:.5f} | {m['ssim']:.4f} | "
                  f"{m['floor_mae']:.5f} | {m['floor_ssim']:.4f} | {per_render:.0f} |", flush=True)


if __name__ == "__main__":
    main()
