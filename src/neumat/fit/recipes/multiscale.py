"""Training recipe of the multi-scale gated model (Timonen et al. 2025, Sec. 4.2, 4.4, 4.5), and its loss.

Adam (beta1 0.99, beta2 0.999, eps 1e-15), learning rate 3e-3 multiplied by 0.9 every 10k steps, EMA with
weight 0.005, batches of 2^16 queries from the Sec. 4.2 distribution ("footprint": cosine-weighted
directions, uniform uv, Eq. 9 footprints) and the Eq. 10 loss. The paper trains SVBRDFs for about 500k steps
(4-5 h on a V100) and homogeneous BRDFs for about 100k steps with batches of 2^18 and cosine-weighted
queries (`HOMOGENEOUS_RECIPE`).

Loss (Eq. 10), per query over the RGB vector, averaged over the batch:

    L = lambda |f - f_hat|^2 / |sg(f_hat) + eps|^2 + (1 - lambda) |f - f_hat|^2,   lambda = 0.9999, eps = 1e-6

registered as "relative_l2_mix" in `neumat.fit.losses` (`LOSSES`).
"""
from __future__ import annotations

import neumat.fit.footprint_queries  # noqa: F401  (registers the "footprint" query sampler)
from neumat.fit.recipe import Recipe

RECIPE = Recipe(steps=500_000, batch_size=1 << 16, lr=3e-3, betas=(0.99, 0.999), eps=1e-15, lr_decay=0.9,
                lr_decay_every=10_000, ema=0.005, loss="relative_l2_mix", queries="footprint")

HOMOGENEOUS_RECIPE = Recipe(steps=100_000, batch_size=1 << 18, lr=3e-3, betas=(0.99, 0.999), eps=1e-15,
                            lr_decay=0.9, lr_decay_every=10_000, ema=0.005, loss="relative_l2_mix",
                            queries="cosine")
