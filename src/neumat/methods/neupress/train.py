"""Training recipe of NeuPreSS (TG, Frisvad, Ramamoorthi, Jensen; Sec. 4.2), in two phases on path-traced
observations (`neumat.fit.translucent_observations.Observations`, the source of the fit):

Details (schedule, options, measurements): src/neumat/methods/neupress/NOTES.md,
section `neumat.methods.neupress.train`.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch

from neumat.core.config import bounded, config_to_dict
from neumat.core.errors import InputError
from neumat.methods.neupress.targets import light_grid, neupress_predict, sampler_kl
from neumat.fit.phase import FitContext, Phase
from neumat.fit.recipe import Recipe
from neumat.fit.translucent_fit import (ObservationOptions, SourceOptions, observation_phase, online_source,
                                       set_bounds_from, split_observations)


@dataclass
class Options(SourceOptions, ObservationOptions):
    """NeuPreSS's recipe options: those of every fit on observations, where its batches come from (the file or
    Mitsuba online), and the sampler phase's."""

    sampler_batch: int = bounded(32, ge=1)
    """Random training observations (x, wo, n) per step of the sampler phase."""
    grid: tuple[int, int] = (32, 64)
    """[n_theta, n_phi] light directions the appearance module's output is binned on for the sampler's KL."""


RECIPE = Recipe(steps=2300, batch_size=4096, lr=1e-3, schedule="halves", loss="l2", log_every=100,
                phase_split=(20 / 23, 3 / 23), options=config_to_dict(Options()))

#: RECIPE already fits the CPU budget (module docstring)
CPU_RECIPE = RECIPE


def phases(ctx: FitContext) -> list[Phase]:
    model = ctx.model
    train, validation = split_observations(ctx)
    set_bounds_from(ctx)
    appearance_steps, sampler_steps = ctx.split(("appearance", "sampler"))
    online, online_from = online_source(ctx, appearance_steps)
    appearance = [p for name, p in model.named_parameters() if name.startswith("appearance")]
    sampler = [p for name, p in model.named_parameters() if name.startswith("sampler")]
    batch, size = ctx.opts.sampler_batch, ctx.opts.grid
    if len(size) != 2 or min(size) < 1:
        raise InputError(f"neupress recipe options: option.grid: expected [n_theta, n_phi] (positive integers), "
                         f"got {list(size)}")
    grid = tuple(t.to(ctx.device) for t in light_grid(*size))
    gen = ctx.generator

    def kl(step: int) -> dict[str, torch.Tensor]:
        idx = torch.randint(len(train), (batch,), generator=gen, device=gen.device).to(train.x.device)
        return {"kl": sampler_kl(model, train.x[idx], train.wo[idx], train.n[idx], grid)}

    return [observation_phase(ctx, "appearance", appearance_steps, neupress_predict(model), appearance, train,
                              validation, online=online, online_from=online_from),
            Phase("sampler", sampler_steps, kl, sampler)]
