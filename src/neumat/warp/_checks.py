"""Input checks shared by the warps: uniform numbers u and points."""
from __future__ import annotations

import torch

from ..core.checks import check_finite, check_shape


def check_u(u: torch.Tensor, name: str = "u", dim: int = 2) -> torch.Tensor:
    """Check a (N, dim) tensor of finite uniform numbers."""
    check_shape(u, name, (-1, dim))
    return check_finite(u, name)
