"""Textures over uv with wrap tiling: bilinear lookup, mip pyramids and differentiable anisotropic filtering.

Texture layout: (C, H, W) tensors in image orientation, as `neumat.io.texture_set`: texel (row i, column j)
has its centre at uv = ((j + 0.5) / W, 1 - (i + 0.5) / H); u points right, v up; lookups wrap (tile).

Footprints are Gaussian filters in uv given by their covariance Sigma (N, 2, 2) (uv units^2), the
`Query.footprint` convention. Anisotropic filtering follows texture hardware (Heckbert / EXT_texture_filter_
anisotropic): up to `max_probes` trilinear probes along the major axis, at the mip level of the minor axis
(of the major axis / max_probes when that is coarser). Level choice and probe spacing match the second moments
of the Gaussian: a trilinear probe of level l (box pyramid + bilinear tent) has a standard deviation of about
2^l / 2 texels per axis, so a Gaussian of standard deviation s texels uses lod = log2(2 s); n probes spaced d
apart add a variance d^2 (n^2 - 1) / 12 along the major axis, which makes up major^2 - minor^2.
"""
from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from ..core.checks import check_finite, check_shape
from ..core.errors import InputError


def texel_coords(uv: torch.Tensor, height: int, width: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Continuous texel coordinates (x, y), each (N,), of uv (N, 2): x = u W - 1/2, y = (1 - v) H - 1/2."""
    return uv[:, 0] * width - 0.5, (1 - uv[:, 1]) * height - 0.5


def bilinear(tex: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
    """Bilinear lookup with wrap tiling: tex (C, H, W), uv (N, 2) -> (N, C); differentiable in tex.
    One fused `grid_sample` over the texture padded circularly by one texel (corner-aligned grid)."""
    c, h, w = tex.shape
    x, y = texel_coords(torch.remainder(uv.to(tex.dtype), 1.0), h, w)  # in [-1/2, W - 1/2], [-1/2, H - 1/2]
    grid = torch.stack([(x + 1) * (2 / (w + 1)) - 1, (y + 1) * (2 / (h + 1)) - 1], -1)
    padded = F.pad(tex.unsqueeze(0), (1, 1, 1, 1), mode="circular")
    out = F.grid_sample(padded, grid.view(1, 1, -1, 2), mode="bilinear", padding_mode="border", align_corners=True)
    return out.view(c, -1).t()


def box_pyramid(tex: torch.Tensor) -> list[torch.Tensor]:
    """Mip levels of tex (C, H, W) down to 1 x 1 by 2 x 2 box averaging (odd sizes: the last texel row /
    column is averaged in with the area-weighted resize). Level 0 is `tex` itself."""
    levels = [tex]
    while max(levels[-1].shape[1:]) > 1:
        c, h, w = levels[-1].shape
        size = (max(1, h // 2), max(1, w // 2))
        levels.append(F.adaptive_avg_pool2d(levels[-1].unsqueeze(0), size)[0])
    return levels


def pyramid_levels(height: int, width: int) -> int:
    """Number of levels of a full pyramid of a height x width texture (down to 1 x 1)."""
    return 1 + int(math.floor(math.log2(max(height, width))))


def check_footprint(footprint: torch.Tensor, name: str = "footprint") -> torch.Tensor:
    """Check (N, 2, 2) symmetric positive definite covariances; raise InputError naming the first bad one."""
    check_shape(footprint, name, (-1, 2, 2))
    check_finite(footprint, name)
    if footprint.shape[0] == 0:
        return footprint
    a, b, b2, c = footprint[:, 0, 0], footprint[:, 0, 1], footprint[:, 1, 0], footprint[:, 1, 1]
    scale = footprint.abs().amax(dim=(1, 2)).clamp(min=1e-30)
    asym = (b - b2).abs() > 1e-5 * scale
    if bool(asym.any()):
        i = int(asym.nonzero()[0])
        raise InputError(f"{name}[{i}]: expected a symmetric matrix, got {footprint[i].tolist()}")
    det = a * c - b * b
    bad = (a <= 0) | (c <= 0) | (det <= 0)
    if bool(bad.any()):
        i = int(bad.nonzero()[0])
        raise InputError(f"{name}[{i}]: expected a positive definite covariance (positive diagonal and "
                         f"determinant), got {footprint[i].tolist()} with determinant {float(det[i]):.3g}")
    return footprint


def footprint_axes(cov: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Standard deviations along the major and minor axes (N,) and the unit major direction (N, 2) of
    covariances cov (N, 2, 2)."""
    a, b, c = cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 1]
    mean, half = (a + c) / 2, torch.sqrt(((a - c) / 2) ** 2 + b * b)
    theta = 0.5 * torch.atan2(2 * b, a - c)
    major = (mean + half).clamp(min=0).sqrt()
    minor = (mean - half).clamp(min=0).sqrt()
    return major, minor, torch.stack([torch.cos(theta), torch.sin(theta)], -1)


