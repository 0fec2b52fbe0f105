"""Dr.Jit runtime translators of the homogeneous baselines (`neumat.export.drjit.runtime`): NBRDF and the naive MLP
as the "direction-mlp" program, the fitted GGX as the "ggx" program (with its mixture sampler)."""
from __future__ import annotations

import numpy as np
import torch

from neumat.core.errors import InputError
from neumat.export.drjit.runtime import ACTIVATIONS
from neumat.methods.baselines.ggx import GGXFit
from neumat.methods.baselines.naive_mlp import NaiveMLP
from neumat.methods.baselines.nbrdf import NBRDF


def _np(t: torch.Tensor) -> np.ndarray:
    return t.detach().cpu().float().numpy()


def _mlp_arrays(mlp, who: str, activation: str) -> dict:
    if activation not in ACTIVATIONS:
        raise InputError(f"export_drjit: {who} activation {activation!r} has no Dr.Jit form ({', '.join(ACTIVATIONS)})")
    arrays = {}
    for i, layer in enumerate(mlp.linears()):
        arrays[f"layer{i}_weight"] = _np(layer.weight)
        arrays[f"layer{i}_bias"] = _np(layer.bias)
    return arrays


@torch.no_grad()
def translate_nbrdf(model: NBRDF) -> tuple[dict, dict]:
    """(manifest, arrays) of an NBRDF: half / difference inputs under its `half` and `fold_phi_d`, the MLP, its
    output transform (float64 weights, e.g. of `NBRDF.from_keras`, are rounded to float32)."""
    if not isinstance(model, NBRDF):
        raise InputError(f"NBRDF drjit translator: expected an NBRDF, got {type(model).__name__}")
    c = model.cfg
    manifest = {"program": "direction-mlp", "inputs": "hd", "half": c.half, "fold_phi_d": c.fold_phi_d,
                "activation": c.activation, "output": c.output,
                "describe": f"nbrdf (6-{'-'.join([str(c.hidden)] * c.hidden_layers)}-3 {c.activation}, {c.output})"}
    return manifest, _mlp_arrays(model.mlp, "NBRDF", c.activation)


@torch.no_grad()
def translate_naive_mlp(model: NaiveMLP) -> tuple[dict, dict]:
    """(manifest, arrays) of the naive MLP: exp(MLP([wi, wo]))."""
    if not isinstance(model, NaiveMLP):
        raise InputError(f"naive-mlp drjit translator: expected a NaiveMLP, got {type(model).__name__}")
    c = model.cfg
    manifest = {"program": "direction-mlp", "inputs": "wiwo", "activation": c.activation, "output": "exp",
                "describe": f"naive-mlp (6-{'-'.join([str(c.hidden)] * c.hidden_layers)}-3 {c.activation})"}
    return manifest, _mlp_arrays(model.mlp, "naive-mlp", c.activation)


@torch.no_grad()
def translate_ggx(model: GGXFit) -> tuple[dict, dict]:
    """(manifest, no arrays) of a fitted GGX: its diffuse, Schlick F0, alphas and lobe probability."""
    if not isinstance(model, GGXFit):
        raise InputError(f"ggx drjit translator: expected a GGXFit, got {type(model).__name__}")
    alpha = model.alpha.float().tolist()
    manifest = {"program": "ggx", "diffuse": model.diffuse.float().tolist(),
                "specular": model.specular.float().tolist(), "alpha": alpha,
                "p_diffuse": float(model.diffuse_probability()), "describe": model.describe()}
    return manifest, {}
