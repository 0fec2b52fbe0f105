"""Training recipe of the neumip-offset baseline (NeuMIP with its neural offset module): the gated model's recipe
(Timonen et al. 2025 train every model with the same data, loss and optimiser), its CPU-sized recipe and its
latent size that follows the source."""
from neumat.fit.recipes.multiscale import (CPU_RECIPE, RECIPE, Options, config_for_source,  # noqa: F401
                                         phases)
