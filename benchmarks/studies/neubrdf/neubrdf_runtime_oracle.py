"""The best any NeuBRDF runtime form could render (issue 32: can chrome reach SSIM 0.99 at N_side 64?).

NeuBRDF's runtime form (1/4 corner weights) reads one feature per HEALPix pixel for wi and one for the mirrored
wo, so whatever its MLP, the shipped model is constant on every pair (pixel of wi, pixel of wo). The best such
function in L2 is the reference averaged over the pixel pair. This script renders that oracle, the average of
the reference over K points per pixel pair (`neumat.methods.neubrdf.pixel_pair_targets.PixelPairAverage`: uniform
sub-pixel centres of the nested hierarchy, 2^8 per pixel, drawn independently for wi and wo), under the Table 3
protocol (`neumat.render.comparison`: sphere under the sky, 128^2, 512 spp, floor = the reference at the next
seed), at several N_side. The same averages are the targets of NeuBRDF's runtime phase (recipe option
runtime_fraction). An oracle below the target
means no runtime-form model at that N_side can reach it, however it is trained.

    OMP_NUM_THREADS=1 PYTHONPATH=src python benchmarks/studies/neubrdf/neubrdf_runtime_oracle.py merl_tables/chrome.binary \
        [--nside 64 128 256] [--samples 16] [--resolution 128] [--spp 512]
"""
from __future__ import annotations

import argparse
import time

import torch

from neumat.catalog.open_material import open_material
from neumat.methods.neubrdf.pixel_pair_targets import PixelPairAverage
from neumat.nn import healpix as hpx
from neumat.render.comparison import image_comparison, reference_renders


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("source")
    ap.add_argument("--nside", type=int, nargs="+", default=[64, 128, 256])
    ap.add_argument("--samples", type=int, default=16, help="points per pixel pair")
    ap.add_argument("--resolution", type=int, default=128)
    ap.add_argument("--spp", type=int, default=512)
    args = ap.parse_args()
    torch.set_num_threads(1)
    ref = open_material(args.source)
    renders = reference_renders(ref, args.spp, args.resolution)
    print(f"{args.source}: {args.resolution}^2, {args.spp} spp, {args.samples} points per pixel pair")
    print("| N_side | pixel (deg) | image MAE | image RMSE | SSIM | FLIP | floor MAE | floor SSIM | s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for n in args.nside:
        t0 = time.perf_counter()
        oracle = PixelPairAverage(ref, n, args.samples, torch.Generator().manual_seed(0))
        m = image_comparison(oracle, ref, args.spp, args.resolution, renders=renders)
        pixel = (4 * torch.pi / hpx.npix(n)) ** 0.5 * 180 / torch.pi
        print(f"| {n} | {pixel:.2f} | {m['mae']:.4f} | {m['rmse']:.4f} | {m['ssim']:.4f} | {m['flip']:.4f} | "
              f"{m['floor_mae']:.5f} | {m['floor_ssim']:.4f} | {time.perf_counter() - t0:.0f} |", flush=True)


if __name__ == "__main__":
    main()
