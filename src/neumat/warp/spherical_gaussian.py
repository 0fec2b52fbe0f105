"""von Mises-Fisher (spherical Gaussian) lobes: pdf kappa exp(kappa (w.mu - 1)) / (2 pi (1 - exp(-2 kappa))).

mu is (N, 3) or (3,) unit; kappa >= 0 is a scalar or (N,). Written with expm1/log1p so it stays accurate for
large kappa and tends to the uniform sphere as kappa -> 0.
"""
from __future__ import annotations

import math

import torch

from ..core.checks import check_directions
from ..core.errors import InputError
from ..core.frames import frame_from_normal, to_local, to_world
from ._checks import check_u, lobe_parameters

#: below this kappa (0, subnormals) the lobe is the uniform sphere; the expm1 forms are exact above it
_KAPPA_UNIFORM = 1e-20


def _prepare(n: int, mu, kappa, ref: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Broadcast mu to (N, 3) and kappa to (N,) on the device/dtype of `ref`."""
    mu, kappa = lobe_parameters(n, mu, kappa, ref, "mu", "kappa")
    if n and kappa.min().item() < 0:
        raise InputError(f"kappa: concentration must be >= 0, got {kappa.min().item():.4g}")
    return mu, kappa


def sample_vmf(u: torch.Tensor, mu, kappa) -> torch.Tensor:
    """u (N, 2) -> directions w (N, 3) distributed by the vMF lobe (mu, kappa)."""
    check_u(u)
    mu, kappa = _prepare(u.shape[0], mu, kappa, u)
    small = kappa < _KAPPA_UNIFORM
    k = torch.where(small, torch.ones_like(kappa), kappa)
    # 1 - cos(theta), from w = 1 + log1p(u0 expm1(-2 kappa)) / kappa
    one_minus = torch.where(small, 2 * u[:, 0], -torch.log1p(u[:, 0] * torch.expm1(-2 * k)) / k).clamp(0, 2)
    sin = (one_minus * (2 - one_minus)).clamp(min=0).sqrt()
    phi = 2 * math.pi * u[:, 1]
    local = torch.stack([sin * torch.cos(phi), sin * torch.sin(phi), 1 - one_minus], -1)
    t, b = frame_from_normal(mu)
    return to_world(local, t, b, mu)


def vmf_pdf(w: torch.Tensor, mu, kappa) -> torch.Tensor:
    """Solid-angle density (N,) of the vMF lobe (mu, kappa) at directions w (N, 3)."""
    check_directions(w, "w")
    mu, kappa = _prepare(w.shape[0], mu, kappa, w)
    small = kappa < _KAPPA_UNIFORM
    k = torch.where(small, torch.ones_like(kappa), kappa)
    one_minus = 0.5 * ((w - mu) ** 2).sum(-1)  # 1 - w.mu, accurate near mu
    p = k / (-2 * math.pi * torch.expm1(-2 * k)) * torch.exp(-k * one_minus)
    return torch.where(small, torch.full_like(p, 1 / (4 * math.pi)), p)


def invert_vmf(w: torch.Tensor, mu, kappa) -> torch.Tensor:
    """Inverse of `sample_vmf`: directions w (N, 3) -> u (N, 2)."""
    check_directions(w, "w")
    mu, kappa = _prepare(w.shape[0], mu, kappa, w)
    small = kappa < _KAPPA_UNIFORM
    k = torch.where(small, torch.ones_like(kappa), kappa)
    one_minus = 0.5 * ((w - mu) ** 2).sum(-1)
    u0 = torch.where(small, one_minus / 2, torch.expm1(-k * one_minus) / torch.expm1(-2 * k))
    t, b = frame_from_normal(mu)
    local = to_local(w, t, b, mu)
    u1 = torch.remainder(torch.atan2(local[:, 1], local[:, 0]) / (2 * math.pi), 1.0)
    return torch.stack([u0.clamp(0, 1), u1], -1)
