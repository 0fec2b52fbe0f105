"""Measurements behind the deviations from Real-Time Neural Appearance Models (Zeltner et al. 2024) listed in
docs/neural_appearance.md: controlled short fits on a 64^2 texture set, one switch at a time.

    python benchmarks/studies/neural_appearance/neural_appearance_deviations.py                    # Wood092 and Metal027 at 64^2
    python benchmarks/studies/neural_appearance/neural_appearance_deviations.py --sets Wood092_1K --steps 300 --batch 256

Variants of neural-appearance (`neumat.methods.neural_appearance.model`, its recipe at --steps x --batch, 16-sample
targets, seed 0 for all):
  "ours"             as shipped: directions in each learned frame lifted to the hemisphere, frame weights x 0.1,
                     loss |log(1 + f_hat cos_i) - log(1 + f cos_i)| ("log_cos");
  "no lift"          directions in the learned frames fed as they are (T w, the paper's Eq. 7 and nothing more;
                     `neumat.nn.shading_frames.lift_to_hemisphere` replaced by the identity for this fit);
  "frame scale 1"    frame decoder weights at full scale (`frame_weight_scale=1`, the paper's plain linear layer);
  "log L1, no cos"   loss |log(1 + f_hat) - log(1 + f)|, the paper's "L1 loss in log space" (Zheng et al. 2021)
                     without our cosine weight.
Scores: `benchmarks/studies/neural_appearance/neural_appearance.py`'s held-out point log_cos, point relative L1 and filtered log_cos.

Also (--noise): the relative error of 16-sample footprint-filtered targets against 1024-sample ones, per mip
level (isotropic footprints, `Query.lod`), on 8192 random point queries: what a fixed sample count costs at each
level, against the paper's count proportional to the filter area.
"""
from __future__ import annotations

import argparse
import time
from dataclasses import replace

import torch
from torch import nn

from .neural_appearance import held_out, scores

import neumat.nn.shading_frames as shading_frames
from neumat.core.query import Query
from neumat.fit.losses import LOSSES
from neumat.fit.method import recipe_for
from neumat.methods.neural_appearance.train import config_for_source
from neumat.fit.trainer import fit
from neumat.io.shared_data import shared_data_dir
from neumat.methods.neural_appearance.model import NeuralAppearance
from neumat.reflectance.svbrdf import SVBRDF
from neumat.warp.hemisphere import sample_cosine_hemisphere


@LOSSES.register("log_l1_no_cos")
class LogL1Loss(nn.Module):
    """mean |log(1 + f_hat) - log(1 + f)|: L1 in log space without the cosine weight."""

    def forward(self, pred: torch.Tensor, target: torch.Tensor, q: Query) -> torch.Tensor:
        return (torch.log1p(pred.clamp(min=0)) - torch.log1p(target)).abs().mean()


def noise_rows(name: str, source: SVBRDF, n: int = 8192) -> list[dict]:
    g = torch.Generator().manual_seed(11)
    u = torch.rand(n, 6, generator=g)
    rows = []
    for level in range(0, 7):
        q = Query(sample_cosine_hemisphere(u[:, :2]), sample_cosine_hemisphere(u[:, 2:4]), uv=u[:, 4:6],
                  lod=torch.full((n,), float(level)))
        source.samples = 1024
        ref = source.eval(q)
        source.samples = 16
        est = source.eval(q)
        rows.append({"set": name, "level": level, "rel L1 of 16-sample targets": float((est - ref).abs().sum() /
                                                                                       ref.abs().sum())})
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sets", default="Wood092_1K,Metal027_1K")
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--steps", type=int, default=600)
    ap.add_argument("--batch", type=int, default=512)
    ap.add_argument("--variants", default="ours,no lift,frame scale 1,log L1, no cos".replace("1, no", "1; no"),
                    help="comma-separated (write 'log L1; no cos' for the loss variant)")
    ap.add_argument("--noise", action="store_true", help="only the footprint-sample noise per level")
    args = ap.parse_args()
    torch.set_num_threads(1)
    data = shared_data_dir()
    if data is None:
        raise SystemExit("needs shared/data/svbrdf")
    for name in args.sets.split(","):
        folder = data / "svbrdf" / name
        if args.noise:
            for r in noise_rows(name, SVBRDF.from_folder(folder, max_size=args.size, samples=16)):
                print(r, flush=True)
            continue
        train = SVBRDF.from_folder(folder, max_size=args.size, samples=16)
        heldout = held_out(SVBRDF.from_folder(folder, max_size=args.size, samples=256), 4096)
        lift = shading_frames.lift_to_hemisphere
        for variant in (v.replace(";", ",") for v in args.variants.split(",")):
            torch.manual_seed(0)
            config = {**config_for_source(train), **({"frame_weight_scale": 1.0} if variant == "frame scale 1" else {})}
            model = NeuralAppearance(**config)
            recipe = replace(recipe_for("neural-appearance"), batch_size=args.batch)
            if variant == "log L1, no cos":
                recipe = replace(recipe, loss="log_l1_no_cos")
            shading_frames.lift_to_hemisphere = (lambda w: w) if variant == "no lift" else lift
            try:
                t = time.perf_counter()
                fit(model, train, recipe, steps=args.steps, progress=False)
                row = {"set": name, "variant": variant, **scores(model, heldout), "fit s": time.perf_counter() - t}
            finally:
                shading_frames.lift_to_hemisphere = lift
            print(row, flush=True)


if __name__ == "__main__":
    main()
