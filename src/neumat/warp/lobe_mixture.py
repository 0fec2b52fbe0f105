"""A fixed, material-independent proposal: cosine-weighted hemisphere plus GGX reflection lobes of several
roughnesses, mixed with equal weights (a defensive mixture, Hesterberg 1995).

Used to render different materials with the same directions (same seed, same samples), so their images differ
by the materials only, while any lobe from nearly diffuse to nearly mirror-like is sampled at least 1 / (number of
components) as well as by a lobe of its own width. Local frame z = normal; `wi` (N, 3) is the direction the
lobes are reflected from (the viewer, upper hemisphere). Densities are per steradian of the full sphere; a sample
of a GGX lobe may point below the surface (the reflection pdf is 0 there, as `ggx_reflection_pdf`).
"""
from __future__ import annotations

import torch

from ..core.checks import check_directions, check_shape
from ..core.errors import InputError
from ._checks import check_u
from .ggx import ggx_reflection_pdf, sample_ggx_reflection
from .hemisphere import cosine_hemisphere_pdf, sample_cosine_hemisphere

#: GGX roughnesses of the default mixture: from chrome-like (0.01) to rough (0.5), a factor ~3.5 apart
DEFAULT_ALPHAS = (0.01, 0.035, 0.12, 0.4)


def _check_alphas(alphas) -> tuple[float, ...]:
    alphas = tuple(float(a) for a in alphas)
    if not alphas or not all(0 < a for a in alphas):
        raise InputError(f"lobe mixture alphas: expected one or more positive GGX roughnesses, got {alphas!r}")
    return alphas


def sample_lobe_mixture(wi: torch.Tensor, u: torch.Tensor, alphas=DEFAULT_ALPHAS) -> torch.Tensor:
    """Directions wo (N, 3) from the mixture given wi (N, 3) (wi_z > 0) and u (N, 2) in [0, 1)^2.

    Component c of the 1 + len(alphas) equally likely ones (0: cosine, c > 0: GGX reflection of alphas[c - 1])
    is picked with u[:, 0], which is then stretched back to [0, 1) for the component's own sampling.
    """
    alphas = _check_alphas(alphas)
    check_directions(wi, "wi")
    check_u(u)
    check_shape(u, "u", (wi.shape[0], 2))
    k = 1 + len(alphas)
    scaled = u[:, 0] * k
    comp = scaled.floor().clamp(max=k - 1)
    u_comp = torch.stack([(scaled - comp).clamp(0, 1 - torch.finfo(u.dtype).eps), u[:, 1]], -1)
    wo = sample_cosine_hemisphere(u_comp)
    for c, a in enumerate(alphas, start=1):
        pick = comp == c
        if bool(pick.any()):
            wo[pick] = sample_ggx_reflection(wi[pick], u_comp[pick], a, a)
    return wo


def lobe_mixture_pdf(wi: torch.Tensor, wo: torch.Tensor, alphas=DEFAULT_ALPHAS) -> torch.Tensor:
    """Density (N,) per steradian with which `sample_lobe_mixture` draws wo (N, 3) given wi (N, 3)."""
    alphas = _check_alphas(alphas)
    check_directions(wi, "wi")
    check_directions(wo, "wo")
    check_shape(wo, "wo", (wi.shape[0], 3))
    total = cosine_hemisphere_pdf(wo)
    for a in alphas:
        total = total + ggx_reflection_pdf(wi, wo, a, a)
    return total / (1 + len(alphas))
