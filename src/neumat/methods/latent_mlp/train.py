"""Training recipe of the multi-scale gated model (Timonen et al. 2025, Sec. 4.2, 4.4, 4.5), and its loss.

Details (schedule, options, measurements): src/neumat/methods/latent_mlp/NOTES.md,
section `neumat.methods.latent_mlp.train`.
"""
from __future__ import annotations

from dataclasses import replace

from neumat.core.config import config_to_dict
from neumat.fit.footprint_queries import FootprintOptions, with_target_samples
from neumat.fit.phase import FitContext, Phase, online_phase
from neumat.fit.query_samplers import QUERY_SAMPLERS
from neumat.fit.recipe import Recipe, latent_size_for_source

#: the recipe options: the footprint distribution's
Options = FootprintOptions

RECIPE = Recipe(steps=500_000, batch_size=1 << 16, lr=3e-3, betas=(0.99, 0.999), eps=1e-15, lr_decay=0.9,
                lr_decay_every=10_000, ema=0.005, loss="relative_l2_mix", queries="footprint",
                options=config_to_dict(Options()))

#: RECIPE's first 1000 steps at 2^12 queries on the source's targets (the recommended preset trains longer on cheaper
#: targets: `LONG_RUN` in __init__.py)
CPU_RECIPE = Recipe(steps=1000, batch_size=1 << 12, lr=3e-3, betas=(0.99, 0.999), eps=1e-15, lr_decay=0.9,
                    lr_decay_every=10_000, ema=0.005, loss="relative_l2_mix", queries="footprint", checkpoint_every=200,
                    options=config_to_dict(Options()))

HOMOGENEOUS_RECIPE = Recipe(steps=100_000, batch_size=1 << 18, lr=3e-3, betas=(0.99, 0.999), eps=1e-15,
                            lr_decay=0.9, lr_decay_every=10_000, ema=0.005, loss="relative_l2_mix",
                            queries="cosine", options=config_to_dict(Options()))


def phases(ctx: FitContext) -> list[Phase]:
    """One online phase; the "footprint" and "footprint-uv" samplers draw with the options fine_bias and
    elongation_std; targets are filtered with the option target_samples."""
    o = ctx.opts
    ctx = replace(ctx, source=with_target_samples(ctx.source, o.target_samples))
    name = ctx.queries if ctx.queries is not None else ctx.recipe.queries
    if name in ("footprint", "footprint-uv"):
        draw = QUERY_SAMPLERS.get(name)(ctx.source, ctx.model, fine_bias=o.fine_bias, elongation_std=o.elongation_std)
        ctx = replace(ctx, queries=draw)
    return [online_phase(ctx)]


def config_for_source(source, options: dict | None = None) -> dict:
    """Config fields that follow the source, for the gated model and the baselines that share this recipe:
    spatial_size = the texture resolution (`latent_size_for_source`: the paper's 1024 for its 1K texture sets,
    32 for a 64 x 38 set, not a 1024^2 pyramid); {} for a source without textures. `--set spatial_size=N`
    overrides it."""
    size = latent_size_for_source(source)
    return {} if size is None else {"spatial_size": size}
