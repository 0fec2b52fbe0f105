"""A fused CPU kernel (`neumat.nn.cpu_kernels`) against the model in float64, scored beside the float32 torch path:
`kernel_and_torch_errors(model, q, q64, floor)`. The kernel tests of the dipole, the UV baselines and NeuPreSS hold a
kernel to "as close to float64 as torch's own float32", which this computes the same way for each."""
from __future__ import annotations

import copy

import torch

from ..core.query import Query
from ..nn import cpu_kernels


def kernel_and_torch_errors(model, q: Query, q64: Query, floor: float) -> tuple[torch.Tensor, float, float]:
    """(kernel values, kernel error, torch error): `model` evaluated without autograd at q through its kernel
    (asserted to run exactly once) and with the kernels switched off (the float32 torch path), both against a
    float64 copy of the model at q64 (q in float64); each error the worst over rows of |value - reference| / the
    row's largest |reference| (the channels share one MLP's rounding), that largest value floored at `floor`."""
    with torch.no_grad():
        before = cpu_kernels.calls[0]
        fast = model.eval(q)
        assert cpu_kernels.calls[0] == before + 1, "the kernel did not run (or ran more than once)"
        with cpu_kernels.switched_off():
            ref32 = model.eval(q)
        ref = copy.deepcopy(model).double().eval(q64)
    scale = ref.abs().amax(1, keepdim=True).clamp(min=floor)
    return fast, float(((fast - ref) / scale).abs().max()), float(((ref32 - ref) / scale).abs().max())
