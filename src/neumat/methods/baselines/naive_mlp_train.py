"""Training recipe of the naive MLP baseline (no paper: NeuBRDF-like online fit, NBRDF's loss).

CPU_RECIPE: half the steps (10k of 8192, the cosine decay over them): a step takes 0.035 - 0.06 CPU seconds
(benchmarks/studies/neubrdf/results/cpu_recipes.md), so the 20k steps of RECIPE take 12 - 21 minutes on one core,
10k 6 - 10.
"""
from neumat.fit.recipe import Recipe

#: Adam 1e-3 with a cosine decay over 20k steps of 8192 cosine-weighted queries, log(1 + f cos) L1 loss.
RECIPE = Recipe(steps=20_000, batch_size=8192, lr=1e-3, schedule="cosine", lr_min=1e-5,
                loss="log_cos", queries="cosine")

#: RECIPE at half the steps (module docstring)
CPU_RECIPE = Recipe(steps=10_000, batch_size=8192, lr=1e-3, schedule="cosine", lr_min=1e-5,
                    loss="log_cos", queries="cosine")
