"""Training recipe of the GGX baseline: a few thousand Adam steps on the 7 (or 8) parameters, from the best of a
few starting roughnesses.

Details (schedule, options, measurements): src/neumat/methods/neubrdf/NOTES.md,
section `neumat.methods.baselines.ggx_train`.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass, field, replace

import torch

from neumat.core.config import bounded, config_to_dict
from neumat.core.errors import InputError
from neumat.fit.phase import FitContext, Phase, loss_module, online_phase, online_targets, query_draw
from neumat.fit.recipe import Recipe



@dataclass
class Options:
    """The GGX recipe's trial starts (module docstring)."""

    alpha_starts: list[float] = field(default_factory=lambda: [0.3, 0.05, 0.01])
    """Starting roughnesses of the trial fits, inside the model's (alpha_min, alpha_max); fewer than two: no trials."""
    start_steps: int = bounded(200, ge=1)
    """Steps of each trial fit (at most the fit's own)."""


RECIPE = Recipe(steps=2000, batch_size=16384, lr=2e-2, schedule="cosine", lr_min=1e-3,
                loss="log_cos", queries="rusinkiewicz", options=config_to_dict(Options()))

#: the paper-size recipe already fits the CPU budget (module docstring)
CPU_RECIPE = RECIPE


def phases(ctx: FitContext) -> list[Phase]:
    """One online phase, on a fresh fit from the best start (module docstring)."""
    starts, steps = _starts(ctx)
    if len(starts) > 1 and not ctx.resuming:  # a trial is never longer than the fit itself
        ctx.model.load_state_dict(best_start(ctx, starts, min(steps, ctx.recipe.steps)).state_dict())
    return [online_phase(ctx)]


def best_start(ctx: FitContext, starts: list[float], steps: int):
    """The trial fit (a copy of ctx.model restarted at each alpha of `starts`, `steps` steps of ctx's recipe with
    seed + i) with the lowest loss on one batch drawn with seed recipe.seed + 3; the first on ties."""
    from neumat.fit.trainer import fit

    recipe = ctx.recipe
    trial_recipe = replace(recipe, steps=steps, log_every=steps, checkpoint_every=steps,
                           options={**recipe.options, "alpha_starts": []})
    draw = query_draw(ctx)
    q = draw(recipe.batch_size, torch.Generator(device=ctx.device).manual_seed(recipe.seed + 3), ctx.device)
    target = online_targets(ctx, q).to(ctx.device)
    loss_fn = loss_module(ctx)
    best, best_loss = None, float("inf")
    for i, alpha in enumerate(starts):
        trial = type(ctx.model)(replace(ctx.model.cfg, init_alpha=alpha)).to(ctx.device)
        fit(trial, ctx.source, replace(trial_recipe, seed=recipe.seed + i), device=ctx.device, progress=False,
            loss=ctx.loss, queries=ctx.queries)
        with torch.no_grad():
            value = float(loss_fn(trial.eval(q), target.to(trial.raw_alpha.dtype), q))
        if value < best_loss:
            best, best_loss = copy.deepcopy(trial), value
    if best is None:
        raise InputError(f"ggx recipe: every start ({starts}) ended with a non-finite loss")
    return best


def _starts(ctx: FitContext) -> tuple[list[float], int]:
    """(alpha_starts, start_steps); InputError for a start outside the model's alpha range."""
    o = ctx.opts
    cfg = getattr(ctx.model, "cfg", None)
    lo, hi = getattr(cfg, "alpha_min", 0.0), getattr(cfg, "alpha_max", 1.0)
    if not all(lo < a < hi for a in o.alpha_starts):
        raise InputError(f"ggx recipe options: option.alpha_starts: expected alphas in ({lo}, {hi}) (the model's "
                         f"alpha_min, alpha_max), got {o.alpha_starts}")
    return o.alpha_starts, o.start_steps
