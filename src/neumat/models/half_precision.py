"""The torch side of half-precision inference: `half_rounded(model)`, a copy of a model that stores what an fp16
export stores (`neumat.export.half_precision`) and computes in float32, as the exports' shaders do.

Real-Time Neural Appearance Models (Zeltner et al. 2024, Sec. 7) train in FP32 and infer in FP16. The exports keep
the latent textures and the decoder weights in half precision (RGBA16F textures, weights packed two per uint)
and accumulate in float32, so the reference of their parity checks is this copy, not a half-precision forward
pass: its preconditioned textures (`LatentPyramid`, `AngularTexture`) are baked (the preconditioned values become
the parameters, the preconditioner is dropped, as the exports store the preconditioned textures), the shading
frames' weight scale is folded into their decoder weights (as the exports store them), vector-quantised features
are frozen (their logits replaced by the indices the exports store), and then every
floating-point parameter is rounded to the nearest float16 (ties to even) and kept as float32. Buffers (index
tables, fixed Fourier matrices) are left as they are: the exports store them exactly.
"""
from __future__ import annotations

import copy

import torch
from torch import nn

from ..core.errors import InputError
from ..nn.angular_texture import AngularTexture
from ..nn.codebook import VQFeatures
from ..nn.latent_texture import LatentPyramid
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
