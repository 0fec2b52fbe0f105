"""Dr.Jit runtime translator of the multi-scale models (the gated model, tripleplane and the other configurations
of `MultiScale`): the "latent-mlp" program of `neumat.export.drjit.latent`.

`translate(model) -> (manifest, arrays)`: the preconditioned spatial pyramid (the levels the forward pass reads),
the two angular textures, the shading-frame decoder (its weight scale folded in), the radial warps (decoded from
z_s or constant) and the SiLU MLP."""
from __future__ import annotations

import numpy as np
import torch

from neumat.core.errors import InputError
from neumat.methods.latent_mlp.multiscale import MultiScale
from neumat.methods.latent_mlp.spatial_latent import SpatialLatent


def _np(t: torch.Tensor) -> np.ndarray:
    return t.detach().cpu().float().numpy()


@torch.no_grad()
def translate(model: MultiScale) -> tuple[dict, dict]:
    """(manifest, arrays) of a MultiScale model; InputError for a subclass that changes how it reads."""
    if not isinstance(model, MultiScale):
        raise InputError(f"multiscale drjit translator: expected a multi-scale model, got {type(model).__name__}")
    if type(model).latents is not MultiScale.latents or type(model).latent_uv is not SpatialLatent.latent_uv:
        raise InputError(f"export_drjit: {model.name} reads its latents its own way; no Dr.Jit runtime for it yet")
    c = model.cfg
    spatial = model.spatial is not None
    arrays = {"half_texture": _np(model.half_texture.texture()), "diff_texture": _np(model.diff_texture.texture())}
    if spatial:
        flat, start = model.spatial.flat(), 0  # the forward pass's preconditioned levels, all at once
        for i, raw in enumerate(model.spatial.raw):
            h, w = raw.shape[1:]
            arrays[f"level{i}"] = _np(flat[:, start:start + h * w].reshape(-1, h, w))
            start += h * w
    if model.frame is not None:
        if model.frame.frames != 1:
            raise InputError("export_drjit: multiscale with several shading frames has no Dr.Jit runtime yet")
        arrays["frame_weight"] = _np(model.frame.decode.weight * model.frame.weight_scale)
        arrays["frame_bias"] = _np(model.frame.decode.bias)
    for tag, warp in (("h", model.warp_h), ("d", model.warp_d)):
        if warp is None:
            continue
        if warp.latent_dim > 0:
            arrays[f"warp_{tag}_weight"] = _np(warp.decode.weight)
            arrays[f"warp_{tag}_bias"] = _np(warp.decode.bias)
        else:
            arrays[f"warp_{tag}_params"] = _np(warp.params)
    for i, layer in enumerate(model.mlp.linears()):
        arrays[f"layer{i}_weight"] = _np(layer.weight)
        arrays[f"layer{i}_bias"] = _np(layer.bias)
    manifest = {"program": "latent-mlp", "spatial": spatial, "gating": bool(c.gating and spatial),
                "frame": model.frame is not None, "warps": model.warp_h is not None,
                "channels": [c.spatial_channels, c.half_channels, c.diff_channels], "warp_terms": c.warp_terms,
                "max_probes": c.max_probes, "activation": "silu", "output": "exp",
                "describe": f"{model.name} ({'gated' if c.gating and spatial else 'concatenated'}, "
                            f"{'spatial ' + str(c.spatial_size) + '^2 x ' + str(c.spatial_channels) if spatial else 'homogeneous'}, "
                            f"MLP {c.hidden}x{c.hidden_layers})"}
    return manifest, arrays
