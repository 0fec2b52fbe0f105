"""GGX (Trowbridge-Reitz) microfacet distribution: the normal distribution D(m) and Smith masking G1(w).

Functional, differentiable torch in the local frame (z = normal, x = the alpha_x direction); roughness
arguments are floats or (N,) tensors. The GGX warps (`neumat.warp.ggx`) and the microfacet BRDFs
(`neumat.reflectance.microfacet`) both build on these.
"""
from __future__ import annotations

import math

import torch

from ..core.checks import check_shape


def per_query(x, n: int, ref: torch.Tensor, name: str) -> torch.Tensor:
    """A float or (N,) tensor as an (N,) tensor on the device / dtype of `ref`."""
    t = torch.as_tensor(x, dtype=ref.dtype, device=ref.device)
    if t.dim() == 0:
        t = t.expand(n)
    return check_shape(t, name, (n,))


def _alpha(x, n: int, ref: torch.Tensor, name: str):
    """A roughness argument as a Python float (cheap scalar arithmetic) or an (N,) tensor."""
    if isinstance(x, (int, float)) and not isinstance(x, bool):
        return float(x)
    return per_query(x, n, ref, name)


def ggx_ndf(m: torch.Tensor, alpha_x, alpha_y) -> torch.Tensor:
    """GGX normal distribution D(m) (N,) per steradian for unit m (N, 3); 0 where m_z <= 0."""
    ax, ay = _alpha(alpha_x, m.shape[0], m, "alpha_x"), _alpha(alpha_y, m.shape[0], m, "alpha_y")
    q = (m[:, 0] / ax) ** 2 + (m[:, 1] / ay) ** 2 + m[:, 2] ** 2
    d = 1 / (math.pi * ax * ay * q * q)
    return torch.where(m[:, 2] > 0, d, torch.zeros_like(d))


def smith_g1(w: torch.Tensor, alpha_x, alpha_y) -> torch.Tensor:
    """Smith masking G1(w) = 2 w_z / (w_z + sqrt(w_z^2 + ax^2 w_x^2 + ay^2 w_y^2)) (N,); 0 where w_z <= 0."""
    ax, ay = _alpha(alpha_x, w.shape[0], w, "alpha_x"), _alpha(alpha_y, w.shape[0], w, "alpha_y")
    z = w[:, 2].clamp(min=0)  # 0 below the horizon, where G1 = 0 / root = 0
    root = (w[:, 2] ** 2 + (ax * w[:, 0]) ** 2 + (ay * w[:, 1]) ** 2).sqrt()
    return 2 * z / (z + root).clamp(min=torch.finfo(w.dtype).tiny)
