"""NeuBRDF on a sharp specular table (issue 32: MERL chrome, steel): fits of a dense grid with several training
query distributions, losses and feature starts, scored by held-out errors and images (comparison protocol, with
the reference's floor), and the fitted model against the table along the mirror direction, where the peak is.

    OMP_NUM_THREADS=1 PYTHONPATH=src python benchmarks/studies/neubrdf/neubrdf_sharp_peak.py merl_tables/chrome.binary \
        [--nside 16] [--steps 800] [--queries cosine rusinkiewicz merl cosine_merl] [--loss log_cos log_cos_eps] \
        [--starts random directions] [--direction-scale 1]

Queries (`neumat.fit.query_samplers`): "cosine" (the recipe's), "rusinkiewicz" (theta_h uniform: 1.1 % of the
queries within 1 degree of the peak), "merl" (theta_h = pi/2 u^2, the density of the MERL table's cells: 10.5 %
within 1 degree), "cosine_merl" (half and half). Starts: "random" features, or "directions"
(`NeuBRDF.init_direction_features(--direction-scale)`). Every combination is run. Batch 8192, lr 1e-2 halved
every steps / 4, EMA 0.01; images 64^2 at 256 spp.
"""
from __future__ import annotations

import argparse
import itertools
import math
import time
from dataclasses import replace

import torch

from neumat.catalog.open_material import open_material
from neumat.core.query import Query
from neumat.fit.method import recipe_for
from neumat.fit.trainer import fit
from neumat.metrics.hdr import reflectance_errors
from neumat.methods.neubrdf.model import NeuBRDF
from neumat.render.comparison import image_comparison, reference_renders

OFFSETS = (0.0, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0)  # degrees from the mirror direction, in the plane of incidence


def mirror_profile(material, theta_i_deg: float) -> list[float]:
    """Green channel of `material` at wi (theta_i, 0) and wo at OFFSETS degrees past the mirror direction."""
    ti = math.radians(theta_i_deg)
    to = ti + torch.deg2rad(torch.tensor(OFFSETS, dtype=torch.float64))
    wi = torch.tensor([[math.sin(ti), 0.0, math.cos(ti)]], dtype=torch.float64).repeat(len(OFFSETS), 1)
    wo = torch.stack([-torch.sin(to), torch.zeros_like(to), torch.cos(to)], -1)
    with torch.no_grad():
        return material.eval(Query(wi, wo))[:, 1].tolist()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("material")
    ap.add_argument("--nside", type=int, default=16)
    ap.add_argument("--steps", type=int, default=800)
    ap.add_argument("--queries", nargs="+", default=["cosine", "rusinkiewicz", "merl"])
    ap.add_argument("--loss", nargs="+", default=["log_cos"])
    ap.add_argument("--starts", nargs="+", default=["random"], choices=["random", "directions"])
    ap.add_argument("--direction-scale", type=float, default=1.0)
    a = ap.parse_args()
    torch.set_num_threads(1)
    source = open_material(a.material)
    renders = reference_renders(source, 256, 64)
    for t in (10, 30, 60):
        print(f"table at theta_i {t}, offsets " + ", ".join(f"{o:g}" for o in OFFSETS) + " degrees: "
              + ", ".join(f"{v:.3g}" for v in mirror_profile(source, t)))
    print("| queries | loss | start | N_side | steps | fit s | log_err | rel_err | image MAE | SSIM | FLIP | "
          "floor SSIM | model at the mirror direction, theta_i 10 / 30 / 60 |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name, loss, start in itertools.product(a.queries, a.loss, a.starts):
        r = recipe_for("neubrdf")
        recipe = replace(r, steps=a.steps, batch_size=8192, lr_decay_every=max(a.steps // 4, 1), log_every=a.steps,
                         loss=loss, queries=name)
        torch.manual_seed(0)
        model = NeuBRDF(nside=a.nside, features="dense")
        if start == "directions":
            model.init_direction_features(a.direction_scale)
        t0 = time.perf_counter()
        res = fit(model, source, recipe, progress=False)
        seconds = time.perf_counter() - t0
        err = reflectance_errors(res.model, source, n=2 ** 17)
        img = image_comparison(res.model, source, 256, 64, renders=renders)
        profile = " / ".join(f"{mirror_profile(res.model, t)[0]:.3g}" for t in (10, 30, 60))
        print(f"| {name} | {loss} | {start} | {a.nside} | {a.steps} | {seconds:.0f} | {err['log_err']:.5f} | "
              f"{err['rel_err']:.3f} | {img['mae']:.4f} | {img['ssim']:.4f} | {img['flip']:.4f} | "
              f"{img['floor_ssim']:.4f} | {profile} |", flush=True)


if __name__ == "__main__":
    main()
