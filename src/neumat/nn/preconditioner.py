"""Frequency-domain texture preconditioner (Timonen et al. 2025, Sec. 4.3).

A learned texture is stored as raw parameters P (C, H, W); the forward pass uses the blurred texture

    T = IFFT2( FFT2(P) * K ),   K(fx, fy) = 1 / (1 + A sqrt(fx^2 + fy^2))

with fx, fy in cycles per texel (numpy/torch `fftfreq`, in [-1/2, 1/2)) and circular boundaries. K is real,
even and K(0, 0) = 1, so T is real, keeps the texture mean, and the map P -> T is linear and invertible:
it does not change the optimum, but neighbouring texels move together early in training, as with Nicolet et
al.'s "large steps". The paper uses A = 10 for the spatial texture and A = 5 for the angular textures.
"""
from __future__ import annotations

import math

import torch
from torch import nn

from ..core.errors import InputError

#: the paper's strengths
SPATIAL_STRENGTH = 10.0
ANGULAR_STRENGTH = 5.0


def preconditioner_kernel(height: int, width: int, strength: float, dtype=torch.float32, device=None) -> torch.Tensor:
    """K (H, W // 2 + 1) on the `rfft2` frequency grid."""
    fy = torch.fft.fftfreq(height, dtype=dtype, device=device)
    fx = torch.fft.rfftfreq(width, dtype=dtype, device=device)
    return 1.0 / (1.0 + strength * torch.sqrt(fy[:, None] ** 2 + fx[None, :] ** 2))


def precondition(raw: torch.Tensor, strength: float) -> torch.Tensor:
    """T = IFFT2(FFT2(raw) K) over the last two dimensions of raw (..., H, W); differentiable."""
    h, w = raw.shape[-2:]
    k = preconditioner_kernel(h, w, strength, raw.dtype, raw.device)
    return torch.fft.irfft2(torch.fft.rfft2(raw) * k, s=(h, w))


def unprecondition(texture: torch.Tensor, strength: float) -> torch.Tensor:
    """Raw parameters whose preconditioned texture is `texture` (the inverse map; K > 0 everywhere)."""
    h, w = texture.shape[-2:]
    k = preconditioner_kernel(h, w, strength, texture.dtype, texture.device)
    return torch.fft.irfft2(torch.fft.rfft2(texture) / k, s=(h, w))


class FrequencyPreconditioner(nn.Module):
    """Module form of `precondition` with a fixed strength A; forward(raw (..., H, W)) -> (..., H, W)."""

    def __init__(self, strength: float) -> None:
        super().__init__()
        if not (isinstance(strength, (int, float)) and math.isfinite(strength) and strength >= 0):
            raise InputError(f"FrequencyPreconditioner.strength: expected a finite number >= 0, got {strength!r}")
        self.strength = float(strength)

    def forward(self, raw: torch.Tensor) -> torch.Tensor:
        return raw if self.strength == 0 else precondition(raw, self.strength)

    def extra_repr(self) -> str:
        return f"strength={self.strength}"
