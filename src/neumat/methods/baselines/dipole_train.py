"""Training recipe of the dipole baselines of NeuPreSS (Jensen et al. 2001 over a surface quadrature): its six
coefficients (log sigma_a, log sigma_s'), and with `texture_resolution` > 1 their texture of offsets, fitted by L2
to path-traced observations (differentiable rendering of the observations, Deng et al. 2022), as NeuPreSS's
appearance phase (`neumat.fit.translucent_fit`): Adam lr 0.05 halved at 50 % and 75 %, 300 steps of 256 observations,
5 % held back for early stopping, of which at most 4096 are used (each evaluation sums over the whole surface
quadrature: 1.9e3 queries/s in benchmarks/studies/neupress/results/neupress.md). The model needs its surface quadrature
(`DipoleBSSRDF.set_surface`, from the object: `TranslucentObject.surface_samples`); a fresh fit of a model
without one takes `cfg.samples` observed points with their normals, each standing for 1 / samples of the area

Details (schedule, options, measurements): src/neumat/methods/neupress/NOTES.md,
section `neumat.methods.baselines.dipole_train`.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
from scipy.spatial import ConvexHull

from neumat.core.config import bounded, config_to_dict
from neumat.core.errors import InputError
from neumat.methods.baselines.dipole_observed import dipole_predict
from neumat.fit.phase import FitContext, Phase
from neumat.fit.recipe import Recipe
from neumat.fit.translucent_fit import ObservationOptions, observation_phase, set_bounds_from, split_observations


@dataclass
class Options(ObservationOptions):
    """The dipole's recipe options: those of every fit on observations, and the texture's smoothness."""

    max_validation: int | None = bounded(4096, ge=1)
    """Use at most this many held-back observations (None: all); each sums over the whole surface quadrature."""
    smoothness: float = bounded(0.01, ge=0)
    """Weight of the texture's smoothness term, relative to the data's mean squared value (module docstring)."""


RECIPE = Recipe(steps=300, batch_size=256, lr=0.05, schedule="halves", loss="l2", log_every=20,
                options=config_to_dict(Options()))

#: RECIPE already fits the CPU budget (module docstring)
CPU_RECIPE = RECIPE


def observed_quadrature(ctx: FitContext) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """cfg.samples observed points (drawn with the fit's generator), their normals and areas (module docstring)."""
    obs, k = ctx.source, ctx.model.cfg.samples
    if len(obs) < max(k, 4):
        raise InputError(f"dipole-bssrdf: {len(obs)} observations cannot give a surface quadrature of {k} points "
                         "(Config.samples); set it from the object with DipoleBSSRDF.set_surface")
    pick = torch.randperm(len(obs), generator=ctx.generator, device=ctx.generator.device)[:k].cpu()
    area = ConvexHull(obs.x.double().cpu().numpy()).area
    return obs.x[pick], obs.n[pick], torch.full((k,), area / k, dtype=obs.x.dtype)


def phases(ctx: FitContext) -> list[Phase]:
    model = ctx.model
    train, validation = split_observations(ctx)
    if not ctx.resuming and not bool(model.areas.sum() > 0):
        model.set_surface(*(t.to(model.areas.device) for t in observed_quadrature(ctx)))
    (steps,) = ctx.split(("fit",))
    params, penalty = [model.log_sigma_a, model.log_sigma_s], None
    if model.textured:
        set_bounds_from(ctx)
        scale = ctx.opts.smoothness * float((train.value ** 2).mean())
        params.append(model.texture)

        def penalty() -> dict[str, torch.Tensor]:
            return {"smoothness": scale * model.smoothness()}
    return [observation_phase(ctx, "fit", steps, dipole_predict(model), params, train, validation, penalty)]
