"""Fitting the NeuMIP-on-UV baseline (`neumat.models.neumip_uv`) to path-traced observations: L2 on the latent
texture and the MLP, the same loss, batches and early stopping as NeuPreSS (`neumat.fit.neupress`)."""
from __future__ import annotations

import torch

from ..models.neumip_uv import NeuMIPUV
from .translucent_fit import fit_observations
from .translucent_observations import Observations


def fit_neumip_uv(model: NeuMIPUV, observations: Observations, steps: int = 4000, batch: int = 4096,
                  lr: float = 1e-3, bounds: tuple[torch.Tensor, torch.Tensor] | None = None, seed: int = 0,
                  progress: bool = False, log_every: int = 100,
                  validation: Observations | None = None) -> list[dict]:
    """Adam (lr halved at 50% / 75%) on every parameter; `bounds` (lo, hi) is the object's bounding box (default:
    that of the observed points), whose centre is the UV projection's; `validation` as in `fit_observations`."""
    lo, hi = bounds if bounds is not None else (observations.x.min(0).values, observations.x.max(0).values)
    model.set_bounds(lo, hi)
    return fit_observations(neumip_uv_predict(model), list(model.parameters()), observations, steps, batch, lr, seed,
                            progress, log_every, validation, "NeuMIP-UV")


def neumip_uv_predict(model: NeuMIPUV):
    """The unclamped model as a function of observations (what `fit_neumip_uv` fits)."""
    return lambda o: model.raw(o.wi, o.x, o.wo, o.n)
