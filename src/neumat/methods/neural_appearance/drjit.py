"""Dr.Jit runtime translator of neural-appearance (program "neural-appearance",
`neumat.export.drjit.neural_appearance`): the "neumip" program's BRDF decoder (`translate_neumip`) and the learned
sampler's MLP (`ProxySampler`), so that the model renders natively with its own sampler."""
from __future__ import annotations

import torch

from neumat.core.errors import InputError
from neumat.methods.latent_mlp.drjit import _np, translate_neumip
from neumat.methods.neural_appearance.model import NeuralAppearance
from neumat.methods.neural_appearance.proxy_sampler import ProxySampler


@torch.no_grad()
def translate(model: NeuralAppearance) -> tuple[dict, dict]:
    """(manifest, arrays) of a neural-appearance model; InputError for a subclass that samples differently."""
    if not isinstance(model, NeuralAppearance):
        raise InputError(f"neural-appearance drjit translator: expected a NeuralAppearance, got {type(model).__name__}")
    cls = type(model)
    if any(getattr(cls, m) is not getattr(NeuralAppearance, m) for m in ("sample", "pdf", "lobes")) \
            or type(model.sampler).lobes is not ProxySampler.lobes:
        raise InputError(f"export_drjit: {model.name} samples its own way; no Dr.Jit runtime for it yet")
    manifest, arrays = translate_neumip(model)
    mlp = model.sampler.mlp
    if any(type(m).__name__ not in ("Linear", "ReLU") for m in mlp.net):
        raise InputError("export_drjit: neural-appearance's sampler MLP is not Linear / ReLU; no Dr.Jit form")
    for i, layer in enumerate(mlp.linears()):
        arrays[f"sampler_layer{i}_weight"] = _np(layer.weight)
        arrays[f"sampler_layer{i}_bias"] = _np(layer.bias)
    manifest.update(program="neural-appearance", sampler_lobes=model.sampler.cfg.lobes, sampler_activation="relu",
                    describe=manifest["describe"] + f", sampler {model.sampler.cfg.lobes} "
                             f"{model.sampler.cfg.hidden}x{model.sampler.cfg.hidden_layers}")
    return manifest, arrays
