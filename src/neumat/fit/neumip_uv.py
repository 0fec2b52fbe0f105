"""The NeuMIP-on-UV baseline (`neumat.models.neumip_uv`, also `surface-brdf-uv`) as a function of observations:
what its recipe (`neumat.fit.recipes.neumip_uv`) fits by L2 on the latent texture and the MLP, with the same
loss, batches and early stopping as NeuPreSS, through `neumat.fit.trainer.fit`."""
from __future__ import annotations

from ..models.neumip_uv import NeuMIPUV


def neumip_uv_predict(model: NeuMIPUV):
    """The unclamped model as a function of observations (what its recipe fits)."""
    return lambda o: model.raw(o.wi, o.x, o.wo, o.n)
