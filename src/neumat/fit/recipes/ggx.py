"""Training recipe of the GGX baseline: a few thousand Adam steps on the 7 (or 8) parameters.

Rusinkiewicz queries (uniform in theta_h) put enough samples near the specular peak to fit sharp lobes;
log(1 + f cos) L1 loss as the neural models, so that all baselines minimise the same objective.

CPU_RECIPE: the same recipe: 2000 steps of 2^14 take about 2.5 minutes on one CPU core
(benchmarks/results/cpu_recipes.md), within the 10-minute CPU budget.
"""
from neumat.fit.recipe import Recipe

RECIPE = Recipe(steps=2000, batch_size=16384, lr=2e-2, schedule="cosine", lr_min=1e-3,
                loss="log_cos", queries="rusinkiewicz")

#: the paper-size recipe already fits the CPU budget (module docstring)
CPU_RECIPE = RECIPE
CPU_MINUTES = 2.5
