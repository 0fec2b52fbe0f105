"""Input checks shared by the warps: uniform numbers u and points."""
from __future__ import annotations

import torch

from ..core.checks import check_directions, check_finite, check_shape


def check_u(u: torch.Tensor, name: str = "u", dim: int = 2) -> torch.Tensor:
    """Check a (N, dim) tensor of finite uniform numbers."""
    check_shape(u, name, (-1, dim))
    return check_finite(u, name)


def lobe_parameters(n: int, axis, scale, ref: torch.Tensor, axis_name: str,
                    scale_name: str) -> tuple[torch.Tensor, torch.Tensor]:
    """A lobe's unit axis broadcast to (N, 3) (from (3,) or (N, 3)) and its finite scalar parameter to (N,)
    (from a scalar or (N,)), on the device / dtype of `ref`; the sign of the parameter is the caller's check."""
    axis = torch.as_tensor(axis, dtype=ref.dtype, device=ref.device)
    if axis.dim() == 1:
        check_shape(axis, axis_name, (3,))
        axis = axis.expand(n, 3)
    check_directions(axis, axis_name)
    check_shape(axis, axis_name, (n, 3))
    scale = torch.as_tensor(scale, dtype=ref.dtype, device=ref.device)
    if scale.dim() == 0:
        scale = scale.expand(n)
    check_shape(scale, scale_name, (n,))
    check_finite(scale, scale_name)
    return axis, scale
