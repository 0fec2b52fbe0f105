"""Microfacet building blocks (GGX / Trowbridge-Reitz), Fresnel terms and the principled metallic-roughness BRDF.

Functional, differentiable torch; batched (N, ...) tensors in the local frame (z = normal, x = the alpha_x
direction). Roughness arguments are floats or (N,) tensors. The shadowing term is the separable Smith form
G = G1(wi) G1(wo), as in Mitsuba 3's `roughconductor` / `roughplastic`, so the two agree exactly.

Principled model: glTF 2.0 metallic-roughness parameters (with a `specular` level as in Disney /
KHR_materials_specular), diffuse and specular coupled like a coated plastic so that energy is bounded:
    f = (1 - metallic) base_color (1 - F_d(cos_i)) (1 - F_d(cos_o)) / (pi (1 - F_d_avg)) +
        S lerp(F_d, F_m, metallic)(wi.h)
    S = D(h) G1(wi) G1(wo) / (4 cos_i cos_o),  F_d = Schlick(0.08 specular),  F_m = Schlick(base_color)
F_d_avg = F0 + (1 - F0) / 21 is the cosine-weighted hemispherical average of Schlick's F_d, so the diffuse
albedo is exactly (1 - metallic)(1 - F_d(cos_i)) base_color. (glTF's own coupling (1 - F_d(wi.h)) gains up
to 70 % energy at grazing incidence on smooth white bases.) alpha comes from `principled_params_to_alpha`.
Every term is symmetric in wi and wo, so f is reciprocal.
"""
from __future__ import annotations

import math
from typing import Callable

import torch

from ..core.checks import check_directions, check_shape
from ..warp.ggx import ggx_reflection_pdf, sample_ggx_reflection
from ..warp.ggx_distribution import ggx_ndf, per_query as _per_query, smith_g1
from ..warp.hemisphere import sample_cosine_hemisphere

#: smallest GGX alpha the principled parameterisation produces (Burley 2012 clamps at the same value)
PRINCIPLED_MIN_ALPHA = 1e-3


def _per_query_rgb(x, n: int, ref: torch.Tensor, name: str) -> torch.Tensor:
    """A (3,) or (N, 3) value as an (N, 3) tensor on the device / dtype of `ref`."""
    t = torch.as_tensor(x, dtype=ref.dtype, device=ref.device)
    if t.dim() == 1:
        check_shape(t, name, (3,))
        t = t.expand(n, 3)
    return check_shape(t, name, (n, 3))


def _rgb_broadcastable(x, n: int, ref: torch.Tensor, name: str) -> torch.Tensor:
    """A (3,) or (N, 3) value as a tensor on the device / dtype of `ref` that broadcasts against (N, 3)."""
    t = torch.as_tensor(x, dtype=ref.dtype, device=ref.device)
    return check_shape(t, name, (3,) if t.dim() == 1 else (n, 3))


def fresnel_conductor(cos_theta: torch.Tensor, eta, k) -> torch.Tensor:
    """Unpolarised reflectance (N, 3) of a conductor with complex IOR eta + i k ((3,) or (N, 3)) at cos_theta (N,).

    Exact Fresnel equations in the form of Mitsuba 3's `fresnel_conductor`; cos_theta is clamped to [0, 1].
    """
    n = cos_theta.shape[0]
    eta, k = _rgb_broadcastable(eta, n, cos_theta, "eta"), _rgb_broadcastable(k, n, cos_theta, "k")
    if eta.dim() == 1 and k.dim() == 1:
        # per-material constants: work channel-major, (3, 1) constants against a (1, N) cosine row, so every
        # operation runs over long contiguous rows instead of rows of 3; the result is a transposed view
        return _fresnel_conductor(cos_theta.clamp(0, 1).unsqueeze(0), eta.unsqueeze(-1), k.unsqueeze(-1)).T
    return _fresnel_conductor(cos_theta.clamp(0, 1).unsqueeze(-1), eta, k)


def _fresnel_conductor(c: torch.Tensor, eta: torch.Tensor, k: torch.Tensor) -> torch.Tensor:
    """Conductor Fresnel for broadcastable c (cosines in [0, 1]), eta and k."""
    eta2_minus_k2 = eta * eta - k * k
    four_eta2_k2 = 4 * eta * eta * k * k  # for per-material constants computed once, not per query
    c2 = c * c
    s2 = 1 - c2
    t1 = eta2_minus_k2 - s2
    a2pb2 = (t1 * t1 + four_eta2_k2).sqrt()  # argument >= 0: a sum of non-negative terms
    a = (0.5 * (a2pb2 + t1)).clamp(min=0).sqrt()
    term1 = a2pb2 + c2
    term2 = (2 * c) * a
    r_s = (term1 - term2) / (term1 + term2)
    term3 = a2pb2 * c2 + s2 * s2
    term4 = term2 * s2
    r_p = r_s * (term3 - term4) / (term3 + term4)
    return 0.5 * (r_s + r_p)


