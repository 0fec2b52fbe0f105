"""Training recipe of the neumip-frame baseline: the gated model's recipe (Timonen et al. 2025 train every
model with the same data, loss and optimiser)."""
from neumat.fit.recipes.multiscale import RECIPE  # noqa: F401