def trilinear(levels: list[torch.Tensor], uv: torch.Tensor, lod: torch.Tensor) -> torch.Tensor:
    """Trilinear lookup: bilinear in the two levels around lod (N,) (clamped to the pyramid), blended."""
    lod = lod.clamp(0, len(levels) - 1)
    lo = lod.floor().long()
    t = (lod - lo).unsqueeze(-1).to(levels[0].dtype)
    out = uv.new_zeros(uv.shape[0], levels[0].shape[0], dtype=levels[0].dtype)
    for l, tex in enumerate(levels):
        w = torch.where((lo == l).unsqueeze(-1), 1 - t, 0.0) + torch.where((lo + 1 == l).unsqueeze(-1), t, 0.0)
        sel = (w[:, 0] > 0).nonzero().squeeze(-1)
        if sel.numel():
            out = out.index_add(0, sel, w[sel] * bilinear(tex, uv[sel]))
    return out


def filter_anisotropic(levels: list[torch.Tensor], uv: torch.Tensor, footprint: torch.Tensor,
                       max_probes: int = 16) -> torch.Tensor:
    """Gaussian-footprint filtered lookup of a pyramid (see module docstring).

    levels: mip levels (C, H_l, W_l), level 0 finest, level l about 2^l times coarser; uv (N, 2);
    footprint (N, 2, 2) covariance in uv^2. Returns (N, C), differentiable in the levels.
    """
    _, h, w = levels[0].shape
    scale = torch.tensor([w, h], dtype=footprint.dtype, device=footprint.device)
    cov_t = footprint * scale.view(1, 2, 1) * scale.view(1, 1, 2)  # in level-0 texels^2
    major, minor, axis = footprint_axes(cov_t)
    minor = minor.clamp(min=1e-12)
    n = torch.ceil(major / minor).clamp(1, max_probes)
    sigma = torch.maximum(minor, major / max_probes)  # per-probe standard deviation (texels)
    lod = torch.log2((2 * sigma).clamp(min=1e-12))
    spacing = torch.sqrt((12 * (major ** 2 - sigma ** 2)).clamp(min=0) / (n * n - 1).clamp(min=1))
    k = torch.arange(max_probes, device=uv.device, dtype=uv.dtype)
    offset = (k.unsqueeze(0) - (n.unsqueeze(-1) - 1) / 2) * spacing.unsqueeze(-1)  # (N, P) texels along axis
    used = k.unsqueeze(0) < n.unsqueeze(-1)
    delta = offset.unsqueeze(-1) * axis.unsqueeze(1) / scale  # (N, P, 2) uv offsets
    rows, probe = used.nonzero(as_tuple=True)
    values = trilinear(levels, uv[rows] + delta[rows, probe], lod[rows])
    out = uv.new_zeros(uv.shape[0], levels[0].shape[0], dtype=levels[0].dtype)
    return out.index_add(0, rows, values / n[rows].unsqueeze(-1).to(values.dtype))


def isotropic_footprint(lod: torch.Tensor, width: int) -> torch.Tensor:
    """The covariance (N, 2, 2) in uv^2 that `filter_anisotropic` maps to mip level lod (N,) of a texture
    `width` texels wide: standard deviation 2^lod / 2 texels."""
    s = torch.exp2(lod) / (2 * width)
    eye = torch.eye(2, dtype=lod.dtype, device=lod.device)
    return (s * s).view(-1, 1, 1) * eye


class LatentPyramid(nn.Module):
    """A learned mip pyramid of latent vectors, every level its own parameter (C, size >> l, size >> l).

    forward(uv (N, 2), footprint (N, 2, 2) or None, lod (N,) or None) -> (N, C): anisotropic filtering
    with a footprint, trilinear with a lod only, bilinear at the finest level with neither. An optional
    `precondition` module (e.g. `neumat.nn.preconditioner.FrequencyPreconditioner`) maps each raw level
    parameter to the texture used in the forward pass.
    """

    def __init__(self, channels: int, size: int, init_std: float = 0.1, max_probes: int = 16,
                 precondition: nn.Module | None = None) -> None:
        super().__init__()
        if isinstance(size, bool) or not isinstance(size, int) or size < 1 or size & (size - 1):
            raise InputError(f"LatentPyramid.size: expected a power of two, got {size!r}")
        if isinstance(channels, bool) or not isinstance(channels, int) or channels < 1:
            raise InputError(f"LatentPyramid.channels: expected a positive integer, got {channels!r}")
        self.size, self.channels, self.max_probes = size, channels, max_probes
        self.raw = nn.ParameterList(nn.Parameter(torch.randn(channels, size >> l, size >> l) * init_std)
                                    for l in range(pyramid_levels(size, size)))
        self.precondition = precondition

    def levels(self) -> list[torch.Tensor]:
        """The textures of the forward pass, finest first."""
        if self.precondition is None:
            return list(self.raw)
        return [self.precondition(t) for t in self.raw]

    def forward(self, uv: torch.Tensor, footprint: torch.Tensor | None = None,
                lod: torch.Tensor | None = None) -> torch.Tensor:
        levels = self.levels()
        if footprint is not None:
            return filter_anisotropic(levels, uv, footprint, self.max_probes)
        if lod is not None:
            return trilinear(levels, uv, lod.to(uv.dtype))
        return bilinear(levels[0], uv)

    def num_parameters(self) -> int:
        return sum(p.numel() for p in self.raw)
