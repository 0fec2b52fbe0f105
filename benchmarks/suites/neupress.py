"""neupress: NeuPreSS (translucent objects) through the library's trainer. Quick: a smooth synthetic translucent
response; full: observations traced by Mitsuba are not yet a suite input (see skipped)."""
from __future__ import annotations

import torch

from neumat.core.query import Query
from neumat.fit.preset import build_fit
from neumat.fit.trainer import fit
from neumat.fit.translucent_observations import Observations
from neumat.warp.sphere import sample_uniform_sphere

from .. import harness
from .common import paper_budget, recipe_budget

NAME = "neupress"
DESCRIPTION = "NeuPreSS and the dipole baselines: held-out error over held-out variance, through the trainer"
MODELS = ["neupress", "dipole-bssrdf"]
BUDGET = {
    "quick": {"ours": "neupress (2 layers of 16) and the textured dipole, 20 steps on 2000 synthetic observations",
              "paper": paper_budget(MODELS[:1]) + " on a GPU", "expected_wall": "about 10 s"},
    "full": {"ours": f"CPU recipes: {recipe_budget(MODELS)}; 2^16 synthetic observations, seeds 0 and 1",
             "paper": paper_budget(MODELS[:1]) + " on a GPU, on path-traced observations of the bunny and kitten",
             "expected_wall": "about 20 min"},
}
SMALL = {"neupress": dict(features=16, width=16, layers=2, sampler_hidden=[8]),
         "dipole-bssrdf": dict(samples=16, texture_resolution=2)}


def observations(n: int, seed: int) -> Observations:
    """A smooth translucent response on a sphere of radius 0.5: a wrapped-cosine term times a spatial tint."""
    g = torch.Generator().manual_seed(seed)
    x = 0.5 * sample_uniform_sphere(torch.rand(n, 2, generator=g))
    normal = 2 * x
    wi = sample_uniform_sphere(torch.rand(n, 2, generator=g))
    value = (0.05 + 0.05 * (wi * normal).sum(-1, keepdim=True).clamp(min=0)) * (0.6 + 0.4 * normal.abs())
    return Observations(x=x, n=normal, wo=normal.clone(), wi=wi, value=value)


def run(run: harness.Run) -> None:
    """Fit each model, score held-out MSE over the held-out values' variance (1 = predicting the mean)."""
    n, steps = (2000, 20) if run.quick else (2 ** 16, None)
    seeds = [run.seed] if run.quick else [run.seed, run.seed + 1]
    test = observations(n // 4, 10_000)
    rows = []
    for seed in seeds:
        train = observations(n, seed)
        for name in MODELS:
            model, setting = build_fit(name, "cpu", source=train, overrides=SMALL[name] if run.quick else {},
                                       seed=seed)
            result = fit(model, train, setting.recipe, steps=steps, progress=False)
            with torch.no_grad():
                pred = result.model.eval(Query(test.wi, test.wo, x=test.x, n=test.n))
            rows.append({"model": name, "seed": seed, "steps": result.steps, "fit s": result.seconds,
                         "held-out mse / var": ((pred - test.value) ** 2).mean() / test.value.var(),
                         "bytes": model.size_bytes()})
    run.table("fits", "Synthetic translucent response", rows)
    run.skip("image table, baselines and SH-PRT on path-traced objects", "observations traced by Mitsuba are not yet "
             "a suite input; last measured by benchmarks/studies/neupress/")
