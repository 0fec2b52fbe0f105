"""Dr.Jit runtime translator of NeuPreSS (program "neupress", `neumat.export.drjit.neupress`): the Fourier matrices,
the skip-connection appearance MLP, the light sampler's MLP and the object's box, so that the scene integrator
`neumat.integrations.mitsuba_translucent` evaluates S_hat, sigma, incident sampling and its pdf without torch."""
from __future__ import annotations

import numpy as np
import torch
from torch import nn

from neumat.core.errors import InputError
from neumat.methods.neupress.model import SIGMA_MAX, SIGMA_MIN, NeuPreSS


def _np(t: torch.Tensor) -> np.ndarray:
    return t.detach().cpu().float().numpy()


@torch.no_grad()
def translate(model: NeuPreSS) -> tuple[dict, dict]:
    """(manifest, arrays) of a NeuPreSS; InputError for a subclass that evaluates or samples its own way."""
    if not isinstance(model, NeuPreSS):
        raise InputError(f"neupress drjit translator: expected a NeuPreSS, got {type(model).__name__}")
    cls = type(model)
    if any(getattr(cls, m) is not getattr(NeuPreSS, m)
           for m in ("raw", "eval", "sigma", "incident_lobe", "sample_incident", "incident_pdf", "_direction",
                     "_position")):
        raise InputError(f"export_drjit: {model.name} evaluates or samples its own way; no Dr.Jit runtime for it")
    if any(not isinstance(m, (nn.Linear, nn.ReLU)) for m in model.sampler):
        raise InputError("export_drjit: NeuPreSS's sampler is not Linear / ReLU; no Dr.Jit form")
    c, mlp = model.cfg, model.appearance
    arrays = {"appearance_G": _np(model.appearance_features.G), "sampler_G": _np(model.sampler_features.G),
              "app_first_weight": _np(mlp.first.weight), "app_first_bias": _np(mlp.first.bias),
              "app_out_weight": _np(mlp.out.weight), "app_out_bias": _np(mlp.out.bias)}
    for i, layer in enumerate(mlp.hidden):
        arrays[f"app_hidden{i}_weight"] = _np(layer.weight)
        arrays[f"app_hidden{i}_bias"] = _np(layer.bias)
    for i, layer in enumerate(m for m in model.sampler if isinstance(m, nn.Linear)):
        arrays[f"sampler{i}_weight"] = _np(layer.weight)
        arrays[f"sampler{i}_bias"] = _np(layer.bias)
    manifest = {"program": "neupress", "direction_encoding": c.direction_encoding, "skips": bool(mlp.skips),
                "box_min": [float(v) for v in model.box_min.float().tolist()],
                "box_max": [float(v) for v in model.box_max.float().tolist()],
                "sigma_min": SIGMA_MIN, "sigma_max": SIGMA_MAX,
                "describe": f"neupress ({c.features} Fourier features, {mlp.layers} x {mlp.width} ReLU"
                            f"{' with skips' if mlp.skips else ''}, sampler "
                            f"{'-'.join(str(h) for h in c.sampler_hidden)})"}
    return manifest, arrays
