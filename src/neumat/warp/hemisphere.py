"""Uniform and cosine-weighted sampling of the upper hemisphere (z >= 0), densities in solid angle."""
from __future__ import annotations

import math

import torch

from ..core.checks import check_directions
from ._checks import check_u
from .disk import invert_concentric_disk, sample_concentric_disk


def _phi_to_u(w: torch.Tensor) -> torch.Tensor:
    """Azimuth of w (N, 3) mapped to [0, 1)."""
    return torch.remainder(torch.atan2(w[:, 1], w[:, 0]) / (2 * math.pi), 1.0)


def sample_uniform_hemisphere(u: torch.Tensor) -> torch.Tensor:
    """u (N, 2) in [0, 1]^2 -> directions w (N, 3) uniform on the upper hemisphere (z = u0)."""
    check_u(u)
    z = u[:, 0]
    r = (1 - z * z).clamp(min=0).sqrt()
    phi = 2 * math.pi * u[:, 1]
    return torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], -1)


def uniform_hemisphere_pdf(w: torch.Tensor) -> torch.Tensor:
    """Solid-angle density (N,) of `sample_uniform_hemisphere`: 1/(2 pi) for z >= 0, else 0."""
    check_directions(w, "w")
    return torch.where(w[:, 2] >= 0, torch.full_like(w[:, 2], 1 / (2 * math.pi)), torch.zeros_like(w[:, 2]))


def invert_uniform_hemisphere(w: torch.Tensor) -> torch.Tensor:
    """Inverse of `sample_uniform_hemisphere`: w (N, 3) -> u (N, 2)."""
    check_directions(w, "w")
    return torch.stack([w[:, 2], _phi_to_u(w)], -1)


def sample_cosine_hemisphere(u: torch.Tensor) -> torch.Tensor:
    """u (N, 2) -> directions w (N, 3) with density cos(theta)/pi (Malley: concentric disk lifted up)."""
    p = sample_concentric_disk(u)
    z = (1 - (p * p).sum(-1)).clamp(min=0).sqrt()
    return torch.cat([p, z.unsqueeze(-1)], -1)


def cosine_hemisphere_pdf(w: torch.Tensor) -> torch.Tensor:
    """Solid-angle density (N,) of `sample_cosine_hemisphere`: max(z, 0) / pi."""
    check_directions(w, "w")
    return w[:, 2].clamp(min=0) / math.pi


def invert_cosine_hemisphere(w: torch.Tensor) -> torch.Tensor:
    """Inverse of `sample_cosine_hemisphere`: w (N, 3) -> u (N, 2)."""
    check_directions(w, "w")
    return invert_concentric_disk(w[:, :2])
