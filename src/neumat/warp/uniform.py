"""Uniform random numbers for the warps: `uniform(n, d, generator, device)`."""
from __future__ import annotations

import torch


def uniform(n: int, d: int, generator: torch.Generator, device) -> torch.Tensor:
    """(n, d) uniform numbers in [0, 1) from `generator`, on `device` (float32)."""
    return torch.rand(n, d, generator=generator, device=generator.device).to(device)
