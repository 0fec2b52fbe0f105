"""Random Fourier feature maps (Tancik et al. 2020), as NeuPreSS uses them (TG et al., Eq. 8)."""
from __future__ import annotations

import math

import torch
from torch import nn

from neumat.core.checks import check_int
from neumat.core.errors import InputError


class FourierFeatures(nn.Module):
    """F(v) = [cos(2 pi G v), sin(2 pi G v)] with a static G (n_features, in_dim) drawn once from
    N(mean, std^2). forward: (..., in_dim) -> (..., 2 n_features). G is a buffer: saved, never trained."""

    def __init__(self, in_dim: int, n_features: int = 256, mean: float = 18.0, std: float = 1.0, seed: int = 0) -> None:
        super().__init__()
        for name, v in (("in_dim", in_dim), ("n_features", n_features)):
            check_int(v, f"FourierFeatures.{name}")
        if not (math.isfinite(mean) and math.isfinite(std) and std >= 0):
            raise InputError(f"FourierFeatures: expected a finite mean and std >= 0, got mean={mean!r}, std={std!r}")
        gen = torch.Generator().manual_seed(int(seed))
        self.register_buffer("G", mean + std * torch.randn(n_features, in_dim, generator=gen))
        self.in_dim, self.out_dim = in_dim, 2 * n_features

    def forward(self, v: torch.Tensor) -> torch.Tensor:
        if v.shape[-1] != self.in_dim:
            raise InputError(f"FourierFeatures input: expected last dimension {self.in_dim}, got {tuple(v.shape)}")
        a = (2 * math.pi) * (v.to(self.G.dtype) @ self.G.T)
        return torch.cat([torch.cos(a), torch.sin(a)], -1)

    def flops(self) -> int:
        """Multiply-adds of G v (2 per entry) plus one cos and one sin per feature counted as 1 each."""
        return 2 * self.G.numel() + self.out_dim
