"""The area element of a warp from the unit square to the sphere, for pdf checks: pdf(w(u)) |dw/du| = 1."""
from __future__ import annotations

from typing import Callable

import torch


def sphere_jacobian(sample: Callable[[torch.Tensor], torch.Tensor], u: torch.Tensor, h: float = 1e-6) -> torch.Tensor:
    """|d w / d u0 x d w / d u1| (N,) of `sample`: u (N, 2) -> unit w (N, 3) by central differences of step h
    (solid angle per unit u-area; keep u at least h inside the square, and use float64)."""
    e0, e1 = torch.tensor([h, 0.0], dtype=u.dtype), torch.tensor([0.0, h], dtype=u.dtype)
    d0 = (sample(u + e0) - sample(u - e0)) / (2 * h)
    d1 = (sample(u + e1) - sample(u - e1)) / (2 * h)
    return torch.linalg.cross(d0, d1).norm(dim=-1)
