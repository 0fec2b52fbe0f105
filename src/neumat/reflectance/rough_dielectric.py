"""The reflection lobe of a rough dielectric interface (Walter et al. 2007, GGX), as Mitsuba 3's
`roughdielectric` (distribution "ggx", isotropic alpha) evaluates it for two directions on the same side:

    f_r(wi, wo) = F(wi . h, eta) D(h) G1(wi) G1(wo) / (4 cos_i cos_o),   h = (wi + wo) / |wi + wo|

F is the exact dielectric Fresnel reflectance, eta = n_inside / n_outside; both directions lie outside (above the
surface), the side the environment lights. The unit is 1/sr and the cosine is not included (Mitsuba's `eval`
returns f_r cos_o). The transmission lobe is not here: the light it carries into the object is the subsurface
term (NeuPreSS's S_hat).

Details: docs/notes/reflectance.md, section `neumat.reflectance.rough_dielectric`.
"""
from __future__ import annotations

import torch

from ..core.checks import check_directions, check_shape
from ..core.frames import frame_from_normal, to_local, to_world
from ..warp.ggx import ggx_reflection_pdf, sample_ggx_reflection
from ..warp.ggx_distribution import ggx_ndf, per_query, smith_g1
from .microfacet import fresnel_dielectric


def _local(w: torch.Tensor, n: torch.Tensor | None, name: str) -> torch.Tensor:
    """w (N, 3) in the local frame of the normals n (or w itself when n is None)."""
    check_directions(w, name)
    if n is None:
        return w
    check_shape(n, "n", tuple(w.shape))
    check_directions(n, "n")
    return to_local(w, *frame_from_normal(n), n)


def rough_dielectric_reflection(wi: torch.Tensor, wo: torch.Tensor, alpha, eta,
                                n: torch.Tensor | None = None) -> torch.Tensor:
    """f_r(wi, wo) (N,) per steradian, without the cosine; 0 unless both directions are above the surface."""
    wi, wo = _local(wi, n, "wi"), _local(wo, n, "wo")
    check_shape(wo, "wo", tuple(wi.shape))
    alpha = per_query(alpha, wi.shape[0], wi, "alpha")
    up = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    h = wi + wo
    h = h / h.norm(dim=-1, keepdim=True).clamp(min=1e-12)
    fresnel = fresnel_dielectric((wi * h).sum(-1), per_query(eta, wi.shape[0], wi, "eta"))
    g = smith_g1(wi, alpha, alpha) * smith_g1(wo, alpha, alpha)
    denom = 4 * torch.where(up, wi[:, 2] * wo[:, 2], torch.ones_like(wi[:, 2]))
    f = fresnel * ggx_ndf(h, alpha, alpha) * g / denom
    return torch.where(up, f, torch.zeros_like(f))


def sample_rough_dielectric_reflection(wo: torch.Tensor, u: torch.Tensor, alpha,
                                       n: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Light directions wi (N, 3) (in the frame of wo) drawn from the fixed direction wo (N, 3) with u (N, 2) in
    [0, 1)^2, and their density (N,) per steradian; pdf 0 where the reflection goes below the surface or wo is
    not above it."""
    local = _local(wo, n, "wo")
    check_shape(u, "u", (wo.shape[0], 2))
    alpha = per_query(alpha, wo.shape[0], wo, "alpha")
    up = local[:, 2] > 0
    safe = torch.where(up.unsqueeze(-1), local, torch.tensor([0.0, 0.0, 1.0], dtype=wo.dtype, device=wo.device))
    wi = sample_ggx_reflection(safe, u.to(wo.dtype), alpha, alpha)
    pdf = torch.where(up, ggx_reflection_pdf(safe, wi, alpha, alpha), torch.zeros_like(alpha))
    if n is not None:
        wi = to_world(wi, *frame_from_normal(n), n)
    return wi, pdf


def rough_dielectric_reflection_pdf(wi: torch.Tensor, wo: torch.Tensor, alpha,
                                    n: torch.Tensor | None = None) -> torch.Tensor:
    """Density (N,) per steradian with which `sample_rough_dielectric_reflection` draws wi from wo."""
    wi, wo = _local(wi, n, "wi"), _local(wo, n, "wo")
    check_shape(wi, "wi", tuple(wo.shape))
    alpha = per_query(alpha, wo.shape[0], wo, "alpha")
    return ggx_reflection_pdf(wo, wi, alpha, alpha)
