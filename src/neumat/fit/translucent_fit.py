"""Phases of the translucent-object fits (NeuPreSS, the dipole and the UV baselines) for the one trainer
(`neumat.fit.trainer.fit`): the recipe's loss (L2 unless it names another) on random minibatches of path-traced
observations (`Observations`, from `neumat translucent trace`), with early stopping on a held-back fraction of them.

The recipe options these phases read are `ObservationOptions`, the base of every translucent recipe's `Options`.

Details: src/neumat/methods/neupress/NOTES.md, section `neumat.fit.translucent_fit`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Literal, Sequence

import torch
from torch import nn

from ..core.config import bounded
from ..core.errors import InputError
from .phase import FitContext, Phase, loss_module, model_name
from .translucent_observations import Observations
from .translucent_online import OnlineObservations

Predict = Callable[[Observations], torch.Tensor]


@dataclass
class ObservationOptions:
    """Recipe options of every fit on path-traced observations (NeuPreSS and its baselines)."""

    validation_fraction: float = bounded(0.05, ge=0, lt=1)
    """Fraction of the observations held back for early stopping (0: none), drawn with the recipe's seed."""
    max_validation: int | None = bounded(None, ge=1)
    """Use at most this many held-back observations (None: all; a slow model's validation costs less)."""
    bounds: list[list[float]] | None = None
    """Object bounding box [[lo x, y, z], [hi x, y, z]] for model.set_bounds; None: the box recorded with the
    observations, else the observed points'."""


@dataclass
class SourceOptions:
    """Recipe options saying where an appearance phase's batches come from: the observations file, or Mitsuba."""

    source: Literal["offline", "online", "hybrid"] = "offline"
    """offline: batches from the file; online: each traced fresh (no sample reused); hybrid: offline, then online."""
    online_spp: int = bounded(16, ge=1)
    """Paths per observation traced online."""
    online_resolution: int = bounded(32, ge=1)
    """Rays per side of each online view (one light and one Mitsuba trace per view: larger views, fewer calls)."""
    warm_fraction: float = bounded(0.5, ge=0, le=1)
    """hybrid: the fraction of the appearance steps trained on the file's observations before tracing online."""


def online_source(ctx: FitContext, steps: int) -> tuple[OnlineObservations | None, int | None]:
    """(the online source, the phase step it starts at) by option.source for an appearance phase of `steps` steps:
    (None, None) offline; else built from the object the observations describe (InputError without one), with the
    recipe's seed, so that its batches are a function of (seed, step)."""
    opts = ctx.opts
    if opts.source == "offline":
        return None, None
    src = observations_source(ctx)
    online = OnlineObservations.from_observations(src, resolution=opts.online_resolution, spp=opts.online_spp,
                                                  seed=ctx.recipe.seed,
                                                  who=f"fit {model_name(ctx.model)} option.source={opts.source}")
    start = 0 if opts.source == "online" else int(round(opts.warm_fraction * steps))
    return online, start


def observation_mse(predict: Predict, observations: Observations, batch: int = 65536) -> float:
    """Mean squared error of predict on `observations` (per channel), without gradients."""
    total = 0.0
    with torch.no_grad():
        for i in range(0, len(observations), batch):
            o = observations[i:i + batch]
            total += float(((predict(o) - o.value) ** 2).sum())
    return total / (len(observations) * observations.value.shape[-1])


def observations_source(ctx: FitContext) -> Observations:
    """ctx.source, checked: InputError naming what was expected for anything but non-empty Observations."""
    src = ctx.source
    if not isinstance(src, Observations):
        raise InputError(f"fit {model_name(ctx.model)}: source must be path-traced observations "
                         "(neumat.fit.translucent_observations.Observations, e.g. Observations.load of a file "
                         f"from `neumat translucent trace`), got {type(src).__name__}")
    if len(src) == 0:
        raise InputError(f"fit {model_name(ctx.model)}: the observations are empty")
    return src


def split_observations(ctx: FitContext) -> tuple[Observations, Observations | None]:
    """(training, validation or None) on ctx.device, by the recipe's validation options."""
    src = observations_source(ctx)
    fraction = ctx.opts.validation_fraction
    if fraction == 0:
        return src.to(ctx.device), None
    train, held = src.split(fraction, seed=ctx.recipe.seed)
    limit = ctx.opts.max_validation
    if limit is not None:
        held = held[:limit]
    if len(train) == 0:
        raise InputError(f"fit {model_name(ctx.model)}: validation_fraction {fraction} of {len(src)} observations "
                         "leaves none to train on")
    return train.to(ctx.device), held.to(ctx.device)


def set_bounds_from(ctx: FitContext) -> None:
    """model.set_bounds from the option bounds, else the bounding box recorded with the observations
    (`Observations.bbox`, the object's), else that of the observed points: one rule for every entry point. Only on
    a fresh fit (a resumed one has them from the checkpoint)."""
    if ctx.resuming or not hasattr(ctx.model, "set_bounds"):
        return
    box = ctx.opts.bounds
    src = observations_source(ctx)
    if box is not None:
        if len(box) != 2 or any(len(b) != 3 for b in box):
            raise InputError(f"{model_name(ctx.model)} recipe options: option.bounds: expected [[lo x, y, z], "
                             f"[hi x, y, z]] or None, got {box!r}")
        lo, hi = (torch.tensor(b, dtype=torch.float32) for b in box)
    elif src.bbox is not None:
        lo, hi = src.bbox
    else:
        lo, hi = src.x.min(0).values, src.x.max(0).values
    ctx.model.set_bounds(lo.to(ctx.device), hi.to(ctx.device))


