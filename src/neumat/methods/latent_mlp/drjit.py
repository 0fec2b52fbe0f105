"""Dr.Jit runtime translators of the latent-texture family: the multi-scale models (the gated model, tripleplane and
the other configurations of `MultiScale`; `translate`: the "latent-mlp" program of `neumat.export.drjit.latent`),
the NeuMIP configurations (neumip, neumip-offset, neumip-frame, nbrdf-uv; `translate_neumip`: program "neumip") and
the GGX mip-map (`translate_ggx_mipmap`: program "ggx-mipmap"), both in `neumat.export.drjit.neumip`.

`translate(model) -> (manifest, arrays)`: the preconditioned spatial pyramid (the levels the forward pass reads),
the two angular textures, the shading-frame decoder (its weight scale folded in), the radial warps (decoded from
z_s or constant) and the SiLU MLP."""
from __future__ import annotations

import numpy as np
import torch

from neumat.core.errors import InputError
from neumat.methods.latent_mlp.ggx_mipmap import GGXMipmap
from neumat.methods.latent_mlp.multiscale import MultiScale
from neumat.methods.latent_mlp.neumip import NeuMIP
from neumat.methods.latent_mlp.spatial_latent import SpatialLatent


def _np(t: torch.Tensor) -> np.ndarray:
    return t.detach().cpu().float().numpy()


def _levels(pyramid, prefix: str = "level") -> dict:
    """{prefix}{l}: the forward pass's preconditioned levels (C, H_l, W_l) of a `LatentPyramid`, all at once."""
    out, flat, start = {}, pyramid.flat(), 0
    for i, raw in enumerate(pyramid.raw):
        h, w = raw.shape[1:]
        out[f"{prefix}{i}"] = _np(flat[:, start:start + h * w].reshape(-1, h, w))
        start += h * w
    return out


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
        arrays.update(_levels(model.spatial))
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
    latents = f"spatial {c.spatial_size}^2 x {c.spatial_channels}" if spatial else "homogeneous"
    manifest = {"program": "latent-mlp", "spatial": spatial, "gating": bool(c.gating and spatial),
                "frame": model.frame is not None, "warps": model.warp_h is not None,
                "channels": [c.spatial_channels, c.half_channels, c.diff_channels], "warp_terms": c.warp_terms,
                "max_probes": c.max_probes, "activation": "silu", "output": "exp",
                "output_bound": model.output_bound_values(),
                "describe": f"{model.name} ({'gated' if c.gating and spatial else 'concatenated'}, {latents}, "
                            f"MLP {c.hidden}x{c.hidden_layers})"}
    return manifest, arrays


@torch.no_grad()
def translate_neumip(model: NeuMIP) -> tuple[dict, dict]:
    """(manifest, arrays) of a NeuMIP configuration (program "neumip"); InputError for a subclass that reads or
    decodes differently. neural-appearance's BRDF decoder is one (2 frames; its albedo outputs are left out): its
    own translator (`neumat.methods.neural_appearance.drjit.translate`) adds the learned sampler to this (program
    "neural-appearance"); "model_samples" records whether the model has a learned sampler."""
    if not isinstance(model, NeuMIP):
        raise InputError(f"neumip drjit translator: expected a NeuMIP model, got {type(model).__name__}")
    cls = type(model)
    if any(getattr(cls, m) is not getattr(NeuMIP, m) for m in
           ("decode_outputs", "filtered_outputs", "spatial_latent", "latent_uv", "offset_uv", "eval")) \
            or cls.read_latent is not SpatialLatent.read_latent:
        raise InputError(f"export_drjit: {model.name} reads its latents its own way; no Dr.Jit runtime for it yet")
    c = model.cfg
    arrays = _levels(model.spatial)
    frames = c.frames if model.frame is not None else 0
    if frames:
        arrays["frame_weight"] = _np(model.frame.decode.weight * model.frame.weight_scale)
        arrays["frame_bias"] = _np(model.frame.decode.bias)
    linears = model.mlp.linears()
    for i, layer in enumerate(linears):
        last = i == len(linears) - 1  # only the 3 log f rows are read
        arrays[f"layer{i}_weight"] = _np(layer.weight[:3] if last else layer.weight)
        arrays[f"layer{i}_bias"] = _np(layer.bias[:3] if last else layer.bias)
    if model.offset_mlp is not None:
        arrays.update(_levels(model.offset_texture, "offset_level"))
        for i, layer in enumerate(model.offset_mlp.linears()):
            arrays[f"offset_layer{i}_weight"] = _np(layer.weight)
            arrays[f"offset_layer{i}_bias"] = _np(layer.bias)
    manifest = {"program": "neumip", "directions": c.directions, "frames": frames,
                "offset": model.offset_mlp is not None, "offset_min_cos": c.offset_min_cos,
                "spatial_size": c.spatial_size, "level_selection": c.level_selection, "max_probes": c.max_probes,
                "activation": "silu", "model_samples": bool(getattr(model, "can_sample", False)),
                "describe": f"{model.name} (spatial {c.spatial_size}^2 x {c.spatial_channels}, {c.directions}"
                            f"{f', {frames} frame(s)' if frames else ''}{', offset' if c.offset else ''}, "
                            f"MLP {c.hidden}x{c.hidden_layers})"}
    return manifest, arrays


@torch.no_grad()
def translate_ggx_mipmap(model: GGXMipmap) -> tuple[dict, dict]:
    """(manifest, arrays) of a GGX mip-map (program "ggx-mipmap")."""
    if not isinstance(model, GGXMipmap) or type(model).eval is not GGXMipmap.eval \
            or type(model).parameters_at is not GGXMipmap.parameters_at:
        raise InputError(f"ggx-mipmap drjit translator: expected a GGX mip-map, got {type(model).__name__}")
    c = model.cfg
    return ({"program": "ggx-mipmap", "max_probes": c.max_probes,
             "describe": f"ggx-mipmap (12 parameters, {c.spatial_size}^2)"}, _levels(model.spatial))
