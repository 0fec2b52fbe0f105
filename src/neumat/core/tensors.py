"""Per-call cost of small tensor work on hot paths: constant tensors built once per value, dtype and device (a
Python number in a tensor operation is wrapped into a new tensor on every call), and calls run in inference mode
when autograd is off."""
from __future__ import annotations

import functools
from typing import Callable

import torch


@functools.lru_cache(maxsize=256)
def cached_tensor(value, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """`torch.tensor(value, dtype, device)`, built once per arguments (value: a number or nested tuples) and a plain
    tensor even when first asked for in inference mode (autograd may save it). Shared: never modify it."""
    with torch.inference_mode(False):
        return torch.tensor(value, dtype=dtype, device=device)


def inference_call(fn: Callable[..., torch.Tensor], *args) -> torch.Tensor:
    """fn(*args), a tensor, run in inference mode when autograd is off: each tensor operation then skips autograd's
    dispatch layers, about a quarter of the 1 to 1.5 us a small CPU operation costs, which is most of what a
    small batch's evaluation costs (a model's eval is some 30 to 60 such operations). The result is cloned out of
    inference mode into a plain tensor, which the caller may modify in place or give to autograd later (an
    inference tensor allows neither). With autograd on, or already in inference mode: fn(*args) as it is.
    fn must not cache tensors it creates (they would be inference tensors); `cached_tensor` is safe."""
    if torch.is_grad_enabled() or torch.is_inference_mode_enabled():
        return fn(*args)
    with torch.inference_mode():
        out = fn(*args)
    return out.clone()
