"""How far below the pixel-pair average NeuBRDF's runtime phase aims (issue 32): the phase fits each query's pixel
pair to a K-point mean of the source (`neumat.methods.neubrdf.pixel_pair_targets.PixelPairAverage`) under an L1 loss on
logs (log_cos_eps), whose minimiser is the median of those noisy means, not their mean. Where a sub-pixel peak
makes the K points spread, the median lies below the mean and the fitted pair loses energy; the gap closes as K
grows. Per K: over `--queries` cosine_merl queries, `--draws` K-point means each, the energy lost, 1 -
sum(cos median) / sum(cos mean), overall and on the queries whose pair mean is within the top 1 % (the peak).

    OMP_NUM_THREADS=1 PYTHONPATH=src python benchmarks/studies/neubrdf/neubrdf_pair_target_bias.py merl_tables/steel.binary \
        [--nside 64] [--k 8 16 32] [--queries 4096] [--draws 64]
"""
from __future__ import annotations

import argparse

import torch

from neumat.catalog.open_material import open_material
from neumat.methods.neubrdf.pixel_pair_targets import PixelPairAverage
from neumat.fit.query_samplers import QUERY_SAMPLERS


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("source", help="a material (e.g. a MERL-like table)")
    ap.add_argument("--nside", type=int, default=64)
    ap.add_argument("--k", type=int, nargs="+", default=[8, 16, 32], help="points per K-point mean")
    ap.add_argument("--queries", type=int, default=4096)
    ap.add_argument("--draws", type=int, default=64, help="K-point means per query")
    ap.add_argument("--reference-k", type=int, default=1024, help="points of the pair mean itself")
    a = ap.parse_args()
    torch.set_num_threads(1)
    source = open_material(a.source)
    q = QUERY_SAMPLERS.get("cosine_merl")(source)(a.queries, torch.Generator().manual_seed(0), torch.device("cpu"))
    cos = q.wi[:, 2:3].clamp(min=0)
    with torch.no_grad():
        mean = PixelPairAverage(source, a.nside, a.reference_k, torch.Generator().manual_seed(1)).eval(q) * cos
        peak = mean.sum(-1) >= mean.sum(-1).quantile(0.99)
        print(f"{a.source}, N_side {a.nside}, {a.queries} cosine_merl queries, {a.draws} draws each, pair mean of "
              f"{a.reference_k} points\n")
        print("| K | energy lost (all queries) | energy lost (top 1 % pairs) |\n|---|---|---|")
        for k in a.k:
            targets = PixelPairAverage(source, a.nside, k, torch.Generator().manual_seed(2 + k))
            draws = torch.stack([targets.eval(q) * cos for _ in range(a.draws)])
            median = draws.median(dim=0).values
            lost = 1 - median.sum() / mean.sum()
            lost_peak = 1 - median[peak].sum() / mean[peak].sum()
            print(f"| {k} | {lost:.4f} | {lost_peak:.4f} |", flush=True)


if __name__ == "__main__":
    main()
