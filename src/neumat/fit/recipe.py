"""A training recipe: optimiser, schedule, batch, loss, query distribution, seed and options of one fit.

A model's recipe module `neumat.fit.recipes.<name>` ('-' -> '_') holds `RECIPE` (the paper's), `CPU_RECIPE` (the
paper's model on a CPU budget), optionally `NAMED_RECIPES`, typed `Options`, `phases(ctx)` for staged training,
`config_for_source(source, options)` for config fields that follow the source, and `PRESETS` (`neumat.fit.preset`,
what users choose between). Recipes are plain dataclasses, stored as JSON in model files and checkpoints.
"""
from __future__ import annotations

import importlib
import math
import pkgutil
from dataclasses import dataclass, field, replace
from typing import Any, Callable

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
    """Learning-rate schedule: "step" (lr * lr_decay^(step // lr_decay_every)), "cosine" (from lr down to
    lr_min at the last step) or "halves" (lr halved at 50 % and again at 75 % of the steps). In a fit of
    several phases, each phase runs the schedule over its own steps."""
    lr_min: float = 0.0
    """Final learning rate of the "cosine" schedule."""
    checkpoint_every: int = 1000
    """Steps between checkpoints when `fit(..., checkpoint=path)` is given (one is also written at the end)."""
    phase_split: tuple[float, ...] = ()
    """Fractions of `steps` given to each phase of a staged fit, in the order of the recipe module's phases
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


def _recipe_module(model_name: str):
    module = f"neumat.fit.recipes.{model_name.replace('-', '_')}"
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as e:
        if e.name != module:
            raise
        raise UnknownNameError(f"no training recipe for model {model_name!r} (expected module {module})") from None


#: machine -> the recipe-module attribute sized for it: "paper" (= "gpu") the paper's recipe, "cpu" the CPU-sized one
MACHINE_RECIPES = {"paper": "RECIPE", "gpu": "RECIPE", "cpu": "CPU_RECIPE"}


def recipe_for(model_name: str, machine: str = "paper") -> Recipe:
    """A copy of a recipe of model `model_name` from `neumat.fit.recipes.<name, '-' -> '_'>`: its `RECIPE`
    (the paper's, sized for a GPU) for machine "paper" or "gpu", its `CPU_RECIPE` for "cpu", else the recipe of
    that name in its `NAMED_RECIPES` (InputError naming the model's choices when it has none of that name)."""
    mod = _recipe_module(model_name)
    named = getattr(mod, "NAMED_RECIPES", {})
    if machine in MACHINE_RECIPES:
        where = f"{mod.__name__}.{MACHINE_RECIPES[machine]}"
        recipe = getattr(mod, MACHINE_RECIPES[machine], None)
    elif machine in named:
        where, recipe = f"{mod.__name__}.NAMED_RECIPES[{machine!r}]", named[machine]
    else:
        raise InputError(f"recipe {machine!r}: model {model_name} has the recipes "
                         f"{', '.join(recipe_choices(model_name))}")
    if not isinstance(recipe, Recipe):
        raise InputError(f"{where}: expected a neumat.fit.recipe.Recipe, got {type(recipe).__name__}")
    return replace(recipe, options=dict(recipe.options))  # a copy: callers may edit it


def recipe_choices(model_name: str) -> list[str]:
    """The recipe names `recipe_for(model_name, name)` takes: "paper", "cpu" (and "gpu", the same as "paper",
    not listed), then the model's `NAMED_RECIPES`."""
    return ["paper", "cpu", *getattr(_recipe_module(model_name), "NAMED_RECIPES", {})]


def latent_size_for_source(source: Any) -> int | None:
    """The latent-texture resolution that follows a spatially varying source: the largest power of two not above
    the smaller side of its textures (`source.textures.size` or `source.texture_size`, (height, width)), or None
    when the source has no textures (a homogeneous material)."""
    size = getattr(getattr(source, "textures", None), "size", None) or getattr(source, "texture_size", None)
    return None if size is None else 1 << (min(size).bit_length() - 1)


def phases_for(model_name: str) -> Callable | None:
    """The `phases(ctx)` builder of model `model_name`'s recipe module, or None for a single online phase."""
    return getattr(_recipe_module(model_name), "phases", None)


def recipe_names() -> list[str]:
    """Registry names of every model with a recipe module ('_' -> '-')."""
    package = importlib.import_module("neumat.fit.recipes")
    return sorted(info.name.replace("_", "-") for info in pkgutil.iter_modules(package.__path__))


def options_class(model_name: str) -> type | None:
    """The typed recipe options (a dataclass, validated by `neumat.core.config`) of model `model_name`'s recipe
    module (its `Options`), or None when its options are an untyped dict or it has no recipe module."""
    try:
        return getattr(_recipe_module(model_name), "Options", None)
    except UnknownNameError:
        return None


def typed_options(model_name: str, options: dict) -> Any:
    """`options` (a recipe's options dict) as model `model_name`'s `Options` dataclass, strictly checked (unknown
    keys, types and ranges raise InputError); the dict itself for a model without typed options."""
    from ..core.config import config_from_dict

    cls = options_class(model_name)
    if cls is None:
        return options
    try:
        return config_from_dict(cls, options)
    except InputError as e:
        text = str(e).replace(f"{cls.__name__}: ", "").replace(f"{cls.__name__}.", "option.")
        raise InputError(f"{model_name} recipe options: {text}") from None


def recipe_config_for_source(model_name: str, source: Any, options: dict) -> dict:
    """Config defaults of model `model_name` that follow its training source and the recipe's `options`: the
    recipe module's `config_for_source(source, options) -> dict` (e.g. a latent resolution from the texture
    size, a BTF's direction counts), or {}."""
    derive = getattr(_recipe_module(model_name), "config_for_source", None)
    return dict(derive(source, options)) if derive is not None else {}
