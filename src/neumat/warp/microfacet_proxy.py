"""The analytic two-lobe sampling proxy of Real-Time Neural Appearance Models (Zeltner et al. 2024, App. A),
the distribution whose 9 parameters the neural importance-sampling decoder predicts.

p(wo) = w_d p_d(wo) + w_s p_s(wo) (Eq. 8): a tilted cosine lobe and an anisotropic, non-centred GGX
reflection lobe; `proxy_from_raw` maps network outputs (N, 9) to valid parameters.

Details: src/neumat/methods/neural_appearance/NOTES.md, section `neumat.warp.microfacet_proxy`.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import torch

from ..core.checks import check_directions, check_finite, check_range, check_shape
from ..core.errors import InputError
from ..core.frames import frame_from_normal, to_world
from ._checks import check_u
from .hemisphere import sample_cosine_hemisphere

#: smallest roughness and largest |correlation| `proxy_from_raw` produces (M stays invertible)
MIN_ALPHA = 1e-3
MAX_RHO = 0.99
RAW_NAMES = ("w_d", "mu_d,x", "mu_d,y", "w_s", "alpha_x", "alpha_y", "rho", "mu_s,x", "mu_s,y")


class ProxyLobes(NamedTuple):
    """Parameters of the two-lobe proxy for N queries: w_d (N,) diffuse weight (w_s = 1 - w_d), mu_d (N, 2)
    diffuse tilt slopes, alpha (N, 2) roughness (a_x, a_y) in (0, 1], rho (N,) in (-1, 1), mu_s (N, 2) mean
    slopes of the specular lobe."""

    w_d: torch.Tensor
    mu_d: torch.Tensor
    alpha: torch.Tensor
    rho: torch.Tensor
    mu_s: torch.Tensor


def soft_tanh(x: torch.Tensor) -> torch.Tensor:
    """Piecewise-quadratic tanh: x (1 - |x| / 4) for |x| <= 2, sign(x) beyond (C1, range [-1, 1])."""
    c = x.clamp(-2, 2)
    return c * (1 - c.abs() / 4)


def soft_sinh(x: torch.Tensor) -> torch.Tensor:
    """Quadratic odd growth for unbounded slopes: x (1 + |x| / 2) (C1, slope 1 at 0, range R)."""
    return x * (1 + x.abs() / 2)


def proxy_from_raw(raw: torch.Tensor) -> ProxyLobes:
    """Valid proxy parameters from raw decoder outputs (N, 9) ordered as `RAW_NAMES`: softmax over (w_d, w_s),
    alpha = MIN_ALPHA + (1 - MIN_ALPHA) (soft_tanh + 1) / 2, rho = MAX_RHO soft_tanh, mu = soft_sinh."""
    check_shape(raw, "raw proxy parameters", (-1, 9))
    check_finite(raw, "raw proxy parameters")
    w = torch.softmax(raw[:, [0, 3]], -1)
    alpha = MIN_ALPHA + (1 - MIN_ALPHA) * (soft_tanh(raw[:, 4:6]) + 1) / 2
    return ProxyLobes(w[:, 0], soft_sinh(raw[:, 1:3]), alpha, MAX_RHO * soft_tanh(raw[:, 6]), soft_sinh(raw[:, 7:9]))


def check_lobes(lobes: ProxyLobes, n: int) -> None:
    """Shapes (n, ...) and ranges of `lobes`; InputError naming the first problem."""
    for name, t, shape in (("w_d", lobes.w_d, (n,)), ("mu_d", lobes.mu_d, (n, 2)), ("alpha", lobes.alpha, (n, 2)),
                           ("rho", lobes.rho, (n,)), ("mu_s", lobes.mu_s, (n, 2))):
        check_shape(t, name, shape)
        check_finite(t, name)
    check_range(lobes.w_d, "proxy w_d (mixing weight)", 0.0, 1.0)
    if n and not bool((lobes.alpha > 0).all()):
        raise InputError(f"proxy alpha: roughness must be > 0, got min {lobes.alpha.min().item():.4g}")
    if n and not bool((lobes.rho.abs() < 1).all()):
        raise InputError("proxy rho: the correlation must lie in (-1, 1)")


def _diffuse_normal(lobes: ProxyLobes) -> torch.Tensor:
    """n_d (N, 3) of Eq. 9."""
    n = torch.cat([-lobes.mu_d, torch.ones_like(lobes.w_d)[:, None]], -1)
    return n / n.norm(dim=-1, keepdim=True)


def _apply_m(lobes: ProxyLobes, v: torch.Tensor) -> torch.Tensor:
    """M v (N, 3) with M of Eq. 11."""
    ax, ay = lobes.alpha.unbind(-1)
    s = (1 - lobes.rho ** 2).sqrt()
    x = ax * v[:, 0] - lobes.mu_s[:, 0] * v[:, 2]
    y = ay * lobes.rho * v[:, 0] + ay * s * v[:, 1] - lobes.mu_s[:, 1] * v[:, 2]
    return torch.stack([x, y, v[:, 2]], -1)


def _apply_m_inverse(lobes: ProxyLobes, v: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """M^-1 v (N, 3) and det(M^-1) (N,)."""
    ax, ay = lobes.alpha.unbind(-1)
    s = (1 - lobes.rho ** 2).sqrt()
    px = v[:, 0] + lobes.mu_s[:, 0] * v[:, 2]                 # undo the slope offset, then the 2 x 2 block
    py = v[:, 1] + lobes.mu_s[:, 1] * v[:, 2]
    x = px / ax
    y = (py - ay * lobes.rho * x) / (ay * s)
    return torch.stack([x, y, v[:, 2]], -1), 1 / (ax * ay * s)


def sample_proxy(lobes: ProxyLobes, wi: torch.Tensor, u: torch.Tensor, check: bool = True) -> torch.Tensor:
    """Directions wo (N, 3) from the mixture, for wi (N, 3) and u (N, 2) in [0, 1)^2: u_x picks the lobe and is
    rescaled to [0, 1) for the lobe's own warp. check=False skips the input checks, for hot loops whose lobes
    come from `proxy_from_raw` and whose directions and u are valid by construction."""
    if check:
        check_directions(wi, "wi")
        check_u(u)
        check_shape(u, "u", (wi.shape[0], 2))
        check_lobes(lobes, wi.shape[0])
    w_d = lobes.w_d.to(u)
    diffuse = u[:, 0] < w_d
    u0 = torch.where(diffuse, u[:, 0] / w_d.clamp(min=1e-12), (u[:, 0] - w_d) / (1 - w_d).clamp(min=1e-12))
    local = sample_cosine_hemisphere(torch.stack([u0.clamp(0, 1 - 1e-7), u[:, 1]], -1))
    n_d = _diffuse_normal(lobes)
    wo_d = to_world(local, *frame_from_normal(n_d), n_d)
    h = _apply_m(lobes, local)
    h = h / h.norm(dim=-1, keepdim=True)
    wo_s = 2 * (wi * h).sum(-1, keepdim=True) * h - wi
    return torch.where(diffuse[:, None], wo_d, wo_s)


def proxy_pdf(lobes: ProxyLobes, wi: torch.Tensor, wo: torch.Tensor, check: bool = True) -> torch.Tensor:
    """Solid-angle density (N,) of `sample_proxy` at wo (N, 3) given wi (N, 3) (Eqs. 8-10); check as there."""
    if check:
        check_directions(wi, "wi")
        check_directions(wo, "wo")
        check_lobes(lobes, wi.shape[0])
    p_d = (wo * _diffuse_normal(lobes)).sum(-1).clamp(min=0) / math.pi
    h = wi + wo
    h = torch.where(h[:, 2:] < 0, -h, h)                      # the half vector on the upper side
    length = h.norm(dim=-1)
    ok = (length > 1e-12) & (h[:, 2] > 0)
    h = h / torch.where(ok, length, torch.ones_like(length))[:, None]
    v, det_inv = _apply_m_inverse(lobes, h)
    r = v.norm(dim=-1)
    p_h = (v[:, 2] / r) / math.pi * det_inv / r ** 3
    cos_oh = (wo * h).sum(-1).abs()
    p_s = torch.where(ok & (cos_oh > 0), p_h / (4 * cos_oh.clamp(min=1e-12)), torch.zeros_like(p_h))
    return lobes.w_d * p_d + (1 - lobes.w_d) * p_s
