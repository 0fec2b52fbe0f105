"""Training recipe of the neumip-frame baseline: the gated model's recipe (Timonen et al. 2025 train every
model with the same data, loss and optimiser), its CPU-sized recipe, options and phases and its latent size
that follows the source."""
from neumat.fit.recipes.multiscale import (CPU_RECIPE, RECIPE, Options, config_for_source,  # noqa: F401
                                         phases)