def fresnel_dielectric(cos_theta: torch.Tensor, eta) -> torch.Tensor:
    """Unpolarised reflectance (N,) of a dielectric interface, eta = n_inside / n_outside (float or (N,)).

    cos_theta (N,) is measured on the outside (> 0) or inside (< 0); total internal reflection gives 1.
    """
    eta = _per_query(eta, cos_theta.shape[0], cos_theta, "eta")
    outside = cos_theta >= 0
    eta_it = torch.where(outside, eta, 1 / eta)
    ci = cos_theta.abs().clamp(max=1)
    sin_t2 = (1 - ci * ci) / (eta_it * eta_it)
    tir = sin_t2 >= 1
    ct = (1 - sin_t2).clamp(min=0).sqrt()
    r_s = (ci - eta_it * ct) / (ci + eta_it * ct)
    r_p = (eta_it * ci - ct) / (eta_it * ci + ct)
    f = 0.5 * (r_s * r_s + r_p * r_p)
    return torch.where(tir, torch.ones_like(f), f)


def fresnel_schlick(cos_theta: torch.Tensor, f0) -> torch.Tensor:
    """Schlick's approximation f0 + (1 - f0)(1 - cos)^5 (N, 3); f0 is (3,) or (N, 3); cos clamped to [0, 1]."""
    f0 = _per_query_rgb(f0, cos_theta.shape[0], cos_theta, "f0")
    w = (1 - cos_theta.clamp(0, 1)).pow(5).unsqueeze(-1)
    return f0 + (1 - f0) * w


