"""neural-appearance: Real-Time Neural Appearance Models (Zeltner et al. 2024) against the neumip-frame and
ggx-mipmap baselines on the shared texture sets, through `neumat fit-many` at the default presets (its image table)."""
from __future__ import annotations

from .. import harness
from .common import default_budget, paper_budget, quality_rows, summary_rows, texture_set_fits

NAME = "neural-appearance"
DESCRIPTION = "neural-appearance against neumip-frame and ggx-mipmap on the texture sets, through fit-many"
MODELS = ["neural-appearance", "neumip-frame", "ggx-mipmap"]
#: its fits are independent jobs: --workers / --shard share them out
SHARDS = True
BUDGET = {
    "quick": {"ours": "neural-appearance, 10 steps x 256 on Wood092_1K at 32^2 texels with 8-sample footprint "
                       "targets, one seed; sampler variance at 4 points x 64 samples",
              "paper": paper_budget(MODELS[:1]) + " on a GPU", "expected_wall": "about 5 s"},
    "full": {"ours": f"default presets on a CPU: {default_budget(MODELS)}; "
                     "6 texture sets at 256^2 texels x 3 models, seeds 0 "
                     "and 1 (36 fits); sphere images 128^2 at 64 spp; sampler variance of each neural-appearance fit at 64 "
                     "texture points x 1024 samples x 3 elevations",
             "paper": paper_budget(MODELS[:1]) + " on a GPU (the paper's own layered materials, not available)",
             "expected_wall": "about 3 h one job after another (one thread; measured in sessions 66-67 at "
                              "--workers 2: 28 of the 36 jobs in 40 min with each set's reference renderings "
                              "(about 6 min, once per run) already made; fits of a 256^2 set: neural-appearance "
                              "about 3 min, neumip-frame 1.2-2 min at 4000 steps, twice that at its 8000-step "
                              "default, ggx-mipmap 1-1.4 min; the first fit of a sitting up to 7 min); "
                              "--workers 2: about half"},
}


def sampler_variance(model, points: int, samples: int, thetas_deg=(0.0, 30.0, 60.0), seed: int = 0) -> dict:
    """Sec. 6.3 / Fig. 11 on a fitted model: the one-sample estimate f cos / p of its directional albedo (luminance)
    with its own sampler and with cosine sampling, at `points` uniform texture points x `samples` samples per
    elevation; "rel var" = Var / mean^2 per point, averaged; "gain" = cosine's / the sampler's; "z" the largest
    |mean difference| / standard error over the elevations (the sampler is unbiased: within a few)."""
    import math

    import torch

    from neumat.core.query import Query
    from neumat.warp.hemisphere import sample_cosine_hemisphere

    g = torch.Generator().manual_seed(seed)
    lum = torch.tensor([0.2126, 0.7152, 0.0722])
    uv = torch.rand(points, 2, generator=g).repeat_interleave(samples, 0)
    out = {"rel var sampler": [], "rel var cosine": [], "z": []}
    with torch.no_grad():
        for theta in map(math.radians, thetas_deg):
            wi = torch.tensor([math.sin(theta) * math.cos(0.5), math.sin(theta) * math.sin(0.5), math.cos(theta)])
            q = Query(wi.expand(len(uv), 3).contiguous(), uv=uv)
            u = torch.rand(len(uv), 2, generator=g)
            mine = (model.sample(q, u).weight @ lum).reshape(points, samples)
            wo = sample_cosine_hemisphere(torch.rand(len(uv), 2, generator=g))
            cos = (model.eval(q.with_wo(wo)) * math.pi @ lum).reshape(points, samples)
            keep = (mine.abs().sum(1) > 0) & (cos.abs().sum(1) > 0)
            for name, x in (("sampler", mine[keep]), ("cosine", cos[keep])):
                out[f"rel var {name}"].append(float((x.var(1) / x.mean(1).pow(2).clamp(min=1e-12)).mean()))
            se = (mine.var() / mine.numel() + cos.var() / cos.numel()).sqrt()
            out["z"].append(float((mine.mean() - cos.mean()).abs() / se.clamp(min=1e-12)))
    rv_s, rv_c = (sum(out[k]) / len(out[k]) for k in ("rel var sampler", "rel var cosine"))
    return {"rel var sampler": rv_s, "rel var cosine": rv_c, "gain": rv_c / rv_s if rv_s > 0 else None,
            "max z": max(out["z"])}


def run(run: harness.Run) -> None:
    """Fit, measure each neural-appearance fit's sampler against cosine sampling, and tabulate."""
    from neumat.render.comparison import PROTOCOL

    run.protocol["image"] = PROTOCOL
    points, samples = (4, 64) if run.quick else (64, 1024)
    run.protocol["sampler_variance"] = (f"one-sample albedo estimates (luminance) at {points} texture points x "
                                        f"{samples} samples x elevations 0, 30, 60 degrees")

    def after(row: dict) -> dict:
        if row["model"] != "neural-appearance":
            return {}
        from neumat.catalog.modelfile import load_model

        return {"sampler": sampler_variance(load_model(row["nmat"]), points, samples, seed=run.seed)}

    fits = texture_set_fits(run, MODELS, MODELS[:1], after=after)
    if fits is None:
        return
    rows, figure = fits
    run.table("fits", "Texture sets x models", quality_rows(rows), figure=figure)
    run.table("summary", "Per model: mean over the sets, seed spread", summary_rows(rows))
    run.table("sampler", "Sampler variance (Sec. 6.3): relative variance of the albedo estimate with the model's "
                         "sampler and with cosine sampling, their ratio, and the largest |bias| / standard error",
              [{"source": r["name"], "seed": r["seed"], **r["sampler"]} for r in rows if "sampler" in r])
