"""Training recipe of NBRDF (Sztrajman et al. 2021), from the authors' PyTorch code.

Their script draws 800k Rusinkiewicz configurations uniform in (theta_h, theta_d, phi_d), trains on 80 %
(640k) for 100 epochs in batches of 512 with Adam (lr 5e-4, betas (0.9, 0.999), eps 1e-15) on
mean |log(1 + f cos_i) - log(1 + f_hat cos_i)|. Mapped to online steps: 640k / 512 = 1250 steps per epoch,
x 100 epochs = 125k steps of 512 fresh Rusinkiewicz queries (the same distribution, not a fixed set).

CPU_RECIPE: the same 6.4e7 queries in 8x larger batches, 15625 steps of 4096:
a step of 512 costs about as much as one of 4096 on a CPU (0.04 CPU s, mostly per-step overhead: the
source's evaluation and the optimiser; benchmarks/studies/neubrdf/results/cpu_recipes.md), so RECIPE takes about 90 minutes
on one core and this about 5 (0.017 CPU s per step of 4096). Adam's step size does not grow with the batch, so the learning rate stays.
"""
from neumat.fit.recipe import Recipe

RECIPE = Recipe(steps=125_000, batch_size=512, lr=5e-4, betas=(0.9, 0.999), eps=1e-15,
                loss="log_cos", queries="rusinkiewicz")

#: RECIPE's queries in batches of 4096 (module docstring)
CPU_RECIPE = Recipe(steps=15_625, batch_size=4096, lr=5e-4, betas=(0.9, 0.999), eps=1e-15,
                    loss="log_cos", queries="rusinkiewicz")
