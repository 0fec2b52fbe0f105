"""Training recipe of the NeuMIP-on-UV baseline of NeuPreSS (`neumat.models.neumip_uv`): every parameter (latent
texture and MLP) fitted by L2 to path-traced observations exactly as NeuPreSS's appearance phase
(`neumat.fit.translucent_fit`, `neumat.fit.recipes.neupress`): Adam lr 1e-3 halved at 50 % and 75 %, batches of
4096, 5 % held back for early stopping, 2000 steps (the budget of benchmarks/studies/neupress/results/neupress.md, where it
scores 0.435 of the held-out variance). The projection centre is the middle of the option "bounds" (default:
the bounding box of the observed points).

CPU_RECIPE: RECIPE itself, which is CPU-sized: its fit, as NeuPreSS's appearance phase (79 s in
benchmarks/studies/neupress/results/neupress.md), takes 1-2 minutes on 2 CPU cores, within the 10-minute CPU budget.
"""
from __future__ import annotations

from neumat.fit.neumip_uv import neumip_uv_predict
from neumat.fit.phase import FitContext, Phase
from neumat.fit.recipe import Recipe
from neumat.fit.translucent_fit import observation_phase, set_bounds_from, split_observations

RECIPE = Recipe(steps=2000, batch_size=4096, lr=1e-3, schedule="halves", loss="l2", log_every=100,
                options={"validation_fraction": 0.05, "max_validation": None, "bounds": None})

#: RECIPE already fits the CPU budget (module docstring)
CPU_RECIPE = RECIPE


def phases(ctx: FitContext) -> list[Phase]:
    model = ctx.model
    train, validation = split_observations(ctx)
    set_bounds_from(ctx)
    (steps,) = ctx.split(("fit",))
    return [observation_phase(ctx, "fit", steps, neumip_uv_predict(model), list(model.parameters()), train,
                              validation)]
