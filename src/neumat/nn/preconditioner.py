"""Frequency-domain texture preconditioner (Timonen et al. 2025, Sec. 4.3).

A learned texture is stored as raw parameters P (C, H, W); the forward pass uses the blurred texture

    T = IFFT2( FFT2(P) * K ),   K(fx, fy) = 1 / (1 + A sqrt(fx^2 + fy^2))

with fx, fy in cycles per texel (`fftfreq`) and circular boundaries: K is real, even and K(0, 0) = 1, so P -> T is
linear, symmetric (its backward is the same filter) and invertible. The paper uses A = 10 spatially, 5 angularly.
`FrequencyPreconditioner` packs two channels into one complex FFT; `flat` / `many` precondition a mip pyramid at
once (small levels by one block-diagonal matrix). Details: src/neumat/methods/latent_mlp/NOTES.md (row "training
step on a 1K set").
"""
from __future__ import annotations

import math

import torch
from torch import nn

from ..core.errors import InputError

#: the paper's strengths
SPATIAL_STRENGTH = 10.0
ANGULAR_STRENGTH = 5.0
#: textures of at most this many texels (per channel) are preconditioned by a dense matrix in `flat`
SMALL_TEXELS = 256


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


def precondition_matrix(height: int, width: int, strength: float, dtype=torch.float32, device=None) -> torch.Tensor:
    """The map P -> T as a (H W, H W) matrix M on row-major flattened textures: T_flat = P_flat @ M."""
    basis = torch.eye(height * width, dtype=torch.float64).view(-1, height, width)
    return precondition(basis, strength).reshape(height * width, -1).to(dtype=dtype, device=device)


def flat_levels(levels: list[torch.Tensor]) -> torch.Tensor:
    """Mip levels (C, H_l, W_l) flattened row-major and concatenated, finest first: (C, sum H_l W_l)."""
    c = levels[0].shape[0]
    return torch.cat([tex.reshape(c, -1) for tex in levels], 1)


def full_kernel(height: int, width: int, strength: float, dtype=torch.float32, device=None) -> torch.Tensor:
    """K (H, W) on the full `fft2` frequency grid (real and even)."""
    fy = torch.fft.fftfreq(height, dtype=dtype, device=device)
    fx = torch.fft.fftfreq(width, dtype=dtype, device=device)
    return 1.0 / (1.0 + strength * torch.sqrt(fy[:, None] ** 2 + fx[None, :] ** 2))


def _filter(x: torch.Tensor, k: torch.Tensor) -> torch.Tensor:
    """IFFT2(FFT2(x) K) of real x (..., H, W) for a real, even K (H, W) on the full grid: the channels packed two
    to a complex one (a real + i b; the filter keeps real inputs real, so the parts do not mix), one complex
    transform each way (on one CPU thread about 0.6x the time of rfft2 + irfft2, whose inverse is slow)."""
    h, w = x.shape[-2:]
    flat = x.reshape(-1, h, w)
    n = flat.shape[0]
    half = (n + 1) // 2
    second = flat[half:] if n % 2 == 0 else torch.cat([flat[half:], flat.new_zeros(1, h, w)])
    y = torch.fft.ifft2(torch.fft.fft2(torch.complex(flat[:half], second)).mul_(k))
    out = torch.empty_like(flat)
    out[:half] = y.real
    out[half:] = y.imag[:n - half]
    return out.reshape(x.shape)


class _SelfAdjointFilter(torch.autograd.Function):
    """x -> IFFT2(FFT2(x) K) for a real K that is even (K(f) = K(-f)): a circular convolution with a real, even
    kernel, a symmetric linear map, so the gradient is the same filter of the output gradient."""

    @staticmethod
    def forward(ctx, x: torch.Tensor, k: torch.Tensor) -> torch.Tensor:
        ctx.save_for_backward(k)
        return _filter(x, k)

    @staticmethod
    def backward(ctx, grad: torch.Tensor):
        (k,) = ctx.saved_tensors
        return _filter(grad.contiguous(), k), None


class FrequencyPreconditioner(nn.Module):
    """Module form of `precondition` with a fixed strength A; forward(raw (..., H, W)) -> (..., H, W).
    Kernels and matrices are cached per size, dtype and device."""

    def __init__(self, strength: float) -> None:
        super().__init__()
        if not (isinstance(strength, (int, float)) and math.isfinite(strength) and strength >= 0):
            raise InputError(f"FrequencyPreconditioner.strength: expected a finite number >= 0, got {strength!r}")
        self.strength = float(strength)
        self._cache: dict[tuple, torch.Tensor] = {}

    def _cached(self, key: tuple, make) -> torch.Tensor:
        if key not in self._cache:
            self._cache[key] = make()
        return self._cache[key]

    def forward(self, raw: torch.Tensor) -> torch.Tensor:
        if self.strength == 0:
            return raw
        h, w = raw.shape[-2:]
        k = self._cached(("full kernel", h, w, raw.dtype, raw.device),
                         lambda: full_kernel(h, w, self.strength, raw.dtype, raw.device))
        return _SelfAdjointFilter.apply(raw, k)

    def flat(self, raws: list[torch.Tensor]) -> torch.Tensor:
        """The preconditioned textures of raws [(C, H_i, W_i)], flattened row-major and concatenated:
        (C, sum H_i W_i). Textures of at most SMALL_TEXELS texels go through one block-diagonal matrix product."""
        if self.strength == 0:
            return flat_levels(raws)
        c = raws[0].shape[0]
        return torch.cat([tex.reshape(c, -1) for tex in self.many(raws)], 1)

    def many(self, raws: list[torch.Tensor]) -> list[torch.Tensor]:
        """The preconditioned textures [(C, H_i, W_i)] of raws, as `flat` computes them (unflattened)."""
        if self.strength == 0:
            return list(raws)
        c = raws[0].shape[0]
        small = [i for i, raw in enumerate(raws) if raw.shape[-2] * raw.shape[-1] <= SMALL_TEXELS]
        pieces = [None if i in small else self(raw) for i, raw in enumerate(raws)]
        if small:
            sizes = tuple(tuple(raws[i].shape[-2:]) for i in small)
            dtype, device = raws[0].dtype, raws[0].device
            matrix = self._cached(("matrix", sizes, dtype, device), lambda: torch.block_diag(
                *(precondition_matrix(h, w, self.strength, dtype, device) for h, w in sizes)))
            dense = torch.cat([raws[i].reshape(c, -1) for i in small], 1) @ matrix
            for i, part in zip(small, dense.split([h * w for h, w in sizes], 1)):
                pieces[i] = part.view(c, *raws[i].shape[-2:])
        return pieces

    def extra_repr(self) -> str:
        return f"strength={self.strength}"
