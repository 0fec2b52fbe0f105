"""Training recipe of the multi-scale gated model (Timonen et al. 2025, Sec. 4.2, 4.4, 4.5), and its loss.

Adam (beta1 0.99, beta2 0.999, eps 1e-15), learning rate 3e-3 multiplied by 0.9 every 10k steps, EMA with
weight 0.005, batches of 2^16 queries from the Sec. 4.2 distribution ("footprint": cosine-weighted
directions, uniform uv, Eq. 9 footprints) and the Eq. 10 loss. The paper trains SVBRDFs for about 500k steps
(4-5 h on a V100) and homogeneous BRDFs for about 100k steps with batches of 2^18 and cosine-weighted
queries (`HOMOGENEOUS_RECIPE`).

Loss (Eq. 10), per query over the RGB vector, averaged over the batch:

    L = lambda |f - f_hat|^2 / |sg(f_hat) + eps|^2 + (1 - lambda) |f - f_hat|^2,   lambda = 0.9999, eps = 1e-6

registered as "relative_l2_mix" in `neumat.fit.losses` (`LOSSES`).

CPU_RECIPE (the gated model and every baseline sharing this recipe): RECIPE is 4-5 GPU hours; on a CPU a
step of 2^16 footprint queries takes seconds (each target filters the texture set over its footprint), so
the CPU recipe takes 2^12 queries per step for 1000 steps, about 10 minutes on one core for a 1K texture set (0.59 - 0.65 CPU s per step)
(benchmarks/studies/neubrdf/results/cpu_recipes.md); on a 64^2 crop with `--source-option samples=8` about 2 minutes. Otherwise it
is RECIPE: the same optimiser, EMA weight and schedule, i.e. the paper's first 1000 steps, whose learning rate is
still constant (its first decay is at 10k steps). An earlier CPU recipe compressed the paper's 50 decays into the
1000 steps (x 0.9 every 20, to 1.5e-5 at the end): on a 64^2 Plaster001 crop both models ended far worse (mean
FLIP over 9 scales 0.159 / 0.148 gated / tripleplane against 0.112 / 0.123 at the constant rate) and the gated
model, which needs more steps at full rate, fell behind tripleplane (benchmarks/studies/multiscale/results/multiscale_protocol.md, CLI
section). Expect a rough fit: the paper's quality needs RECIPE on a GPU. The latent resolution follows the source
(`config_for_source`). `Options`: the footprint distribution's fine_bias and elongation_std (the paper's values).
"""
from __future__ import annotations

from dataclasses import replace

from neumat.core.config import config_to_dict
from neumat.fit.footprint_queries import FootprintOptions
from neumat.fit.phase import FitContext, Phase, online_phase
from neumat.fit.query_samplers import QUERY_SAMPLERS
from neumat.fit.recipe import Recipe, latent_size_for_source

#: the recipe options: the footprint distribution's
Options = FootprintOptions

RECIPE = Recipe(steps=500_000, batch_size=1 << 16, lr=3e-3, betas=(0.99, 0.999), eps=1e-15, lr_decay=0.9,
                lr_decay_every=10_000, ema=0.005, loss="relative_l2_mix", queries="footprint",
                options=config_to_dict(Options()))

#: RECIPE's first 1000 steps at 2^12 queries: about 10 minutes on one CPU core for a 1K set (module docstring)
CPU_RECIPE = Recipe(steps=1000, batch_size=1 << 12, lr=3e-3, betas=(0.99, 0.999), eps=1e-15, lr_decay=0.9,
                    lr_decay_every=10_000, ema=0.005, loss="relative_l2_mix", queries="footprint", checkpoint_every=200,
                    options=config_to_dict(Options()))

HOMOGENEOUS_RECIPE = Recipe(steps=100_000, batch_size=1 << 18, lr=3e-3, betas=(0.99, 0.999), eps=1e-15,
                            lr_decay=0.9, lr_decay_every=10_000, ema=0.005, loss="relative_l2_mix",
                            queries="cosine", options=config_to_dict(Options()))


def phases(ctx: FitContext) -> list[Phase]:
    """One online phase; the "footprint" and "footprint-uv" samplers draw with the options fine_bias and
    elongation_std."""
    name = ctx.queries if ctx.queries is not None else ctx.recipe.queries
    if name in ("footprint", "footprint-uv"):
        o = ctx.opts
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
