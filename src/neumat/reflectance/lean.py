"""LEAN prefiltering of surface parameters for coarse mip levels (Olano and Baker 2010), as Real-Time Neural
Appearance Models bake its latent pyramid (Zeltner et al. 2024, Sec. 5.1: "we prefilter the material parameters
k(x) (using LEAN) for coarse MIP levels").

The coarse texel keeps the slope moments: n' = normalize(B_x, B_y, 1), alpha'^2 = E[alpha^2] +
trace(E[b b^T] - B B^T); other parameters are box-averaged.

Details: docs/notes/reflectance.md, section `neumat.reflectance.lean`.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

from ..core.errors import InputError


@dataclass(frozen=True)
class NormalGroup:
    """Channels of one layer's slope distribution among the surface parameters: a unit normal at channels
    normal .. normal + 2 and a roughness channel with alpha = roughness ** alpha_power (principled: 2; a GGX
    alpha stored directly: 1)."""

    normal: int
    roughness: int
    alpha_power: float = 2.0


def lean_pyramid(finest: torch.Tensor, groups: list[NormalGroup], levels: int) -> list[torch.Tensor]:
    """Parameter maps (K, H / 2^l, W / 2^l) for l = 0 .. levels - 1 from finest (K, H, W) (module docstring)."""
    if finest.dim() != 3:
        raise InputError(f"lean_pyramid: expected (K, H, W) parameter maps, got shape {tuple(finest.shape)}")
    k, h, w = finest.shape
    if levels < 1 or (h >> (levels - 1)) < 1 or (w >> (levels - 1)) < 1:
        raise InputError(f"lean_pyramid: {levels} levels do not fit {h} x {w} texels")
    for g in groups:
        if not (0 <= g.normal <= k - 3 and 0 <= g.roughness < k) or g.roughness in range(g.normal, g.normal + 3):
            raise InputError(f"lean_pyramid: {g} does not fit {k} parameter channels")
    x = finest.double()
    moments = []                       # per group: b_x, b_y, b_x^2 + b_y^2 + alpha^2
    for g in groups:
        n = x[g.normal:g.normal + 3]
        nz = n[2].clamp(min=1e-3)
        bx, by = n[0] / nz, n[1] / nz
        alpha2 = x[g.roughness].clamp(min=0) ** (2 * g.alpha_power)
        moments.append(torch.stack([bx, by, bx * bx + by * by + alpha2]))
    out = [finest]
    for level in range(1, levels):
        pool = lambda t: F.avg_pool2d(t[None], 1 << level)[0]  # noqa: E731
        coarse = pool(x)
        for g, m in zip(groups, moments):
            bx, by, second = pool(m)
            n = torch.stack([bx, by, torch.ones_like(bx)])
            coarse[g.normal:g.normal + 3] = n / n.norm(dim=0, keepdim=True)
            alpha2 = (second - bx * bx - by * by).clamp(min=0, max=1)
            coarse[g.roughness] = alpha2 ** (1 / (2 * g.alpha_power))
        out.append(coarse.to(finest.dtype))
    return out
