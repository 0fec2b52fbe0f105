"""Training recipe of NeuPreSS (TG, Frisvad, Ramamoorthi, Jensen; Sec. 4.2), in two phases on path-traced
observations (`neumat.fit.translucent_observations.Observations`, the source of the fit):

1. "appearance": Adam on the appearance module only, L2 (Eq. 6) on random batches of `batch_size`
   observations, lr 1e-3 halved at 50 % and 75 % of the phase ("halves"). 5 % of the observations are held
   back (the paper keeps 5 %); the validation MSE is measured every `log_every` steps and the phase ends with
   the weights of its lowest value (early stopping: noisy path-traced targets are otherwise learnt by heart;
   `neumat.fit.translucent_fit`). The bounding box that scales positions is the option bounds, else the object's
   recorded with the observations, else the observed points' (`neumat.fit.translucent_fit.set_bounds_from`).
2. "sampler": Adam on the importance-sampling module only, the KL divergence (`neumat.fit.neupress.sampler_kl`)
   between the appearance module's output binned on a `grid` = 32 x 64 grid of light directions and the
   Gaussian lobe, at `sampler_batch` = 32 random (x, wo, n) of the training observations per step.

Steps: 2000 appearance + 300 sampler (phase_split 20/23, 3/23 of 2300), the budget of every run in
benchmarks/studies/neupress/results/neupress.md (the low-frequency and smooth variants reach their best validation record at
steps 1800-1900 of 2000; the sampler's KL is 0.04-0.05 after 300 steps). The 4000 + 1000 steps that the old
`fit_neupress` defaults named were never measured. The Fourier scale is the model's (`NeuPreSS.Config`: G ~
N(0, 0.3^2), not the paper's N(18, 1); see there).

CPU_RECIPE: RECIPE itself, which is CPU-sized: the NeuPreSS fit of benchmarks/studies/neupress/results/neupress.md took 79 + 143 s
(appearance + sampler) on 2 CPU cores, within the 10-minute CPU budget.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch

from neumat.core.config import bounded, config_to_dict
from neumat.core.errors import InputError
from neumat.fit.neupress import light_grid, neupress_predict, sampler_kl
from neumat.fit.phase import FitContext, Phase
from neumat.fit.recipe import Recipe
from neumat.fit.translucent_fit import ObservationOptions, observation_phase, set_bounds_from, split_observations


@dataclass
class Options(ObservationOptions):
    """NeuPreSS's recipe options: those of every fit on observations, and the sampler phase's."""

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
                              validation),
            Phase("sampler", sampler_steps, kl, sampler)]