def _dot(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Row-wise dot product (N,) of (N, 3) tensors, column by column (faster than a reduction over rows of 3)."""
    return a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2]


def _half_vector(wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
    h = wi + wo
    return h / _dot(h, h).sqrt().clamp(min=1e-12).unsqueeze(-1)


def microfacet_brdf(wi: torch.Tensor, wo: torch.Tensor, alpha_x, alpha_y,
                    fresnel: Callable[[torch.Tensor], torch.Tensor]) -> torch.Tensor:
    """GGX reflection D(h) G1(wi) G1(wo) F(wi.h) / (4 cos_i cos_o) (N, 3); 0 unless both directions are up.

    fresnel maps cos(wi, h) (N,) to reflectance (N, 3).
    """
    check_directions(wi, "wi")
    check_directions(wo, "wo")
    check_shape(wo, "wo", tuple(wi.shape))
    return _microfacet_brdf(wi, wo, alpha_x, alpha_y, fresnel)


def _microfacet_brdf(wi: torch.Tensor, wo: torch.Tensor, alpha_x, alpha_y,
                     fresnel: Callable[[torch.Tensor], torch.Tensor]) -> torch.Tensor:
    """`microfacet_brdf` without input checks, for callers whose directions are already validated."""
    h = _half_vector(wi, wo)
    # where a direction is below the horizon its G1 is 0, so the clamped denominator only guards 0 / 0
    denom = (4 * wi[:, 2] * wo[:, 2]).clamp(min=torch.finfo(wi.dtype).tiny)
    s = ggx_ndf(h, alpha_x, alpha_y) * smith_g1(wi, alpha_x, alpha_y) * smith_g1(wo, alpha_x, alpha_y) / denom
    return fresnel(_dot(wi, h)) * s.unsqueeze(-1)


def principled_params_to_alpha(roughness: torch.Tensor, anisotropy: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """GGX alphas (N,), (N,) from perceptual roughness and anisotropy in [0, 1] (Burley 2012).

    alpha = roughness^2, aspect = sqrt(1 - 0.9 anisotropy), alpha_x = alpha / aspect, alpha_y = alpha * aspect,
    both at least PRINCIPLED_MIN_ALPHA. Inputs are clamped to [0, 1].
    """
    a = roughness.clamp(0, 1) ** 2
    aspect = (1 - 0.9 * anisotropy.clamp(0, 1)).sqrt()
    return (a / aspect).clamp(min=PRINCIPLED_MIN_ALPHA), (a * aspect).clamp(min=PRINCIPLED_MIN_ALPHA)


class _Principled:
    """Per-query principled parameters broadcast to the batch: (N, 3) colours, (N,) scalars and alphas."""

    def __init__(self, wi, base_color, metallic, roughness, anisotropy, specular) -> None:
        n = wi.shape[0]
        self.base = _per_query_rgb(base_color, n, wi, "base_color").clamp(0, 1)
        self.metallic = _per_query(metallic, n, wi, "metallic").clamp(0, 1)
        self.f0_dielectric = 0.08 * _per_query(specular, n, wi, "specular").clamp(0, 1)
        self.ax, self.ay = principled_params_to_alpha(_per_query(roughness, n, wi, "roughness"),
                                                     _per_query(anisotropy, n, wi, "anisotropy"))

    def specular_color(self, cos_d: torch.Tensor) -> torch.Tensor:
        """lerp(F_d, F_m, metallic) (N, 3) at cos(wi, h)."""
        f_d = fresnel_schlick(cos_d, self.f0_dielectric.unsqueeze(-1).expand(-1, 3))
        f_m = fresnel_schlick(cos_d, self.base)
        return torch.lerp(f_d, f_m, self.metallic.unsqueeze(-1))

    def diffuse_transmission(self, cos_theta: torch.Tensor) -> torch.Tensor:
        """1 - F_d(cos_theta) (N,) for directions with cosine cos_theta to the macro normal."""
        return 1 - (self.f0_dielectric + (1 - self.f0_dielectric) * (1 - cos_theta.clamp(0, 1)).pow(5))

    def diffuse_albedo(self, wi: torch.Tensor) -> torch.Tensor:
        """Directional albedo of the diffuse lobe (N, 3): (1 - metallic)(1 - F_d(cos_i)) base_color."""
        return ((1 - self.metallic) * self.diffuse_transmission(wi[:, 2])).unsqueeze(-1) * self.base

    def diffuse(self, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        """Diffuse lobe (N, 3), including the 1 / pi; 0 unless both directions are up."""
        f_avg = self.f0_dielectric + (1 - self.f0_dielectric) / 21
        scale = self.diffuse_transmission(wo[:, 2]) / (math.pi * (1 - f_avg))
        up = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        return self.diffuse_albedo(wi) * torch.where(up, scale, torch.zeros_like(scale)).unsqueeze(-1)

    def specular_probability(self, wi: torch.Tensor) -> torch.Tensor:
        """Probability (N,) of sampling the GGX lobe: its Fresnel weight at cos_i over the total (1 if both are 0)."""
        w_s = self.specular_color(wi[:, 2]).mean(-1)
        w_d = self.diffuse_albedo(wi).mean(-1)
        total = w_s + w_d
        return torch.where(total > 0, w_s / torch.where(total > 0, total, torch.ones_like(total)),
                           torch.ones_like(total))


def principled_eval(wi: torch.Tensor, wo: torch.Tensor, base_color, metallic, roughness, anisotropy,
                    specular=0.5) -> torch.Tensor:
    """Principled BRDF (N, 3). base_color (N, 3) or (3,); metallic, roughness, anisotropy, specular float or (N,).

    Parameters are clamped to [0, 1]; 0 unless both directions are above the surface.
    """
    p = _Principled(wi, base_color, metallic, roughness, anisotropy, specular)
    return p.diffuse(wi, wo) + microfacet_brdf(wi, wo, p.ax, p.ay, p.specular_color)


def _principled_pdf(p: _Principled, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
    p_spec = p.specular_probability(wi)
    up = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    pdf = (1 - p_spec) * wo[:, 2].clamp(min=0) / math.pi + p_spec * ggx_reflection_pdf(wi, wo, p.ax, p.ay)
    return torch.where(up, pdf, torch.zeros_like(pdf))


def principled_pdf(wi: torch.Tensor, wo: torch.Tensor, base_color, metallic, roughness, anisotropy,
                   specular=0.5) -> torch.Tensor:
    """Solid-angle density (N,) of `principled_sample`: mixture of cosine and GGX visible-normal reflection."""
    check_directions(wo, "wo")
    check_shape(wo, "wo", tuple(wi.shape))
    return _principled_pdf(_Principled(wi, base_color, metallic, roughness, anisotropy, specular), wi, wo)


def principled_sample(wi: torch.Tensor, u: torch.Tensor, base_color, metallic, roughness, anisotropy,
                      specular=0.5) -> tuple[torch.Tensor, torch.Tensor]:
    """Sample wo (N, 3) given wi (N, 3) and u (N, 2) in [0, 1)^2; returns (wo, pdf (N,)), pdf 0 where it failed.

    u[:, 0] first picks the lobe (GGX with `specular_probability`, else cosine) and is then rescaled.
    """
    check_directions(wi, "wi")
    check_shape(u, "u", (wi.shape[0], 2))
    p = _Principled(wi, base_color, metallic, roughness, anisotropy, specular)
    p_spec = p.specular_probability(wi)
    pick_spec = u[:, 0] < p_spec
    u0 = torch.where(pick_spec, u[:, 0] / p_spec.clamp(min=1e-12), (u[:, 0] - p_spec) / (1 - p_spec).clamp(min=1e-12))
    u2 = torch.stack([u0.clamp(0, 1), u[:, 1]], -1)
    up_i = wi[:, 2] > 0
    wi_safe = torch.where(up_i.unsqueeze(-1), wi, torch.tensor([0.0, 0.0, 1.0], dtype=wi.dtype, device=wi.device))
    wo = torch.where(pick_spec.unsqueeze(-1), sample_ggx_reflection(wi_safe, u2, p.ax, p.ay),
                     sample_cosine_hemisphere(u2))
    pdf = _principled_pdf(p, wi, wo)
    return wo, pdf

