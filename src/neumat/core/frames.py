"""Orthonormal shading frames: build one from a normal, move vectors to and from it."""
from __future__ import annotations

import torch


def frame_from_normal(n: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Tangent and bitangent (each (N, 3)) completing unit normals n (N, 3) to a right-handed frame.

    Uses the branchless construction of Duff et al. (2017); t x b = n.
    """
    x, y, z = n.unbind(-1)
    sign = torch.where(z >= 0, torch.ones_like(z), -torch.ones_like(z))
    a = -1.0 / (sign + z)
    b = x * y * a
    t = torch.stack([1 + sign * x * x * a, sign * b, -sign * x], -1)
    bt = torch.stack([b, sign + y * y * a, -y], -1)
    return t, bt


def frame_from_normal_tangent(n: torch.Tensor, t: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Gram-Schmidt: a unit tangent orthogonal to n (N, 3) from a rough tangent t (N, 3), and the bitangent."""
    t = t - (t * n).sum(-1, keepdim=True) * n
    # = t / max(|t|, 1e-12); not Tensor.norm, which is ~10x slower on column-major (N, 3) inputs
    t = t / (t * t).sum(-1, keepdim=True).clamp(min=1e-24).sqrt()
    return t, torch.cross(n, t, dim=-1)


def normal_map_frame(n: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(t, b, n): the shading frame of normal-mapped unit normals n (N, 3), the tangent +u (+x) projected onto
    the perturbed tangent plane (the normal-map convention of `neumat.io.texture_set`)."""
    tangent = torch.zeros_like(n)
    tangent[:, 0] = 1
    t, b = frame_from_normal_tangent(n, tangent)
    return t, b, n


def to_local(v: torch.Tensor, t: torch.Tensor, b: torch.Tensor, n: torch.Tensor) -> torch.Tensor:
    """World vector v (N, 3) expressed in the frame (t, b, n)."""
    return torch.stack([(v * t).sum(-1), (v * b).sum(-1), (v * n).sum(-1)], -1)


def to_world(v: torch.Tensor, t: torch.Tensor, b: torch.Tensor, n: torch.Tensor) -> torch.Tensor:
    """Local vector v (N, 3) in the frame (t, b, n) back to world space."""
    return v[:, :1] * t + v[:, 1:2] * b + v[:, 2:3] * n
