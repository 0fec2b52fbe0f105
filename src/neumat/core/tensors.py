"""Constant tensors built once per value, dtype and device, for hot paths: a Python number in a tensor
operation is wrapped into a new tensor on every call."""
from __future__ import annotations

import functools

import torch


@functools.lru_cache(maxsize=256)
def cached_tensor(value, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """`torch.tensor(value, dtype, device)`, built once per arguments (value: a number or nested tuples) and a plain
    tensor even when first asked for in inference mode (autograd may save it). Shared: never modify it."""
    with torch.inference_mode(False):
        return torch.tensor(value, dtype=dtype, device=device)
