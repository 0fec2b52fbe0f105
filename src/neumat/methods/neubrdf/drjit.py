"""NeuBRDF's Dr.Jit runtime translators: the runtime form (`NeuBRDF.runtime`, `SharedNeuBRDF.runtime`) as a program
of `neumat.export.drjit` (what Mitsuba's `neumat` BSDF evaluates natively).

`translate(model) -> (manifest, arrays)`: a NeuBRDF with uniform corner weights (the default
`Config.runtime_interpolation`) and no neural texture as the "healpix-mlp" program (`neumat.export.drjit.runtime`):
the decoded feature rows (a VQ grid's codebook; a dense or low-bit grid's decoded slots), for every ring pixel of S+
(by wi's pixel) and S- (by the pixel of the unmirrored wo, the mirror folded in) the rows of its 4 (ancestor)
corners, and the MLP's layers; the runtime averages the corners and multiplies by the first layer at load, the table
`NeuBRDF.runtime` caches. Inverse-distance weights (`runtime_interpolation="idw"`) and a neural texture
(`texture_channels > 0`) as the "healpix-grid-mlp" program (`neumat.export.drjit.neubrdf`): the same rows with S-
by the pixel of the mirrored wo, the corners' vertex ids and directions, the texture's levels.

`translate_shared(model)`: a SharedNeuBRDF as "healpix-grid-mlp" with one set of pixel rows per material (one
codebook, one MLP), its configured corner weights, and the selected material (`SharedNeuBRDF.select`) as default.
"""
from __future__ import annotations

import copy

import numpy as np
import torch

from neumat.core.errors import InputError
from neumat.export.drjit.runtime import ACTIVATIONS
from neumat.methods.neubrdf.model import NeuBRDF, capped_levels
from neumat.methods.neubrdf.shared_model import SharedNeuBRDF
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
    if not model.is_runtime:
        model = copy.deepcopy(model).runtime()
    cfg = model.cfg
    _check_activation(cfg.activation)
    if cfg.interpolation != "uniform" or model.texture is not None:
        levels = None if model._pruning is None else [(model._pruning[0], model._pruning[1])]
        manifest, arrays = _grid_program(model, levels, 1, 0, cfg.interpolation)
        if model.texture is not None:
            manifest["texture_channels"] = cfg.texture_channels
            manifest["texture_levels"] = len(model.texture.levels)
            for i, level in enumerate(model.texture.levels):
                arrays[f"texture{i}"] = _np(level)
        manifest["pruned"] = model.pruned
        manifest["describe"] = (f"neubrdf (N_side {cfg.nside}, {cfg.features} features, {cfg.interpolation} corner "
                                f"weights, {cfg.hidden}x{cfg.hidden_layers} MLP, direction inputs "
                                f"{cfg.direction_inputs}" + (f", neural texture {cfg.texture_height}x"
                                f"{cfg.texture_width}x{cfg.texture_channels}" if model.texture is not None else "")
                                + ")")
        return manifest, arrays
    n, k = cfg.nside, cfg.feature_dim
    device = model.level_i.device
    pix = torch.arange(12 * n * n, device=device)
    features, slot_rows = _feature_rows(model.grid, device)
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


def _feature_rows(grid, device) -> tuple[torch.Tensor, torch.Tensor]:
    """(feature rows, each grid slot's row): a VQ grid's codebook and indices, else the decoded slots themselves."""
    if isinstance(grid, VQFeatures):
        return grid.codebook, grid.indices().long()
    slot_rows = torch.arange(grid.num_vertices, device=device)
    return grid(slot_rows), slot_rows


def _check_activation(activation: str) -> None:
    if activation not in ACTIVATIONS:
        raise InputError(f"export_drjit: NeuBRDF activation {activation!r} has no Dr.Jit form "
                         f"({', '.join(ACTIVATIONS)})")


def _grid_program(model, levels, materials: int, material: int, interpolation: str) -> tuple[dict, dict]:
    """(manifest, arrays) of "healpix-grid-mlp" for a NeuBRDF-like runtime model (`grid`, `mlp`, `cfg`,
    `vertex_dirs`) of `materials` index grids of 2 n slots each; levels: per material the (S+, S-) capped lookup
    levels (12 nside^2,) of a pruned grid, or None (unpruned)."""
    cfg = model.cfg
    n, k = cfg.nside, cfg.feature_dim
    device = model.vertex_dirs.device
    pix = torch.arange(12 * n * n, device=device)
    features, slot_rows = _feature_rows(model.grid, device)
    h = hpx.hemisphere_size(n)
    rows, vids = [], []
    for m in range(materials):
        for south in (False, True):
            level = 0 if levels is None else levels[m][int(south)]
            vid = hpx.ancestor_corner_vertices(n, pix, level)
            ok = (vid >= hpx.nvertices(n) - h) if south else (vid < h)
            slots = (vid + hpx.south_grid_offset(n) if south else vid).clamp(0, 2 * h - 1) + m * 2 * h
            rows.append(torch.where(ok.all(-1, keepdim=True), slot_rows.to(device)[slots], -1))
            vids.append(vid)
    shape = (materials, 2, 12 * n * n, 4)
    linears = model.mlp.linears()
    arrays = {"features": _np(features), "first_weight": _np(linears[0].weight), "first_bias": _np(linears[0].bias),
              "pixel_rows": _np(torch.stack(rows).view(shape)).astype(np.int16 if len(features) < 2 ** 15
                                                                         else np.int32)}
    if interpolation == "idw":
        arrays["pixel_vertices"] = _np(torch.stack(vids).view(shape)).astype(np.int32)
        arrays["vertex_dirs"] = _np(model.vertex_dirs)
    for i, layer in enumerate(linears[1:], 1):
        arrays[f"layer{i}_weight"] = _np(layer.weight)
        arrays[f"layer{i}_bias"] = _np(layer.bias)
    manifest = {"program": "healpix-grid-mlp", "nside": n, "feature_dim": k, "hidden": cfg.hidden,
                "activation": cfg.activation, "direction_inputs": cfg.direction_inputs, "output": "exp",
                "interpolation": interpolation, "materials": materials, "material": material,
                "texture_channels": 0}
    return manifest, arrays


@torch.no_grad()
def translate_shared(model: SharedNeuBRDF) -> tuple[dict, dict]:
    """(manifest, arrays) of a SharedNeuBRDF's runtime form (a model not in runtime form is translated from a runtime
    copy) as "healpix-grid-mlp": one codebook and MLP, t index grids, the selected material as default."""
    if not isinstance(model, SharedNeuBRDF):
        raise InputError(f"shared-NeuBRDF drjit translator: expected a SharedNeuBRDF, got {type(model).__name__}")
    if not model.is_runtime:
        active = model.active
        model = copy.deepcopy(model).runtime()
        model.active = active
    cfg = model.cfg
    _check_activation(cfg.activation)
    n = cfg.nside
    levels = None
    if model.pruned:
        levels = [(capped_levels(n, model.level_i[m], False), capped_levels(n, model.level_o[m], True))
                  for m in range(cfg.num_materials)]
    manifest, arrays = _grid_program(model, levels, cfg.num_materials, model.active, cfg.interpolation)
    manifest["pruned"] = model.pruned
    manifest["describe"] = (f"shared-neubrdf ({cfg.num_materials} materials, N_side {n}, {cfg.features} features, "
                            f"{cfg.interpolation} corner weights, {cfg.hidden}x{cfg.hidden_layers} MLP, direction "
                            f"inputs {cfg.direction_inputs})")
    return manifest, arrays