class EarlyStopping(nn.Module):
    """Best validation MSE, its step and the parameters then (buffers): what an appearance phase keeps across
    steps, checkpointed by the trainer."""

    def __init__(self, params: Sequence[nn.Parameter]) -> None:
        super().__init__()
        self.register_buffer("best_mse", torch.tensor(math.inf, dtype=torch.float64))
        self.register_buffer("best_step", torch.tensor(-1, dtype=torch.int64))
        for i, p in enumerate(params):
            self.register_buffer(f"best_{i}", p.detach().clone())

    def observe(self, step: int, mse: float, params: Sequence[nn.Parameter]) -> None:
        if mse < float(self.best_mse):  # NaN never wins
            self.best_mse.fill_(mse)
            self.best_step.fill_(step)
            for i, p in enumerate(params):
                getattr(self, f"best_{i}").copy_(p.detach())

    def restore(self, params: Sequence[nn.Parameter]) -> None:
        with torch.no_grad():
            for i, p in enumerate(params):
                p.copy_(getattr(self, f"best_{i}"))


def best_validation(history: list[dict]) -> dict | None:
    """The history record with the lowest "validation_mse" (the weights a validated phase ends with), or None
    when no record has one."""
    records = [r for r in history if math.isfinite(r.get("validation_mse", math.nan))]
    return min(records, key=lambda r: r["validation_mse"]) if records else None


def observation_phase(ctx: FitContext, name: str, steps: int, predict: Predict, params: list[nn.Parameter],
                      train: Observations, validation: Observations | None,
                      penalty: Callable[[], dict[str, torch.Tensor]] | None = None,
                      online: OnlineObservations | None = None, online_from: int | None = None) -> Phase:
    """`steps` steps of the recipe's loss (`recipe.loss`; "l2": the mean squared error) of predict(o) against
    o.value on `recipe.batch_size` observations drawn (with ctx.generator) from `train`, plus the losses
    `penalty()` returns (a regulariser) if given; early stopping on the validation MSE of `validation` unless it
    is None (both from `split_observations`). With `online` (from `online_source`), the steps from `online_from` on
    train on fresh batches `online.draw(step)`."""
    recipe = ctx.recipe
    gen = ctx.generator
    loss = loss_module(ctx)
    named = ctx.loss if ctx.loss is not None else recipe.loss
    key = "mse" if named == "l2" else named if isinstance(named, str) else "objective"  # its record's name

    def batch_loss(step: int) -> torch.Tensor:
        if online is not None and step >= online_from:
            o = online.draw(step, recipe.batch_size).to(ctx.device)
        else:
            idx = torch.randint(len(train), (recipe.batch_size,), generator=gen, device=gen.device)
            o = train[idx.to(train.x.device)]
        return loss(predict(o), o.value, None)  # no Query: the observation losses read values only

    def losses(step: int) -> dict[str, torch.Tensor]:
        return {key: batch_loss(step), **(penalty() if penalty is not None else {})}

    slow_from = online_from if online is not None and online_from < steps else None
    if validation is None:
        return Phase(name, steps, losses, params, slow_from=slow_from)

    stopping = EarlyStopping(params).to(ctx.device)

    def on_record(record: dict) -> None:  # the weights after record["step"] updates
        record["validation_mse"] = observation_mse(predict, validation, recipe.batch_size)
        stopping.observe(record["step"], record["validation_mse"], params)

    def after() -> None:
        if int(stopping.best_step) < 0:
            raise InputError(f"fit {model_name(ctx.model)} ({name}): the validation MSE was never finite; the fit "
                             f"diverged (lower lr, now {recipe.lr})")
        stopping.restore(params)

    return Phase(name, steps, losses, params, after=after, stateful=[stopping], on_record=on_record,
                 slow_from=slow_from)


def observation_report(model, source: Observations, result) -> tuple[dict, dict]:
    """What a fit on observations reports beyond its loss: (metrics saved in the .nmat, one table row). The
    held-back error at the best step relative to the held-back values' variance, and the light sampler's last KL
    where the model trains one."""
    from .method import typed_options

    metrics: dict = {}
    row: dict = {"observations": len(source)}
    best = best_validation(result.history)
    if best is not None:
        opts = typed_options(model_name(model), result.recipe.options)
        held = source.split(opts.validation_fraction, seed=result.recipe.seed)[1]  # as the phases split
        variance = float(held.value.var())
        metrics.update(validation_mse=best["validation_mse"], validation_variance=variance, best_step=best["step"])
        row.update({"validation": len(held), "best step": best["step"], "validation MSE": best["validation_mse"],
                    "relative to its variance": best["validation_mse"] / variance if variance > 0 else None})
    kl = [r["kl"] for r in result.history if r.get("phase") == "sampler" and "kl" in r]
    if kl:
        metrics["sampler_kl"] = row["sampler KL"] = kl[-1]
    return metrics, row
