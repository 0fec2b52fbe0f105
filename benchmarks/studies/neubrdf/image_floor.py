"""Noise floor of sphere renderings: a material rendered twice (seeds 0 and 1), image metrics between the two,
for each render strategy and sampler (issue 32; benchmarks/studies/neubrdf/results/brdf_image_protocol.md).

    OMP_NUM_THREADS=1 python benchmarks/studies/neubrdf/image_floor.py merl_tables/blue-metallic-paint2.binary --spp 64 1024
"""
from __future__ import annotations

import argparse
import time

import torch

from neumat.catalog.open_material import open_material
from neumat.metrics.image import image_metrics
from neumat.render.render import render

CONFIGS = (("mis", "random"), ("mis-lobes", "random"), ("mis-lobes", "sobol"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("material", help="material file or spec, as `neumat render` takes it")
    ap.add_argument("--spp", type=int, nargs="+", default=[64])
    ap.add_argument("--resolution", type=int, default=128)
    args = ap.parse_args()
    torch.set_num_threads(1)
    m = open_material(args.material)
    print(f"{args.material}, sphere under env:sky, {args.resolution}^2\n")
    print("| strategy | sampler | spp | floor MAE | floor SSIM | floor FLIP | seconds per rendering |")
    print("|---|---|---|---|---|---|---|")
    for spp in args.spp:
        for strategy, sampler in CONFIGS:
            t0 = time.perf_counter()
            a, b = (render(m, spp=spp, resolution=args.resolution, strategy=strategy, sampler=sampler, seed=s)
                    for s in (0, 1))
            sec = (time.perf_counter() - t0) / 2
            f = image_metrics(a, b)
            print(f"| {strategy} | {sampler} | {spp} | {f['mae']:.5f} | {f['ssim']:.4f} | {f['flip']:.4f} | {sec:.1f} |",
                  flush=True)


if __name__ == "__main__":
    main()
