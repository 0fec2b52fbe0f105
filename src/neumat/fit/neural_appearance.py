"""Compatibility shim: `fit_neural_appearance`, the old entry point of neural-appearance training, now a thin
wrapper of the one trainer (`neumat.fit.trainer.fit` with the recipe `neumat.fit.recipes.neural_appearance`,
where the training itself and all its defaults live). Only `neumat.cli.fitting` still calls it; delete this
module once the CLI calls `neumat.fit.trainer.fit` (with `config_for_source` of the recipe module) itself."""
from __future__ import annotations

from dataclasses import dataclass, replace

from ..core.checks import check_int


@dataclass
class NeuralAppearanceFit:
    """history: the trainer's records ({"step", "phase", "loss", "brdf loss", "sampler loss"[, "albedo loss"],
    "lr", "seconds"}); seconds: {"total": training seconds}."""

    history: list[dict]
    seconds: dict


def fit_neural_appearance(model, source, encoder_steps: int | None = None, latent_steps: int | None = None,
                          batch: int | None = None, lr: float | None = None, seed: int | None = None,
                          log_every: int | None = None, progress: bool = True, **options) -> NeuralAppearanceFit:
    """`neumat.fit.trainer.fit(model, source, recipe)` with the recipe's fields overridden where given:
    steps = encoder_steps + latent_steps split as given (phase_split), batch -> batch_size, lr, seed,
    log_every, and `options` (directions, blur_degrees, blur_samples, blur_until, sampler_batch) -> options.
    None: the recipe's value."""
    from .recipe import recipe_for
    from .trainer import fit

    recipe = recipe_for("neural-appearance")
    if encoder_steps is not None or latent_steps is not None:
        split = recipe.steps * recipe.phase_split[0]
        enc = int(round(split)) if encoder_steps is None else encoder_steps
        lat = recipe.steps - enc if latent_steps is None else latent_steps
        check_int(enc, "fit_neural_appearance encoder_steps", 0)
        check_int(lat, "fit_neural_appearance latent_steps", 0)
        total = enc + lat
        recipe = replace(recipe, steps=total, phase_split=(enc / total, lat / total) if total else (0.5, 0.5))
    changes = {k: v for k, v in (("batch_size", batch), ("lr", lr), ("seed", seed), ("log_every", log_every))
               if v is not None}
    recipe = replace(recipe, **changes, options={**recipe.options, **options})
    result = fit(model, source, recipe, progress=progress)
    return NeuralAppearanceFit(result.history, {"total": result.seconds})
