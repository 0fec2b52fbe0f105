"""The NeuMIP-on-UV baseline (`neumat.methods.baselines.neumip_uv`, also `surface-brdf-uv`) as a function of
observations: what its recipe (`neumat.methods.baselines.neumip_uv_train`) fits by L2 on the latent texture and the MLP,
with the same loss, batches and early stopping as NeuPreSS, through `neumat.fit.trainer.fit`."""
from __future__ import annotations

from neumat.methods.baselines.neumip_uv import NeuMIPUV


def neumip_uv_predict(model: NeuMIPUV):
    """The unclamped model as a function of observations (what its recipe fits)."""
    return lambda o: model.raw(o.wi, o.x, o.wo, o.n)
