"""What regime a texture set is in for a multi-scale fit: how much normal and roughness detail it has, and how
far its filtered appearance is from a product of a spatial and a directional factor.

Timonen et al. 2025 select materials whose filtered appearance is not "simple averages of albedos": at those,
concatenating spatial and directional features (tripleplane) is the easy path and gating adds nothing. The
separability rank measures that: for a footprint of f texels, the log-luminance of the footprint-filtered SVBRDF
at P positions (a grid with f-texel spacing) x D direction pairs forms a P x D matrix; each column's mean over
the positions (the set's average directional behaviour) is removed, and the rank r is the fewest singular values
holding `energy` of what remains, less the Monte Carlo noise of the footprint samples (two independent
evaluations: the noise energy of their mean is |A - B|^2 / 4). A separable appearance, f = a(x) b(w), has r = 1
(log f = log a + log b: one spatial profile); r = 0 means no spatial variation above the noise; r grows with the
coupling between position and direction.
"""
from __future__ import annotations

import math

import torch

from ..core.checks import check_int, check_number
from ..core.errors import InputError
from ..core.query import Query
from ..io.texture_set import TextureSet
from ..warp.hemisphere import sample_cosine_hemisphere
from .svbrdf import SVBRDF

#: luminance weights of linear RGB (Rec. 709)
LUMINANCE = (0.2126, 0.7152, 0.0722)


def separability_rank(textures: TextureSet, footprint_texels: float, pairs: int = 32, samples: int = 16,
                      energy: float = 0.99, max_positions: int = 4096, seed: int = 0) -> int:
    """The separability rank (module docstring) at a footprint of `footprint_texels` texels (the standard
    deviation of an isotropic Gaussian filter; positions on a grid of that spacing, at most `max_positions`),
    `pairs` cosine-distributed (wi, wo), `samples` footprint samples per value."""
    check_number(footprint_texels, "separability_rank footprint_texels", 0, strict=True)
    check_int(pairs, "separability_rank pairs", 2)
    check_int(max_positions, "separability_rank max_positions", 2)
    if not 0 < energy < 1:
        raise InputError(f"separability_rank energy: expected a fraction in (0, 1), got {energy!r}")
    h, w = textures.size
    step = max(footprint_texels, math.sqrt(h * w / max_positions))
    rows, cols = max(int(h / step), 1), max(int(w / step), 1)
    v, u = torch.meshgrid((torch.arange(rows) + 0.5) / rows, (torch.arange(cols) + 0.5) / cols, indexing="ij")
    uv = torch.stack([u.flatten(), v.flatten()], -1)
    g = torch.Generator().manual_seed(seed)
    wi = sample_cosine_hemisphere(torch.rand(pairs, 2, generator=g))
    wo = sample_cosine_hemisphere(torch.rand(pairs, 2, generator=g))
    p = len(uv)
    sigma = (footprint_texels / max(h, w)) ** 2 * torch.eye(2).expand(p * pairs, 2, 2)
    q = Query(wi=wi.repeat(p, 1), wo=wo.repeat(p, 1), uv=uv.repeat_interleave(pairs, 0), footprint=sigma.contiguous())
    weights = torch.tensor(LUMINANCE)

    def log_luminance(sample_seed: int) -> torch.Tensor:
        with torch.no_grad():
            rgb = SVBRDF(textures, samples=samples, seed=sample_seed).eval(q)
        return torch.log((rgb * weights).sum(-1).clamp(min=0) + 1e-4).reshape(p, pairs).double()

    return noise_corrected_rank(log_luminance(2 * seed), log_luminance(2 * seed + 1), energy)


def noise_corrected_rank(a: torch.Tensor, b: torch.Tensor, energy: float = 0.99) -> int:
    """The fewest singular values of the column-centred mean of two noisy estimates a, b (P, D) of one matrix
    that hold `energy` of its energy less the noise's (|a - b|^2 / 4); 0 when nothing is left above the noise."""
    mean = (a + b) / 2
    mean = mean - mean.mean(0, keepdim=True)
    signal = float((mean ** 2).sum()) - float(((a - b) ** 2).sum()) / 4
    if signal <= 0:
        return 0
    s2 = torch.linalg.svdvals(mean) ** 2
    return min(int((s2.cumsum(0) < energy * signal).sum()) + 1, len(s2))


def normal_tilt_deg(textures: TextureSet) -> torch.Tensor:
    """Each texel's normal-map tilt: degrees between its shading normal and the geometric normal, (H, W)."""
    return torch.rad2deg(torch.acos(textures.normal.float()[..., 2].clamp(-1, 1)))


def texture_statistics(textures: TextureSet, footprints: tuple[float, ...] = (1, 4, 16), pairs: int = 32,
                       samples: int = 16, energy: float = 0.99, seed: int = 0) -> dict:
    """The regime of `textures`: size, normal tilt (degrees from the geometric normal: mean and 95th
    percentile), roughness (mean, standard deviation, 5-95 % range), mean metalness, and the separability rank
    at each footprint in texels (module docstring; footprints larger than the set are left out)."""
    r = textures.roughness.float().flatten()
    tilt = normal_tilt_deg(textures).flatten()
    q = torch.quantile(r, torch.tensor([0.05, 0.95], device=r.device))
    size = max(textures.size)
    return {"name": textures.name, "size": list(textures.size), "tilt_deg": float(tilt.mean()),
            "tilt_p95_deg": float(torch.quantile(tilt, 0.95)), "roughness_mean": float(r.mean()),
            "roughness_std": float(r.std()), "roughness_p5_p95": [float(q[0]), float(q[1])],
            "metalness_mean": float(textures.metalness.float().mean()),
            "separability_rank": {f"{f:g}": separability_rank(textures, f, pairs, samples, energy, seed=seed)
                                  for f in footprints if f <= size / 2}}
