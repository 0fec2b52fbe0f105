"""Training of the neural importance sampler (`neumat.methods.neural_appearance.proxy_sampler.ProxySampler`, Zeltner
et al. 2024, Sec. 4.3, 5.2) on any BRDF, through the one trainer.

The pair (material, sampler) is a `SampledMaterial`, a `LearnedMaterial` named "proxy-sampler" whose recipe
(`neumat.methods.neural_appearance.proxy_recipe`) has one phase: directions drawn from the sampler's current proxy are
scored against the material's f cos(theta_o) with the KL divergence KL(f cos / a || p), through its score-function
gradient -E_p[(f cos / p) grad log p] (Mueller et al. 2019); f is the luminance of the material's value, wi
uniform over the upper hemisphere and uv uniform over the texture. One sample per query, so the per-query
normaliser a(wi, uv) is replaced by the batch mean of f cos / p: queries with a higher albedo weigh more. The
material is the fixed target; only the sampler's parameters train.

- `proxy_kl_loss(lobes, wi, u, brdf, who)`: that loss (also the sampler's loss in neural-appearance training).
- `fit_sampler(material, sampler=None, ...)`: `neumat.fit.trainer.fit(SampledMaterial(material, sampler), ...)`
  with the recipe's defaults, returning the trained sampler.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import torch

from neumat.core.checks import check_int
from neumat.core.errors import InputError
from neumat.core.material import Material
from neumat.color.tonemap import LUMINANCE
from neumat.methods.neural_appearance.proxy_sampler import ProxySampler, SampledMaterial, feature_dim
from neumat.warp.microfacet_proxy import ProxyLobes, proxy_pdf, sample_proxy


@dataclass
class SamplerFit:
    """sampler: the trained sampler (eval mode); history: the trainer's records ({"step", "phase", "loss",
    "loss_median", "lr", "seconds"} every recipe.log_every steps); seconds: training time."""

    sampler: ProxySampler
    history: list[dict]
    seconds: float


def proxy_kl_loss(lobes: ProxyLobes, wi: torch.Tensor, u: torch.Tensor, brdf, who: str) -> torch.Tensor:
    """KL(f cos / a || p) through its score-function gradient (module docstring): wo (N, 3) drawn from the
    detached `lobes` with u (N, 2), scored against brdf(wo) -> (N, 3), evaluated without gradient."""
    with torch.no_grad():
        wo = sample_proxy(ProxyLobes(*(t.detach() for t in lobes)), wi, u, check=False)
        wo = wo / wo.norm(dim=-1, keepdim=True)
        target = (brdf(wo).float() @ torch.tensor(LUMINANCE, device=wo.device)).clamp(min=0) * wo[:, 2].clamp(min=0)
        if not bool(torch.isfinite(target).all()):
            raise InputError(f"proxy sampler fit: {who} returned non-finite values")
    pdf = proxy_pdf(lobes, wi, wo, check=False)
    ratio = target / pdf.detach().clamp(min=1e-12)
    return -(ratio * pdf.clamp(min=1e-12).log()).mean() / ratio.mean().clamp(min=1e-12)


def fit_sampler(material: Material, sampler: ProxySampler | None = None, *, steps: int | None = None,
                batch: int | None = None, lr: float | None = None, seed: int | None = None,
                progress: bool = True, device: str | torch.device | None = None,
                checkpoint: str | Path | None = None, resume: bool = False) -> SamplerFit:
    """Train `sampler` (default a new `ProxySampler` with the material's feature count, initialised from torch's
    global generator) on `material` through `neumat.fit.trainer.fit` (module docstring). steps / batch / lr /
    seed override the recipe `neumat.methods.neural_appearance.proxy_recipe.RECIPE` (None: its defaults); device,
    checkpoint and resume are the trainer's."""
    from neumat.fit.method import recipe_for
    from neumat.fit.trainer import fit

    features = feature_dim(material, "fit_sampler")
    recipe = recipe_for(SampledMaterial.name)
    if steps is not None:
        check_int(steps, "fit_sampler steps", 1)
        recipe.steps = steps
    if batch is not None:
        recipe.batch_size = batch
    if lr is not None:
        if not lr > 0:
            raise InputError(f"fit_sampler lr: expected > 0, got {lr!r}")
        recipe.lr = lr
    if seed is not None:
        recipe = replace(recipe, seed=seed)
    sampler = sampler if sampler is not None else ProxySampler(features=features)
    if sampler.cfg.features != features:
        raise InputError(f"fit_sampler: the sampler takes {sampler.cfg.features} features, "
                         f"{type(material).__name__} gives {features}")
    result = fit(SampledMaterial(material, sampler), material, recipe, device=device, progress=progress,
                 checkpoint=checkpoint, resume=resume)
    return SamplerFit(sampler, result.history, result.seconds)
