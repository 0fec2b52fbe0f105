"""Learned radial warps of the angular textures (Timonen et al. 2025, Sec. 3.2, Eq. 7).

    r' = sum_k w_k r^alpha_k,   w = softmax(logits) (a partition of unity),   alpha_k = 1/2 + softplus(a_k)

so alpha_k > 1/2 and r' maps [0, 1] onto [0, 1] monotonically (every term is increasing, r'(0) = 0 and
r'(1) = 1). The initial exponents are 1 -/+ INIT_SPREAD with equal weights: approximately the identity
(|r' - r| <= r (cosh(0.1 ln r) - 1) < 3e-3), but not exactly, because two equal terms would receive equal
gradients forever. Per-texture parameters are either shared (homogeneous BRDFs) or decoded from the
spatial latent z_s by one linear layer (spatially varying materials; zero weights at initialisation).
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from ..core.checks import check_int
from ..core.errors import InputError

MIN_ALPHA = 0.5
INIT_SPREAD = 0.1


def warp_radius(r: torch.Tensor, logits: torch.Tensor, alpha_raw: torch.Tensor) -> torch.Tensor:
    """r' (N,) of radii r (N,) in [0, 1] with logits and raw exponents (N, K) or (K,)."""
    w = torch.softmax(logits, -1)
    alpha = MIN_ALPHA + F.softplus(alpha_raw)
    r = r.clamp(1e-9, 1.0).unsqueeze(-1)
    return (w * torch.exp(alpha * torch.log(r))).sum(-1)


def _initial_parameters(terms: int) -> torch.Tensor:
    """(2 K,) logits then raw exponents of the near-identity initial warp."""
    alpha = torch.linspace(1 - INIT_SPREAD, 1 + INIT_SPREAD, terms) if terms > 1 else torch.ones(1)
    raw = torch.log(torch.expm1(alpha - MIN_ALPHA))  # softplus inverse
    return torch.cat([torch.zeros(terms), raw])


class RadialWarp(nn.Module):
    """r' = warp(r) with `terms` components; forward(r (N,), z (N, latent_dim) or None) -> (N,).

    latent_dim = 0: one shared set of parameters. latent_dim > 0: parameters = Linear(z) (bias initialised to
    the near-identity warp, weights to 0).
    """

    def __init__(self, terms: int = 2, latent_dim: int = 0) -> None:
        super().__init__()
        check_int(terms, "RadialWarp.terms")
        self.terms, self.latent_dim = terms, latent_dim
        init = _initial_parameters(terms)
        if latent_dim > 0:
            self.decode = nn.Linear(latent_dim, 2 * terms)
            with torch.no_grad():
                self.decode.weight.zero_()
                self.decode.bias.copy_(init)
        else:
            self.params = nn.Parameter(init)

    def parameters_for(self, z: torch.Tensor | None) -> torch.Tensor:
        """(N, 2 K) or (2 K,) logits and raw exponents."""
        if self.latent_dim > 0:
            if z is None:
                raise InputError("RadialWarp: this warp is decoded from the spatial latent; pass z")
            return self.decode(z)
        return self.params

    def forward(self, r: torch.Tensor, z: torch.Tensor | None = None) -> torch.Tensor:
        p = self.parameters_for(z)
        return warp_radius(r, p[..., :self.terms], p[..., self.terms:])

    def flops(self) -> int:
        """Per evaluation: the decode layer (if any), softmax, K powers (log + mul + exp) and the weighted sum."""
        decode = 2 * self.latent_dim * 2 * self.terms if self.latent_dim > 0 else 0
        return decode + 4 * self.terms + 3 * self.terms + 2 * self.terms + 1
