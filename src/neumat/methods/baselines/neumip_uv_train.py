"""Training recipe of the NeuMIP-on-UV baseline of NeuPreSS (`neumat.methods.baselines.neumip_uv`): every parameter
(latent texture and MLP) fitted by L2 to path-traced observations exactly as NeuPreSS's appearance phase
(`neumat.fit.translucent_fit`, `neumat.methods.neupress.train`): Adam lr 1e-3 halved at 50 % and 75 %, batches of
4096, 5 % held back for early stopping, 2000 steps (the budget of benchmarks/studies/neupress/results/neupress.md, where
it scores 0.435 of the held-out variance). The projection centre is the middle of the bounding box
(`neumat.fit.translucent_fit.set_bounds_from`: option bounds, else the object's recorded box, else the points').

CPU_RECIPE: RECIPE itself, which is CPU-sized: its fit, as NeuPreSS's appearance phase (79 s in
benchmarks/studies/neupress/results/neupress.md), takes 1-2 minutes on 2 CPU cores, within the 10-minute CPU budget.
"""
from __future__ import annotations

from neumat.core.config import config_to_dict
from neumat.methods.baselines.neumip_uv_targets import neumip_uv_predict
from neumat.fit.phase import FitContext, Phase
from neumat.fit.recipe import Recipe
from neumat.fit.translucent_fit import ObservationOptions, observation_phase, set_bounds_from, split_observations

#: the recipe options: those of every fit on observations
Options = ObservationOptions

RECIPE = Recipe(steps=2000, batch_size=4096, lr=1e-3, schedule="halves", loss="l2", log_every=100,
                options=config_to_dict(Options()))

#: RECIPE already fits the CPU budget (module docstring)
CPU_RECIPE = RECIPE


def phases(ctx: FitContext) -> list[Phase]:
    model = ctx.model
    train, validation = split_observations(ctx)
    set_bounds_from(ctx)
    (steps,) = ctx.split(("fit",))
    return [observation_phase(ctx, "fit", steps, neumip_uv_predict(model), list(model.parameters()), train,
                              validation)]
