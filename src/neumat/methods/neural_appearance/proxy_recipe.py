"""Training recipe of the neural importance sampler attached to a material (`SampledMaterial`, model name
"proxy-sampler"; not a registered model: it wraps a material the caller brings). One phase, "sampler": every
step draws `batch_size` queries (wi uniform over the upper hemisphere, uv uniform, u for the proxy's directions)
and takes an Adam step on the sampler's parameters alone against
`neumat.methods.neural_appearance.proxy_train.proxy_kl_loss` (Zeltner et al. 2024, Sec. 5.2); the learning rate halves
at 50 % and 75 % of the steps. Call it through `neumat.methods.neural_appearance.proxy_train.fit_sampler(material)` or
`neumat.fit.trainer.fit(SampledMaterial(material, sampler), material)`.

CPU_RECIPE: RECIPE itself: 2000 steps of 4096 sampler queries, sized for a CPU already (its time follows the
material's evaluation).
"""
from __future__ import annotations

from dataclasses import dataclass

import torch

from neumat.core.errors import InputError
from neumat.core.material import describe_source
from neumat.core.query import Query
from neumat.fit.phase import FitContext, Phase
from neumat.methods.neural_appearance.proxy_train import proxy_kl_loss
from neumat.fit.recipe import Recipe
from neumat.methods.neural_appearance.proxy_sampler import SampledMaterial, features_of
from neumat.warp.hemisphere import sample_uniform_hemisphere


@dataclass
class Options:
    """The proxy sampler's recipe has no options (any given is refused by name)."""


RECIPE = Recipe(steps=2000, batch_size=4096, lr=3e-3, schedule="halves", log_every=100)

#: RECIPE itself (module docstring)
CPU_RECIPE = RECIPE


def phases(ctx: FitContext) -> list[Phase]:
    model, dev, gen, batch = ctx.model, ctx.device, ctx.generator, ctx.recipe.batch_size
    if not isinstance(model, SampledMaterial):
        raise InputError(f"proxy-sampler fit: expected a SampledMaterial, got {type(model).__name__}")
    material = model.material
    if ctx.source is not material:
        raise InputError("proxy-sampler fit: the source must be the material the sampler is attached to "
                         "(fit(SampledMaterial(material, sampler), material))")
    features = model.sampler.cfg.features
    who = describe_source(material)

    def losses(step: int) -> dict[str, torch.Tensor]:
        u = torch.rand(batch, 6, generator=gen, device=gen.device).to(dev)
        wi = sample_uniform_hemisphere(u[:, :2])
        q = Query(wi, uv=u[:, 4:] if features else None)
        lobes = model.sampler.lobes(wi, features_of(material, q))
        return {"loss": proxy_kl_loss(lobes, wi, u[:, 2:4], lambda wo: material.eval(q.with_wo(wo)), who)}

    return [Phase("sampler", ctx.recipe.steps, losses, [p for p in model.sampler.parameters() if p.requires_grad])]
