"""Training recipe of the surface-BRDF-on-UV baseline (`surface-brdf-uv`, the stand-in for NeuPreSS's NeRFactor
row): the NeuMIP-UV recipe (the same network, data, loss and budget), whose CPU recipe is RECIPE itself."""
from neumat.fit.recipes.neumip_uv import CPU_RECIPE, RECIPE, Options, phases  # noqa: F401
