"""A training recipe: optimiser, schedule, batch, loss, query distribution and seed of one fit.

Each model ships its paper's defaults as `RECIPE` in `neumat.fit.recipes.<model name>`; `recipe_for`
finds them. Recipes are plain dataclasses, so `config_from_dict(Recipe, ...)` / `config_to_dict` turn
them into JSON for model files and `--set` overrides.
"""
from __future__ import annotations

import importlib
import math
from dataclasses import dataclass, replace

from ..core.checks import check_int, check_number
from ..core.errors import InputError, UnknownNameError


@dataclass
class Recipe:
    """Hyper-parameters of one fit (Adam on online targets)."""

    steps: int
    """Optimiser steps."""
    batch_size: int
    """Queries per step."""
    lr: float
    """Adam learning rate at step 0."""
    betas: tuple[float, float] = (0.9, 0.999)
    """Adam betas."""
    eps: float = 1e-8
    """Adam epsilon."""
    lr_decay: float = 1.0
    """"step" schedule: the learning rate is multiplied by this every `lr_decay_every` steps."""
    lr_decay_every: int = 0
    """Period of the step decay in steps; 0 = constant learning rate."""
    ema: float = 0.0
    """Weight of the new parameters in the exponential moving average per step (0 = no EMA). The EMA
    copy is the fitted model: it is what gets evaluated and saved."""
    loss: str = "log_cos"
    """Name in `neumat.fit.losses.LOSSES`."""
    queries: str = "cosine"
    """Name in `neumat.fit.query_samplers.QUERY_SAMPLERS`."""
    seed: int = 0
    """Seed of the query generator (model initialisation is seeded by whoever builds the model)."""
    grad_clip: float = 0.0
    """Clip the global gradient norm to this value; 0 = off."""
    log_every: int = 50
    """Steps between history records and progress-bar loss updates."""
    schedule: str = "step"
    """Learning-rate schedule: "step" (lr * lr_decay^(step // lr_decay_every)) or "cosine" (from lr down to
    lr_min at the last step)."""
    lr_min: float = 0.0
    """Final learning rate of the "cosine" schedule."""
    checkpoint_every: int = 1000
    """Steps between checkpoints when `fit(..., checkpoint=path)` is given (one is also written at the end)."""


def check_recipe(r: Recipe) -> Recipe:
    """Raise InputError naming the first invalid field of `r`; returns `r`."""
    for name, lo in (("steps", 0), ("batch_size", 1), ("lr_decay_every", 0), ("log_every", 1),
                     ("checkpoint_every", 1)):
        check_int(getattr(r, name), f"Recipe.{name}", lo)
    for name in ("lr", "eps", "lr_decay", "ema", "grad_clip", "lr_min"):
        check_number(getattr(r, name), f"Recipe.{name}", 0)
    if r.lr <= 0:
        raise InputError(f"Recipe.lr: expected a positive learning rate, got {r.lr!r}")
    if r.ema > 1:
        raise InputError(f"Recipe.ema: expected a weight in [0, 1], got {r.ema!r}")
    if len(r.betas) != 2 or not all(0 <= b < 1 for b in r.betas):
        raise InputError(f"Recipe.betas: expected two numbers in [0, 1), got {r.betas!r}")
    if r.schedule not in ("step", "cosine"):
        raise InputError(f"Recipe.schedule: expected 'step' or 'cosine', got {r.schedule!r}")
    return r


def learning_rate(r: Recipe, step: int, total_steps: int) -> float:
    """Learning rate of step `step` (0-based) of a fit with `total_steps` steps."""
    if r.schedule == "cosine":
        t = step / max(total_steps - 1, 1)
        return r.lr_min + (r.lr - r.lr_min) * 0.5 * (1 + math.cos(math.pi * t))
    if r.lr_decay_every <= 0:
        return r.lr
    return r.lr * r.lr_decay ** (step // r.lr_decay_every)


def recipe_for(model_name: str) -> Recipe:
    """A copy of the default recipe of model `model_name`: `neumat.fit.recipes.<name, '-' -> '_'>.RECIPE`."""
    module = f"neumat.fit.recipes.{model_name.replace('-', '_')}"
    try:
        mod = importlib.import_module(module)
    except ModuleNotFoundError as e:
        if e.name != module:
            raise
        raise UnknownNameError(f"no training recipe for model {model_name!r} (expected module {module})") from None
    recipe = getattr(mod, "RECIPE", None)
    if not isinstance(recipe, Recipe):
        raise InputError(f"{module}.RECIPE: expected a neumat.fit.recipe.Recipe, got {type(recipe).__name__}")
    return replace(recipe)  # a copy: callers may edit it
