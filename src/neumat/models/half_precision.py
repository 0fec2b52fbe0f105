"""The torch side of half-precision inference: `half_rounded(model)`, a copy of a model that stores what an fp16
export stores (`neumat.export.half_precision`) and computes in float32, as the exports' shaders do.

Half-aware training (`with_half_parameters`, `snap_to_half_`) ends a fit on parameters an fp16 export
stores exactly.

Details: docs/formats/glsl.md, section `neumat.models.half_precision`.
"""
from __future__ import annotations

import copy
from typing import Any, Callable

import torch
from torch import nn

from ..core.errors import InputError
from ..core.tensors import tensors_swapped
from ..nn.angular_texture import AngularTexture
from ..nn.codebook import VQFeatures
from ..nn.latent_texture import LatentPyramid
from ..nn.preconditioner import FrequencyPreconditioner
from ..nn.shading_frames import ShadingFrame

#: the largest finite float16
HALF_MAX = 65504.0


def round_to_half(values: torch.Tensor, name: str = "tensor") -> torch.Tensor:
    """`values` rounded to the nearest float16 (ties to even), in their own dtype. Raises InputError naming `name`
    if a value is not finite or rounds beyond the float16 range (|x| > 65504)."""
    rounded = values.detach().to(torch.float16)
    if not torch.isfinite(rounded).all():
        raise InputError(f"half precision: {name} has values that are not finite or exceed the float16 range "
                         f"(|x| <= {HALF_MAX:g}); largest |x| {float(values.detach().abs().max()):.6g}")
    return rounded.to(values.dtype)


@torch.no_grad()
def half_rounded(model: nn.Module) -> nn.Module:
    """A copy of `model` (left unchanged) storing the float16-rounded values an fp16 export stores, computing in
    float32 (module docstring); in inference mode."""
    out = copy.deepcopy(model).train(False)
    for module in out.modules():
        if isinstance(module, LatentPyramid) and module.precondition is not None:
            levels = [level.detach().clone() for level in module.levels()]
            module.precondition = None
            for raw, level in zip(module.raw, levels):
                raw.copy_(level)
        elif isinstance(module, AngularTexture) and module.precondition is not None:
            texture = module.texture().detach().clone()
            module.precondition = None
            module.raw.copy_(texture)
        elif isinstance(module, VQFeatures):
            module.freeze()  # the exports store the indices, not the logits (a rounded logit may flip an argmax)
        elif isinstance(module, ShadingFrame) and module.weight_scale != 1.0:
            module.decode.weight.mul_(module.weight_scale)
            module.weight_scale = 1.0
    for name, parameter in out.named_parameters():
        if parameter.is_floating_point():
            parameter.copy_(round_to_half(parameter, name))
    return out


def _stored_scales(model: nn.Module) -> dict[str, float]:
    """name -> s for each parameter whose export stores s * value (a shading frame's weight scale; every other
    floating-point parameter is stored as itself, s = 1). InputError for modules whose exports store something
    that is not a multiple of one parameter (module docstring)."""
    scales = {}
    for prefix, module in model.named_modules():
        precondition = getattr(module, "precondition", None) if isinstance(module, (LatentPyramid,
                                                                                       AngularTexture)) else None
        identity = isinstance(precondition, FrequencyPreconditioner) and precondition.strength == 0
        refused = (precondition is not None and not identity) or isinstance(module, VQFeatures)
        if refused:
            raise InputError(f"half-aware training: {type(module).__name__} {prefix or '(model)'!r} stores "
                             "preconditioned or vector-quantised values, which an fp16 export rounds in another "
                             "form than its parameters; half-aware training supports plain parameters only")
        if isinstance(module, ShadingFrame) and module.weight_scale != 1.0:
            scales[f"{prefix}.decode.weight" if prefix else "decode.weight"] = module.weight_scale
    return scales


def _stored_rounding(p: torch.Tensor, scale: float, name: str) -> torch.Tensor:
    """round_to_half(scale * p) / scale, detached: the value of p that an fp16 export stores, in p's units."""
    return round_to_half(p.detach() * scale, name) / scale if scale != 1.0 else round_to_half(p, name)


class _Call(nn.Module):
    """Runs fn() with `model` as a submodule, so that torch.func.functional_call can swap its parameters."""

    def __init__(self, model: nn.Module) -> None:
        super().__init__()
        self.model = model

    def forward(self, fn: Callable[[], Any]) -> Any:
        return fn()


def with_half_parameters(model: nn.Module, fn: Callable[[], Any]) -> Any:
    """fn() computed with every floating-point parameter of `model` replaced by the value an fp16 export stores
    (`half_rounded`'s values, in the model's own parametrisation) and a straight-through gradient: the forward
    sees round(p), the backward passes the gradient at round(p) to p unchanged. `model` is left as it was."""
    scales = _stored_scales(model)
    rounded = {f"model.{name}": p + (_stored_rounding(p, scales.get(name, 1.0), name) - p.detach())
               for name, p in model.named_parameters() if p.is_floating_point()}
    tensors_swapped()  # module_stamp must see the swapped tensors, then the model's own again
    try:
        return torch.func.functional_call(_Call(model), rounded, (fn,))
    finally:
        tensors_swapped()


@torch.no_grad()
def snap_to_half_(model: nn.Module) -> nn.Module:
    """Round every floating-point parameter of `model` in place to the value an fp16 export stores (so that
    `half_rounded(model)` computes what `model` computes, to float32 arithmetic); returns `model`."""
    scales = _stored_scales(model)
    for name, p in model.named_parameters():
        if p.is_floating_point():
            p.copy_(_stored_rounding(p, scales.get(name, 1.0), name))
    return model


@torch.no_grad()
def is_half_exact(model: nn.Module) -> bool:
    """True when every floating-point parameter of `model` is already what an fp16 export stores (a
    half-aware fit's result): `snap_to_half_` would change nothing."""
    scales = _stored_scales(model)
    return all(torch.equal(p, _stored_rounding(p, scales.get(name, 1.0), name))
               for name, p in model.named_parameters() if p.is_floating_point())
