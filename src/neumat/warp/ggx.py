"""GGX visible-normal sampling (Heitz 2018, "Sampling the GGX Distribution of Visible Normals", JCGT 7(4)).

Local frame z = macro normal, x = the direction of alpha_x. `wi` (N, 3) is the direction the normals are seen
from (upper hemisphere); alpha_x, alpha_y are floats or (N,) tensors. The density of the sampled micro-normal
m is the visible-normal distribution D_wi(m) = G1(wi) max(0, wi . m) D(m) / wi_z per steradian.

Two triplets: `sample_ggx_vndf / ggx_vndf_pdf / invert_ggx_vndf` for the micro-normal m, and
`sample_ggx_reflection / ggx_reflection_pdf / invert_ggx_reflection` for wo = wi mirrored about m, with density
D_wi(h) / (4 wi . h) = G1(wi) D(h) / (4 wi_z), h the half vector.
"""
from __future__ import annotations

import math

import torch

from ..core.checks import check_directions, check_finite, check_shape
from ..core.errors import InputError
from ._checks import check_u
from .ggx_distribution import ggx_ndf, smith_g1


def _alphas(n: int, alpha_x, alpha_y, ref: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """alpha_x, alpha_y broadcast to (N,) on the device / dtype of `ref`; must be positive."""
    out = []
    for name, a in (("alpha_x", alpha_x), ("alpha_y", alpha_y)):
        a = torch.as_tensor(a, dtype=ref.dtype, device=ref.device)
        if a.dim() == 0:
            a = a.expand(n)
        check_shape(a, name, (n,))
        check_finite(a, name)
        if n and not bool((a > 0).all()):
            raise InputError(f"{name}: GGX roughness must be > 0, got min {a.min().item():.4g}")
        out.append(a)
    return out[0], out[1]


def _hemisphere_basis(vh: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Orthonormal T1, T2 (N, 3) spanning the plane orthogonal to the stretched view vh (Heitz 2018, listing 1)."""
    lensq = vh[:, 0] ** 2 + vh[:, 1] ** 2
    inv = torch.rsqrt(torch.where(lensq > 0, lensq, torch.ones_like(lensq)))
    t1 = torch.stack([-vh[:, 1] * inv, vh[:, 0] * inv, torch.zeros_like(lensq)], -1)
    t1 = torch.where((lensq > 0).unsqueeze(-1), t1, torch.tensor([1.0, 0.0, 0.0], dtype=vh.dtype, device=vh.device))
    return t1, torch.linalg.cross(vh, t1, dim=-1)


def _stretched_view(wi: torch.Tensor, ax: torch.Tensor, ay: torch.Tensor) -> torch.Tensor:
    vh = torch.stack([ax * wi[:, 0], ay * wi[:, 1], wi[:, 2]], -1)
    return vh / vh.norm(dim=-1, keepdim=True)


def sample_ggx_vndf(wi: torch.Tensor, u: torch.Tensor, alpha_x, alpha_y) -> torch.Tensor:
    """Micro-normals m (N, 3), distributed by D_wi(m), from wi (N, 3) with wi_z > 0 and u (N, 2) in [0, 1)^2."""
    check_directions(wi, "wi")
    check_u(u)
    check_shape(u, "u", (wi.shape[0], 2))
    ax, ay = _alphas(wi.shape[0], alpha_x, alpha_y, wi)
    vh = _stretched_view(wi, ax, ay)
    t1, t2 = _hemisphere_basis(vh)
    r = u[:, 0].clamp(min=0).sqrt()
    phi = 2 * math.pi * u[:, 1]
    p1, p2 = r * torch.cos(phi), r * torch.sin(phi)
    s = 0.5 * (1 + vh[:, 2])
    p2 = (1 - s) * (1 - p1 * p1).clamp(min=0).sqrt() + s * p2
    p3 = (1 - p1 * p1 - p2 * p2).clamp(min=0).sqrt()
    nh = p1.unsqueeze(-1) * t1 + p2.unsqueeze(-1) * t2 + p3.unsqueeze(-1) * vh
    m = torch.stack([ax * nh[:, 0], ay * nh[:, 1], nh[:, 2].clamp(min=0)], -1)
    return m / m.norm(dim=-1, keepdim=True)


def ggx_vndf_pdf(wi: torch.Tensor, m: torch.Tensor, alpha_x, alpha_y) -> torch.Tensor:
    """Density (N,) per steradian of `sample_ggx_vndf` at micro-normals m (N, 3); 0 for back-facing m or wi_z <= 0."""
    check_directions(wi, "wi")
    check_directions(m, "m")
    check_shape(m, "m", (wi.shape[0], 3))
    ax, ay = _alphas(wi.shape[0], alpha_x, alpha_y, wi)
    cos_i = wi[:, 2]
    dot = (wi * m).sum(-1)
    ok = (cos_i > 0) & (dot > 0)
    pdf = smith_g1(wi, ax, ay) * dot.clamp(min=0) * ggx_ndf(m, ax, ay) / torch.where(ok, cos_i, torch.ones_like(cos_i))
    return torch.where(ok, pdf, torch.zeros_like(pdf))


def invert_ggx_vndf(wi: torch.Tensor, m: torch.Tensor, alpha_x, alpha_y) -> torch.Tensor:
    """Inverse of `sample_ggx_vndf`: visible micro-normals m (N, 3) -> u (N, 2) in [0, 1]^2."""
    check_directions(wi, "wi")
    check_directions(m, "m")
    check_shape(m, "m", (wi.shape[0], 3))
    ax, ay = _alphas(wi.shape[0], alpha_x, alpha_y, wi)
    vh = _stretched_view(wi, ax, ay)
    t1, t2 = _hemisphere_basis(vh)
    nh = torch.stack([m[:, 0] / ax, m[:, 1] / ay, m[:, 2]], -1)
    nh = nh / nh.norm(dim=-1, keepdim=True)
    p1 = (nh * t1).sum(-1)
    p2 = (nh * t2).sum(-1)
    s = 0.5 * (1 + vh[:, 2])
    p2 = (p2 - (1 - s) * (1 - p1 * p1).clamp(min=0).sqrt()) / s
    u0 = (p1 * p1 + p2 * p2).clamp(0, 1)
    u1 = torch.remainder(torch.atan2(p2, p1) / (2 * math.pi), 1.0)
    return torch.stack([u0, u1], -1)


def sample_ggx_reflection(wi: torch.Tensor, u: torch.Tensor, alpha_x, alpha_y) -> torch.Tensor:
    """Directions wo (N, 3): wi mirrored about a visible GGX normal m ~ D_wi. wo may point below the surface."""
    m = sample_ggx_vndf(wi, u, alpha_x, alpha_y)
    wo = 2 * (wi * m).sum(-1, keepdim=True) * m - wi
    return wo / wo.norm(dim=-1, keepdim=True)


def ggx_reflection_pdf(wi: torch.Tensor, wo: torch.Tensor, alpha_x, alpha_y) -> torch.Tensor:
    """Density (N,) per steradian of `sample_ggx_reflection`: G1(wi) D(h) / (4 wi_z); 0 unless both are up."""
    check_directions(wi, "wi")
    check_directions(wo, "wo")
    check_shape(wo, "wo", (wi.shape[0], 3))
    ax, ay = _alphas(wi.shape[0], alpha_x, alpha_y, wi)
    h = wi + wo
    h = h / h.norm(dim=-1, keepdim=True).clamp(min=1e-12)
    up = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    pdf = smith_g1(wi, ax, ay) * ggx_ndf(h, ax, ay) / (4 * torch.where(up, wi[:, 2], torch.ones_like(wi[:, 2])))
    return torch.where(up, pdf, torch.zeros_like(pdf))


def invert_ggx_reflection(wi: torch.Tensor, wo: torch.Tensor, alpha_x, alpha_y) -> torch.Tensor:
    """Inverse of `sample_ggx_reflection`: wo (N, 3) -> u (N, 2), through the half vector."""
    h = wi + wo
    return invert_ggx_vndf(wi, h / h.norm(dim=-1, keepdim=True).clamp(min=1e-12), alpha_x, alpha_y)
