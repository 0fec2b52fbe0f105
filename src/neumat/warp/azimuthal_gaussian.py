"""Azimuthal-equidistant Gaussian lobes: the importance-sampling lobe of NeuPreSS.

A zero-mean isotropic 2D Gaussian of standard deviation sigma (radians) in the azimuthal equidistant projection
around the unit axis n: a direction at angle theta from n and azimuth phi maps to the plane point of radius
r = theta. The radius follows a Rayleigh(sigma) law truncated to r <= pi, so every sample is a direction and
the lobe is exact on the sphere. With C = 1 - exp(-pi^2 / (2 sigma^2)):

    sample:  r = sigma sqrt(-2 ln(1 - u0 C)),  phi = 2 pi u1   (Box-Muller radius, inverted CDF)
    pdf:     exp(-theta^2 / (2 sigma^2)) / (2 pi sigma^2 C) * theta / sin(theta)   per steradian

The factor theta / sin(theta) is the Jacobian of the projection: 1 at the axis, it diverges (integrably) at the
antipode -n, where the pdf is capped to a large finite value. C is computed with expm1, so the lobe stays
accurate from sigma ~ 1e-3 (a plane Gaussian, pdf 1/(2 pi sigma^2) at the axis) to sigma ~ 1e3 (r/pi -> sqrt(u0),
uniform over the projected disk). axis is (N, 3) or (3,) unit, sigma > 0 a scalar or (N,); everything is
differentiable with respect to sigma.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ..core.checks import check_directions
from ..core.errors import InputError
from ..core.frames import frame_from_normal, to_local, to_world
from ._checks import check_u, lobe_parameters


def _prepare(n: int, axis, sigma, ref: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Broadcast axis to (N, 3) and sigma to (N,) on the device/dtype of `ref`; check them."""
    axis, sigma = lobe_parameters(n, axis, sigma, ref, "axis", "sigma")
    if n and sigma.min().item() <= 0:
        raise InputError(f"sigma: standard deviation must be > 0, got {sigma.min().item():.4g}")
    return axis, sigma


def _truncation(sigma: torch.Tensor) -> torch.Tensor:
    """-C = expm1(-pi^2 / (2 sigma^2)) in [-1, 0): minus the Rayleigh mass inside r <= pi."""
    return torch.expm1(-0.5 * (math.pi / sigma) ** 2)


def _angle(w: torch.Tensor, axis: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Angle theta (N,) between w and axis, and theta / sin(theta) (N,), accurate over all of [0, pi].

    theta = 2 atan2(|w - n|, |w + n|) and sin(theta) = 2 |w - n| |w + n| / (|w - n|^2 + |w + n|^2) have full
    relative accuracy at both ends; the norms are floored at sqrt(tiny) so w = n gives ratio 1 and w = -n a large
    finite ratio (and finite gradients).
    """
    tiny = torch.finfo(w.dtype).tiny
    d2 = ((w - axis) ** 2).sum(-1).clamp(min=tiny)
    s2 = ((w + axis) ** 2).sum(-1).clamp(min=tiny)
    d, s = d2.sqrt(), s2.sqrt()
    theta = 2 * torch.atan2(d, s)
    return theta, theta * (d2 + s2) / (2 * d * s)


def sample_azimuthal_gaussian(u: torch.Tensor, axis, sigma) -> torch.Tensor:
    """u (N, 2) in [0, 1]^2 -> unit directions w (N, 3), in the space of axis, drawn from the lobe (axis, sigma)."""
    check_u(u)
    axis, sigma = _prepare(u.shape[0], axis, sigma, u)
    # r = sigma sqrt(-2 ln(1 - u0 C)). Only u0 = 1 with C = 1 (rounded) hits the clamp, which keeps r finite there
    # (a few sigma, where the pdf is > 0); the floors keep the gradients w.r.t. sigma finite at u0 = 0 and 1.
    finfo = torch.finfo(u.dtype)
    arg = (u[:, 0] * _truncation(sigma)).clamp(min=-(1 - finfo.eps / 2))
    r = (sigma * (-2 * torch.log1p(arg)).clamp(min=finfo.tiny).sqrt()).clamp(max=math.pi)
    phi = 2 * math.pi * u[:, 1]
    sin = torch.sin(r)
    local = torch.stack([sin * torch.cos(phi), sin * torch.sin(phi), torch.cos(r)], -1)
    t, b = frame_from_normal(axis)
    return to_world(local, t, b, axis)


def azimuthal_gaussian_pdf(w: torch.Tensor, axis, sigma) -> torch.Tensor:
    """Solid-angle density (N,) of the lobe (axis, sigma) at unit directions w (N, 3)."""
    check_directions(w, "w")
    axis, sigma = _prepare(w.shape[0], axis, sigma, w)
    theta, ratio = _angle(w, axis)
    norm = -2 * math.pi * sigma ** 2 * _truncation(sigma)  # 2 pi sigma^2 C
    return torch.exp(-0.5 * (theta / sigma) ** 2) / norm * ratio


def invert_azimuthal_gaussian(w: torch.Tensor, axis, sigma) -> torch.Tensor:
    """Inverse of `sample_azimuthal_gaussian`: unit directions w (N, 3) -> u (N, 2) (same frame around axis)."""
    check_directions(w, "w")
    axis, sigma = _prepare(w.shape[0], axis, sigma, w)
    theta, _ = _angle(w, axis)
    u0 = torch.expm1(-0.5 * (theta / sigma) ** 2) / _truncation(sigma)
    t, b = frame_from_normal(axis)
    local = to_local(w, t, b, axis)
    u1 = torch.remainder(torch.atan2(local[:, 1], local[:, 0]) / (2 * math.pi), 1.0)
    return torch.stack([u0.clamp(0, 1), u1], -1)


@dataclass
class AzimuthalGaussianLobe:
    """One lobe per query, axis (N, 3) unit and sigma (N,) radians, built once (e.g. by a network) and used for
    both sampling and densities, so that one-sample MIS evaluates the network that predicts sigma only once."""

    axis: torch.Tensor
    sigma: torch.Tensor

    def sample(self, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Directions w (N, 3) for u (N, 2) in [0, 1)^2 and their solid-angle pdf (N,)."""
        w = sample_azimuthal_gaussian(u, self.axis, self.sigma)
        return w, azimuthal_gaussian_pdf(w, self.axis, self.sigma)

    def pdf(self, w: torch.Tensor) -> torch.Tensor:
        """Solid-angle density (N,) at unit directions w (N, 3)."""
        return azimuthal_gaussian_pdf(w, self.axis, self.sigma)
