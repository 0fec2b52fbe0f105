"""FLOPs per evaluation of a model, to compare models at equal compute (Timonen et al. 2025, Sec. 5).

`model_flops` is the model's own analytic count (`model.flops()`, documented per model: MLP layers,
activations, angular texture reads, gating, warps, frames; not the spatial texture fetch, which texture
units do, as the paper counts). `measured_matmul_flops` cross-checks the dense part by running the model
under `torch.utils.flop_counter.FlopCounterMode`, which counts 2 m n k per matrix product (linear layers,
batched matrix products) and nothing else.

Details: src/neumat/methods/latent_mlp/NOTES.md, section `neumat.metrics.flops`.
"""
from __future__ import annotations

import torch
from torch.utils._python_dispatch import TorchDispatchMode
from torch.utils.flop_counter import FlopCounterMode

from ..core.errors import InputError
from ..core.query import Query
from ..nn.latent_texture import LatentPyramid


def model_flops(model) -> int:
    """Floating-point operations per evaluation, from `model.flops()`."""
    if not callable(getattr(model, "flops", None)):
        raise InputError(f"model_flops: {type(model).__name__} has no flops() method")
    return int(model.flops())


def measured_matmul_flops(model, query: Query) -> float:
    """Matrix-product FLOPs per query of one `model.eval(query)` call on its torch path (torch's FLOP counter; a
    fused CPU kernel's products are not torch's to count)."""
    from ..nn import cpu_kernels

    if len(query) == 0:
        raise InputError("measured_matmul_flops: the query batch is empty")
    with torch.no_grad(), cpu_kernels.switched_off(), FlopCounterMode(display=False) as counter:
        model.eval(query)
    return counter.get_total_flops() / len(query)


def flops_table(models: dict) -> list[tuple[str, int]]:
    """[(name, flops per evaluation)] of a dict name -> model, in the dict's order."""
    return [(name, model_flops(m)) for name, m in models.items()]


_aten = torch.ops.aten
#: FLOPs per output element of element-wise operations (EDM2's prices); others not listed cost nothing
_PER_ELEMENT = {
    **{op: 3 for op in ("silu", "sigmoid", "_softmax", "softmax")},
    **{op: 2 for op in ("clamp", "clamp_min", "clamp_max", "leaky_relu", "lerp", "hardtanh")},
    **{op: 1 for op in ("add", "sub", "rsub", "mul", "div", "exp", "exp2", "expm1", "log", "log2", "log1p", "pow",
                        "sqrt", "rsqrt", "reciprocal", "neg", "abs", "sin", "cos", "atan2", "acos", "asin", "atan",
                        "tanh", "relu", "square", "addcmul", "addcdiv", "where", "maximum", "minimum", "floor",
                        "frac", "remainder", "fmod", "sign", "eq", "gt", "lt", "ge", "le", "ne", "sum", "mean",
                        "amax", "cumsum", "linalg_vector_norm", "norm", "hypot", "round")},
}
#: FLOPs per output element of a texture read (bilinear: EDM2's upsample_bilinear2d rate)
TEXTURE_READ = 4


class _PaperCounter(TorchDispatchMode):
    def __init__(self) -> None:
        super().__init__()
        self.total = 0
        self.paused = 0  # > 0 inside a spatial texture fetch

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        out = func(*args, **(kwargs or {}))
        if self.paused:
            return out
        name = func.overloadpacket.__name__.rstrip("_")
        first = out[0] if isinstance(out, (tuple, list)) else out
        numel = first.numel() if isinstance(first, torch.Tensor) else 0
        if name in ("mm", "bmm", "addmm", "baddbmm", "addbmm", "matmul"):
            a = args[1] if name.startswith(("addmm", "baddbmm", "addbmm")) else args[0]
            self.total += numel * a.shape[-1]  # out elements x inner dimension multiply-adds
        elif name in ("grid_sampler_2d", "grid_sampler_3d", "upsample_bilinear2d"):
            self.total += TEXTURE_READ * numel
        else:
            self.total += _PER_ELEMENT.get(name, 0) * numel
        return out


def paper_flops_of(fn, *inputs, batch: int) -> float:
    """FLOPs per item of `fn(*inputs)` (a module or function over a batch of `batch` items), counted as the
    paper does (src/neumat/methods/latent_mlp/NOTES.md)."""
    if isinstance(batch, bool) or not isinstance(batch, int) or batch < 1:
        raise InputError(f"paper_flops_of: expected a positive integer batch size, got {batch!r}")
    with torch.no_grad(), _PaperCounter() as counter:
        fn(*inputs)
    return counter.total / batch


def paper_flops(model, query: Query) -> float:
    """FLOPs per query of `model.eval`, counted as the paper does (src/neumat/methods/latent_mlp/NOTES.md): the count
    over the query batch twice minus the count over it once, over its size, without the spatial texture fetch."""
    from ..nn import cpu_kernels

    n = len(query)
    if n == 0:
        raise InputError("paper_flops: the query batch is empty")
    double = query[torch.arange(2 * n, device=query.device) % n]
    counter = _PaperCounter()

    def pause(*_):
        counter.paused += 1

    def resume(*_):
        counter.paused -= 1

    fetches = [m for m in model.modules() if isinstance(m, LatentPyramid)] if hasattr(model, "modules") else []
    hooks = [h for m in fetches for h in (m.register_forward_pre_hook(pause), m.register_forward_hook(resume))]
    try:
        totals = []
        for q in (query, double):
            counter.total = 0
            with torch.no_grad(), cpu_kernels.switched_off(), counter:  # torch's operations, to count
                model.eval(q)
            totals.append(counter.total)
    finally:
        for h in hooks:
            h.remove()
    return (totals[1] - totals[0]) / n

