"""A training recipe: optimiser, schedule, batch, loss, query distribution, seed and options of one fit.

A model's recipes ("paper", "cpu" and named ones) are part of its `neumat.fit.method.Method`, with its typed
options and phases; `neumat.fit.method.recipe_for` looks them up. Recipes are plain dataclasses, stored as JSON in
model files and checkpoints.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Callable

from ..core.checks import check_int, check_number
from ..core.errors import InputError


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
    """Learning-rate schedule: "step" (lr * lr_decay^(step // lr_decay_every)), "cosine" (from lr down to
    lr_min at the last step) or "halves" (lr halved at 50 % and again at 75 % of the steps). In a fit of
    several phases, each phase runs the schedule over its own steps."""
    lr_min: float = 0.0
    """Final learning rate of the "cosine" schedule."""
    checkpoint_every: int = 1000
    """Steps between checkpoints when `fit(..., checkpoint=path)` is given (one is also written at the end)."""
    phase_split: tuple[float, ...] = ()
    """Fractions of `steps` given to each phase of a staged fit, in the order of the method's phases
    (the last phase takes the rounding rest); empty for a single-phase fit."""
    options: dict[str, Any] = field(default_factory=dict)
    """Model-specific training options with their defaults (e.g. neural-appearance's "directions"); `--set`
    changes them by name, unknown names raise."""


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
    if r.schedule not in ("step", "cosine", "halves"):
        raise InputError(f"Recipe.schedule: expected 'step', 'cosine' or 'halves', got {r.schedule!r}")
    if not all(isinstance(f, (int, float)) and math.isfinite(f) and 0 <= f <= 1 for f in r.phase_split) \
            or sum(r.phase_split) > 1 + 1e-9:
        raise InputError(f"Recipe.phase_split: expected fractions in [0, 1] summing to at most 1, got "
                         f"{list(r.phase_split)}")
    if not isinstance(r.options, dict):
        raise InputError(f"Recipe.options: expected a dict, got {type(r.options).__name__}")
    for key, value in r.options.items():
        for v in value if isinstance(value, (list, tuple)) else (value,):
            if isinstance(v, float) and not math.isfinite(v):
                raise InputError(f"Recipe.options[{key!r}]: expected finite numbers, got {value!r}")
    return r


def learning_rate(r: Recipe, step: int, total_steps: int) -> float:
    """Learning rate of step `step` (0-based) of a fit with `total_steps` steps."""
    if r.schedule == "cosine":
        t = step / max(total_steps - 1, 1)
        return r.lr_min + (r.lr - r.lr_min) * 0.5 * (1 + math.cos(math.pi * t))
    if r.schedule == "halves":
        return r.lr * 0.5 ** ((step >= total_steps // 2) + (step >= 3 * total_steps // 4))
    if r.lr_decay_every <= 0:
        return r.lr
    return r.lr * r.lr_decay ** (step // r.lr_decay_every)


def latent_size_for_source(source: Any) -> int | None:
    """The latent-texture resolution that follows a spatially varying source: the largest power of two not above
    the smaller side of its textures (`source.textures.size` or `source.texture_size`, (height, width)), or None
    when the source has no textures (a homogeneous material)."""
    size = getattr(getattr(source, "textures", None), "size", None) or getattr(source, "texture_size", None)
    return None if size is None else 1 << (min(size).bit_length() - 1)
