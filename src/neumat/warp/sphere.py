"""Uniform sampling of the unit sphere, density in solid angle."""
from __future__ import annotations

import math

import torch

from ..core.checks import check_directions
from ._checks import check_u
from .hemisphere import _phi_to_u


def sample_uniform_sphere(u: torch.Tensor) -> torch.Tensor:
    """u (N, 2) in [0, 1]^2 -> directions w (N, 3) uniform on the sphere (z = 1 - 2 u0)."""
    check_u(u)
    z = 1 - 2 * u[:, 0]
    r = (1 - z * z).clamp(min=0).sqrt()
    phi = 2 * math.pi * u[:, 1]
    return torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], -1)


def uniform_sphere_pdf(w: torch.Tensor) -> torch.Tensor:
    """Solid-angle density (N,) of `sample_uniform_sphere`: 1/(4 pi)."""
    check_directions(w, "w")
    return torch.full_like(w[:, 2], 1 / (4 * math.pi))


def invert_uniform_sphere(w: torch.Tensor) -> torch.Tensor:
    """Inverse of `sample_uniform_sphere`: w (N, 3) -> u (N, 2)."""
    check_directions(w, "w")
    return torch.stack([(1 - w[:, 2]) / 2, _phi_to_u(w)], -1)
