"""Shirley-Chiu concentric map from the unit square onto the unit disk (area preserving)."""
from __future__ import annotations

import math

import torch

from ..core.checks import check_finite, check_shape
from ._checks import check_u


def sample_concentric_disk(u: torch.Tensor) -> torch.Tensor:
    """Map u (N, 2) in [0, 1]^2 to points p (N, 2) on the unit disk, uniformly in area."""
    check_u(u)
    a, b = (2 * u - 1).unbind(-1)
    first = a.abs() > b.abs()
    r = torch.where(first, a, b)
    safe_a = torch.where(a == 0, torch.ones_like(a), a)
    safe_b = torch.where(b == 0, torch.ones_like(b), b)
    phi = torch.where(first, (math.pi / 4) * b / safe_a, math.pi / 2 - (math.pi / 4) * a / safe_b)
    return torch.stack([r * torch.cos(phi), r * torch.sin(phi)], -1)


def concentric_disk_pdf(p: torch.Tensor) -> torch.Tensor:
    """Area density (N,) of `sample_concentric_disk`: 1/pi inside the unit disk, 0 outside."""
    check_shape(p, "p", (-1, 2))
    inside = (p * p).sum(-1) <= 1
    return torch.where(inside, torch.full_like(p[:, 0], 1 / math.pi), torch.zeros_like(p[:, 0]))


def invert_concentric_disk(p: torch.Tensor) -> torch.Tensor:
    """Inverse of `sample_concentric_disk`: points p (N, 2) on the disk -> u (N, 2) in [0, 1]^2."""
    check_shape(p, "p", (-1, 2))
    check_finite(p, "p")
    x, y = p.unbind(-1)
    r = p.norm(dim=-1)
    first = x.abs() >= y.abs()
    safe_x = torch.where(x == 0, torch.ones_like(x), x)
    safe_y = torch.where(y == 0, torch.ones_like(y), y)
    # case |x| >= |y|: a = r sign(x), b = a (4/pi) atan(y/x); otherwise the roles swap
    a1 = torch.copysign(r, x)
    b1 = a1 * (4 / math.pi) * torch.atan(y / safe_x)
    b2 = torch.copysign(r, y)
    a2 = b2 * (4 / math.pi) * torch.atan(x / safe_y)
    a = torch.where(first, a1, a2)
    b = torch.where(first, b1, b2)
    return (torch.stack([a, b], -1) + 1) / 2
