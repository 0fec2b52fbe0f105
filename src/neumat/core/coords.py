"""Coordinate maps with their inverses: spherical angles, Rusinkiewicz half/difference, disk projections.

Angles in radians. theta is measured from +z, phi from +x towards +y, phi in [0, 2 pi).
"""
from __future__ import annotations

import math

import torch

from .tensors import cached_tensor

TWO_PI = 2 * math.pi


def dir_to_spherical(w: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(theta, phi) of unit vectors w (N, 3); theta in [0, pi], phi in [0, 2 pi)."""
    theta = torch.acos(w[:, 2].clamp(-1, 1))
    phi = torch.atan2(w[:, 1], w[:, 0]) % TWO_PI
    return theta, phi


def spherical_to_dir(theta: torch.Tensor, phi: torch.Tensor) -> torch.Tensor:
    """Unit vectors (N, 3) from angles theta, phi (N,)."""
    st = torch.sin(theta)
    return torch.stack([st * torch.cos(phi), st * torch.sin(phi), torch.cos(theta)], -1)


def _rot_z(v: torch.Tensor, angle: torch.Tensor) -> torch.Tensor:
    c, s = torch.cos(angle), torch.sin(angle)
    return torch.stack([c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1], v[:, 2]], -1)


def _rot_y(v: torch.Tensor, angle: torch.Tensor) -> torch.Tensor:
    c, s = torch.cos(angle), torch.sin(angle)
    return torch.stack([c * v[:, 0] + s * v[:, 2], v[:, 1], -s * v[:, 0] + c * v[:, 2]], -1)


def io_to_hd(wi: torch.Tensor, wo: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Rusinkiewicz half vector h and difference vector d (each (N, 3)) of directions wi, wo (N, 3).

    d is wi expressed in the frame where h is the pole: rotate wi by -phi_h about z, then by -theta_h about y.
    """
    h = wi + wo
    h = h / h.norm(dim=-1, keepdim=True).clamp(min=1e-12)
    theta_h, phi_h = dir_to_spherical(h)
    d = _rot_y(_rot_z(wi, -phi_h), -theta_h)
    return h, d


def hd_vectors(wi: torch.Tensor, wo: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """`io_to_hd` without trigonometry (phi_h = 0 at the pole, as there), in few tensor operations: the hot path
    of models whose inputs are h and d. d is wi in the orthonormal frame (t, b, h) that `io_to_hd`'s rotations
    define: with u = (h_x, h_y) / sin theta_h ((1, 0) at the pole), t = (h_z u, -sin theta_h) and b = h x t."""
    h = wi + wo
    h = h / torch.linalg.vector_norm(h, dim=-1, keepdim=True).clamp(min=1e-12)
    hxy = h[:, :2]
    s = torch.linalg.vector_norm(hxy, dim=-1, keepdim=True)                        # sin theta_h (N, 1)
    u = torch.where(s > 0, hxy / s.clamp(min=torch.finfo(s.dtype).tiny), cached_tensor((1.0, 0.0), h.dtype, h.device))
    t = torch.cat((h[:, 2:] * u, -s), -1)
    frame = torch.stack((t, torch.linalg.cross(h, t), h), 1)                       # rows t, b, h (N, 3, 3)
    return h, torch.bmm(frame, wi.unsqueeze(-1)).squeeze(-1)


def hd_to_io(h: torch.Tensor, d: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Inverse of `io_to_hd`: (wi, wo) from half and difference vectors (N, 3)."""
    theta_h, phi_h = dir_to_spherical(h)
    wi = _rot_z(_rot_y(d, theta_h), phi_h)
    d_mirror = torch.stack([-d[:, 0], -d[:, 1], d[:, 2]], -1)
    wo = _rot_z(_rot_y(d_mirror, theta_h), phi_h)
    return wi, wo


def io_to_rusinkiewicz(wi: torch.Tensor, wo: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """(theta_h, phi_h, theta_d, phi_d), each (N,), of wi, wo (N, 3)."""
    h, d = io_to_hd(wi, wo)
    theta_h, phi_h = dir_to_spherical(h)
    theta_d, phi_d = dir_to_spherical(d)
    return theta_h, phi_h, theta_d, phi_d


def rusinkiewicz_to_io(theta_h, phi_h, theta_d, phi_d) -> tuple[torch.Tensor, torch.Tensor]:
    """Inverse of `io_to_rusinkiewicz`: (wi, wo) as (N, 3) each."""
    return hd_to_io(spherical_to_dir(theta_h, phi_h), spherical_to_dir(theta_d, phi_d))


def hemisphere_to_disk(w: torch.Tensor) -> torch.Tensor:
    """Orthographic disk projection (N, 2): the (x, y) of a unit vector; radius sin(theta)."""
    return w[:, :2]


def disk_to_hemisphere(p: torch.Tensor) -> torch.Tensor:
    """Inverse of `hemisphere_to_disk` on the upper hemisphere: (N, 2) -> (N, 3)."""
    z = (1 - (p * p).sum(-1)).clamp(min=0).sqrt()
    return torch.cat([p, z.unsqueeze(-1)], -1)


def disk_to_polar(p: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Polar coordinates (r, phi) of disk points (N, 2); phi in [0, 2 pi)."""
    return p.norm(dim=-1), torch.atan2(p[:, 1], p[:, 0]) % TWO_PI


def polar_to_disk(r: torch.Tensor, phi: torch.Tensor) -> torch.Tensor:
    """Inverse of `disk_to_polar`: (N, 2)."""
    return torch.stack([r * torch.cos(phi), r * torch.sin(phi)], -1)
