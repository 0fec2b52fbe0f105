"""FLOPs per evaluation of a model, to compare models at equal compute (Timonen et al. 2025, Sec. 5).

`model_flops` is the model's own analytic count (`model.flops()`, documented per model: MLP layers,
activations, angular texture reads, gating, warps, frames; not the spatial texture fetch, which texture
units do, as the paper counts). `measured_matmul_flops` cross-checks the dense part by running the model
under `torch.utils.flop_counter.FlopCounterMode`, which counts 2 m n k per matrix product (linear layers,
batched matrix products) and nothing else.
"""
from __future__ import annotations

import torch
from torch.utils.flop_counter import FlopCounterMode

from ..core.errors import InputError
from ..core.query import Query


def model_flops(model) -> int:
    """Floating-point operations per evaluation, from `model.flops()`."""
    if not callable(getattr(model, "flops", None)):
        raise InputError(f"model_flops: {type(model).__name__} has no flops() method")
    return int(model.flops())


def measured_matmul_flops(model, query: Query) -> float:
    """Matrix-product FLOPs per query of one `model.eval(query)` call (torch's FLOP counter)."""
    if len(query) == 0:
        raise InputError("measured_matmul_flops: the query batch is empty")
    with torch.no_grad(), FlopCounterMode(display=False) as counter:
        model.eval(query)
    return counter.get_total_flops() / len(query)


def flops_table(models: dict) -> list[tuple[str, int]]:
    """[(name, flops per evaluation)] of a dict name -> model, in the dict's order."""
    return [(name, model_flops(m)) for name, m in models.items()]
