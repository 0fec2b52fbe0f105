"""NeuBRDF's Dr.Jit runtime translator: the runtime form (`NeuBRDF.runtime`) as the "healpix-mlp" program of
`neumat.export.drjit.runtime` (what Mitsuba's `neumat` BSDF evaluates natively).

`translate(model) -> (manifest, arrays)`: the decoded feature rows (a VQ grid's codebook; a dense or low-bit grid's
decoded slots), for every ring pixel of S+ (by wi's pixel) and S- (by the pixel of the unmirrored wo, the mirror
folded in) the rows of its 4 (ancestor) corners, and the MLP's layers; the runtime averages the corners and
multiplies by the first layer at load, the table `NeuBRDF.runtime` caches. Uniform corner weights only (the
default `Config.runtime_interpolation`); a neural texture has no Dr.Jit form yet.
"""
from __future__ import annotations

import copy

import numpy as np
import torch

from neumat.core.errors import InputError
from neumat.methods.neubrdf.model import NeuBRDF
from neumat.nn import healpix as hpx
from neumat.nn.codebook import VQFeatures


def _np(t: torch.Tensor) -> np.ndarray:
    return t.detach().cpu().float().numpy() if t.is_floating_point() else t.detach().cpu().numpy()


@torch.no_grad()
def translate(model: NeuBRDF) -> tuple[dict, dict]:
    """(manifest, arrays) of `model`'s runtime form (a model not in runtime form is translated from a runtime copy:
    floats rounded to fp16, as `neumat fit` ships it); InputError for what the runtime program does not cover."""
    if not isinstance(model, NeuBRDF):
        raise InputError(f"NeuBRDF drjit translator: expected a NeuBRDF, got {type(model).__name__}")
    if model.texture is not None:
        raise InputError("export_drjit: NeuBRDF with a neural texture (texture_channels > 0) has no Dr.Jit runtime "
                         "yet; export it as GLSL or render it through the torch bridge")
    if not model.is_runtime:
        model = copy.deepcopy(model).runtime()
    cfg = model.cfg
    if cfg.interpolation != "uniform":
        raise InputError("export_drjit: NeuBRDF with runtime_interpolation='idw' has no Dr.Jit runtime yet "
                         "(uniform corner weights only)")
    if cfg.activation not in ("relu", "leaky_relu", "tanh"):
        raise InputError(f"export_drjit: NeuBRDF activation {cfg.activation!r} has no Dr.Jit form "
                         "(relu, leaky_relu, tanh)")
    n, k = cfg.nside, cfg.feature_dim
    device = model.level_i.device
    pix = torch.arange(12 * n * n, device=device)
    if isinstance(model.grid, VQFeatures):
        features, slot_rows = model.grid.codebook, model.grid.indices().long()
    else:
        slot_rows = torch.arange(model.grid.num_vertices, device=device)
        features = model.grid(slot_rows)
    rows = []
    for south in (False, True):  # as NeuBRDF.runtime builds its per-pixel features
        level = 0 if model._pruning is None else model._pruning[int(south)]
        vid = hpx.ancestor_corner_vertices(n, pix, level)
        ok = (vid >= hpx.nvertices(n) - hpx.hemisphere_size(n)) if south else (vid < hpx.hemisphere_size(n))
        slots = (vid + hpx.south_grid_offset(n) if south else vid).clamp(0, 2 * hpx.hemisphere_size(n) - 1)
        rows.append(torch.where(ok.all(-1, keepdim=True), slot_rows.to(device)[slots], -1))
    rows[1] = rows[1][hpx.mirror_pixels(n).to(device)]  # S- by the pixel of the unmirrored wo
    linears = model.mlp.linears()
    arrays = {"features": _np(features), "first_weight": _np(linears[0].weight), "first_bias": _np(linears[0].bias),
              "pixel_rows": _np(torch.stack(rows)).astype(np.int16 if len(features) < 2 ** 15 else np.int32)}
    for i, layer in enumerate(linears[1:], 1):
        arrays[f"layer{i}_weight"] = _np(layer.weight)
        arrays[f"layer{i}_bias"] = _np(layer.bias)
    manifest = {"program": "healpix-mlp", "nside": n, "feature_dim": k, "hidden": cfg.hidden,
                "activation": cfg.activation, "direction_inputs": cfg.direction_inputs, "output": "exp",
                "pruned": model.pruned,
                "describe": f"neubrdf (N_side {n}, {cfg.features} features, {cfg.hidden}x{cfg.hidden_layers} MLP, "
                            f"direction inputs {cfg.direction_inputs})"}
    return manifest, arrays
