"""The training query distribution of Timonen et al. 2025, Sec. 4.2: directions, uv and footprints.

wi and wo cosine-weighted, uv uniform, footprints as the paper's Eq. 9 (`Query.footprint` holds their
covariance), the level range shifted to the source's texel size by default (`texel_relative`). Registered as
the "footprint" and "footprint-uv" query samplers.

Details: src/neumat/methods/latent_mlp/NOTES.md, section `neumat.fit.footprint_queries`.
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import torch

from ..core.config import bounded
from ..core.errors import InputError
from ..core.material import Material
from ..core.query import Query
from ..warp.hemisphere import sample_cosine_hemisphere
from ..warp.uniform import uniform
from .query_samplers import QUERY_SAMPLERS, QueryDraw

#: paper values: log2 of the footprint scale (uv units) spans [L_MIN, L_MAX]
L_MIN, L_MAX = -13.0, 1.0
#: texture size (texels) at which the paper's range holds
PAPER_TEXELS = 1024
#: paper value: exponent B of the fine-level bias e2 = (exp(B e3) - 1) / (exp(B) - 1)
FINE_BIAS = 5.0
#: paper value: standard deviation of z2 in the elongation (1 + z2) / cos theta_o
ELONGATION_STD = 0.2


@dataclass
class FootprintOptions:
    """Recipe options of the fits that draw these footprints (the paper's values by default)."""

    fine_bias: float = bounded(FINE_BIAS, gt=0)
    """Exponent B of the fine-level bias of the footprint scales (larger: fine footprints drawn more often)."""
    elongation_std: float = bounded(ELONGATION_STD, ge=0)
    """Standard deviation of z2 in the footprints' elongation (1 + z2) / cos theta_o."""
    target_samples: int = bounded(0, ge=0)
    """Monte Carlo positions per footprint of each training target (`with_target_samples`); 0: the source's own
    (a texture set's default, the paper's 256). Why: on a CPU the 256-position targets are most of a step's time,
    and a target's noise averages out over the steps (unbiased estimates, an L2-type loss)."""


def with_target_samples(source: Material, samples: int) -> Material:
    """`source`, or with `samples` > 0 a shallow copy whose footprint estimates use `samples` positions (a source
    that filters footprints by Monte Carlo has a `samples` attribute: `neumat.reflectance.svbrdf.SVBRDF`,
    layered and conductor sets); a source without footprint filtering is returned as it is."""
    if samples <= 0 or not hasattr(source, "samples"):
        return source
    out = copy.copy(source)
    out.samples = int(samples)
    return out


def footprint_scale(e3: torch.Tensor, l_min: float = L_MIN, l_max: float = L_MAX,
                    fine_bias: float = FINE_BIAS) -> torch.Tensor:
    """e1 (N,) in uv units from uniform e3 (N,): log2 e1 = l_min + (l_max - l_min)(exp(B e3) - 1)/(exp(B) - 1),
    B = fine_bias."""
    e2 = torch.expm1(fine_bias * e3) / math.expm1(fine_bias)
    return torch.exp2(l_min + (l_max - l_min) * e2)


def footprint_covariance(scale: torch.Tensor, elongation: torch.Tensor, angle: torch.Tensor) -> torch.Tensor:
    """C = scale^2 R(angle)^T diag(elongation^2, 1) R(angle), (N, 2, 2), for (N,) inputs (Eq. 9)."""
    c, s = torch.cos(angle), torch.sin(angle)
    rot = torch.stack([torch.stack([c, -s], -1), torch.stack([s, c], -1)], -2)
    d = torch.stack([elongation * elongation, torch.ones_like(elongation)], -1)
    cov = rot.transpose(-1, -2) @ (d.unsqueeze(-1) * rot)
    cov = 0.5 * (cov + cov.transpose(-1, -2))  # exactly symmetric
    return (scale * scale).view(-1, 1, 1) * cov


def sample_footprints(cos_view: torch.Tensor, u: torch.Tensor, z2: torch.Tensor, min_cos: float = 0.01,
                      l_min: float = L_MIN, l_max: float = L_MAX, fine_bias: float = FINE_BIAS) -> torch.Tensor:
    """Eq. 9 covariances (N, 2, 2) from cos theta_o (N,), uniforms u (N, 2) (e3, u3 / 2 pi) and
    z2 (N,) ~ N(0, elongation_std^2)."""
    scale = footprint_scale(u[:, 0], l_min, l_max, fine_bias)
    elongation = (1 + z2).clamp(min=0.2) / cos_view.clamp(min=min_cos)
    return footprint_covariance(scale, elongation, 2 * math.pi * u[:, 1])


def source_texels(source: Material) -> int | None:
    """max(H, W) of the source's texture maps (`source.textures.size`), or None when it has none."""
    size = getattr(getattr(source, "textures", None), "size", None)
    return None if size is None else int(max(size))


def texel_shift(source: Material) -> float:
    """log2(PAPER_TEXELS / S) for a source of S x S texels (0 when its size is unknown): added to l_min and
    l_max it keeps the paper's footprint distribution in texels."""
    texels = source_texels(source)
    return 0.0 if texels is None else math.log2(PAPER_TEXELS / texels)


@QUERY_SAMPLERS.register("footprint")
def footprint_queries(source: Material, model=None, min_cos: float = 0.01, l_min: float = L_MIN,
                      l_max: float = L_MAX, texel_relative: bool = True, fine_bias: float = FINE_BIAS,
                      elongation_std: float = ELONGATION_STD) -> QueryDraw:
    """draw(n, generator, device) -> Query with cosine-weighted wi, wo, uniform uv and Eq. 9 footprints;
    with `texel_relative`, [l_min, l_max] is shifted by `texel_shift(source)` (see the module docstring)."""
    if getattr(source, "full_sphere", False):
        raise InputError("query sampler 'footprint' draws surface queries, but the source spans the whole sphere")
    if not (0 < min_cos <= 1) or not (l_min < l_max) or not fine_bias > 0 or not elongation_std >= 0:
        raise InputError(f"footprint_queries: expected 0 < min_cos <= 1, l_min < l_max, fine_bias > 0 and "
                         f"elongation_std >= 0, got min_cos={min_cos}, l_min={l_min}, l_max={l_max}, "
                         f"fine_bias={fine_bias}, elongation_std={elongation_std}")
    if texel_relative:
        shift = texel_shift(source)
        l_min, l_max = l_min + shift, l_max + shift

    def draw(n: int, generator: torch.Generator, device) -> Query:
        u = uniform(n, 8, generator, device)
        z2 = elongation_std * torch.randn(n, generator=generator, device=generator.device).to(device)
        wi = sample_cosine_hemisphere(u[:, 0:2])
        wo = sample_cosine_hemisphere(u[:, 2:4])
        cov = sample_footprints(wo[:, 2], u[:, 6:8], z2, min_cos, l_min, l_max, fine_bias)
        return Query(wi, wo, uv=u[:, 4:6], footprint=cov)

    return draw


@QUERY_SAMPLERS.register("footprint-uv")
def footprint_uv_queries(source: Material, model=None, **kwargs) -> QueryDraw:
    """The "footprint" sampler with the paper's log2-scale range in uv units, whatever the source's size
    (`kwargs`: those of `footprint_queries`)."""
    return footprint_queries(source, model, texel_relative=False, **kwargs)
