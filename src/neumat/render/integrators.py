"""Direct illumination with multiple importance sampling (power heuristic, beta = 2).

Per shading point one light sample and one material sample are drawn:
  "light":     L = f Li cos / p_light
  "material":  L = f Li cos / p_mat      (delta lights cannot be hit: they fall back to "light")
  "mis":       both, weighted by p^2 / (p_light^2 + p_mat^2)
  "mis-lobes": "mis" with the material sample drawn from a fixed, material-independent mixture of a cosine
               lobe and GGX lobes from chrome-like to rough (`neumat.warp.lobe_mixture`): renders of two
               materials with the same seed then use the same directions and differ by the materials only,
               which is what image comparisons of a model with its reference need
f is always `material.eval(Query(wi=light direction, wo=viewer direction))`. The material strategy draws
the light direction with `material.sample(Query(wi=viewer), u)` (the sampled `wo` slot is the light
direction) and its density `material.pdf(Query(wi=viewer, wo=light))`; materials with can_sample = False
use cosine-weighted hemisphere sampling instead. Values in one estimator are thus consistent whether or
not the material is exactly reciprocal.
"""
from __future__ import annotations

import math

import torch

from ..core.errors import InputError
from ..core.frames import to_local, to_world
from ..core.material import Material
from ..core.query import Query
from ..warp.hemisphere import sample_cosine_hemisphere
from ..warp.lobe_mixture import lobe_mixture_pdf, sample_lobe_mixture
from .lights import Light
from .scenes import Hits, Scene

STRATEGIES = ("mis", "light", "material", "mis-lobes")


def check_strategy(strategy: str) -> str:
    """Return `strategy` or raise InputError listing the known ones."""
    if strategy not in STRATEGIES:
        raise InputError(f"strategy: expected one of {', '.join(STRATEGIES)}, got {strategy!r}")
    return strategy


def shade_direct(material: Material, light: Light, scene: Scene, hits: Hits, view: torch.Tensor,
                 u: torch.Tensor, strategy: str = "mis") -> torch.Tensor:
    """Reflected radiance (M, 3) towards the camera at M hits.

    view: (M, 3) unit world directions from the hits to the camera; u: (M, 4) uniform numbers (light
    sample, material sample), float32 or float64 (environment maps use the extra bits of float64).
    """
    check_strategy(strategy)
    frame = (hits.tangent, hits.bitangent, hits.n)
    wo = _unit(to_local(view, *frame))
    front = wo[:, 2] > 0
    wo = torch.where(front[:, None], wo, _up(wo))
    use_light = light.is_delta or strategy != "material"
    use_material = not light.is_delta and strategy != "light"
    mis = strategy in ("mis", "mis-lobes") and not light.is_delta
    fixed = strategy == "mis-lobes"

    dirs, pdfs, radiance, valids = [], [], [], []
    if use_light:
        ls = light.sample(hits.p, u[:, :2])
        wi = _unit(to_local(ls.wi, *frame))
        ok = front & (ls.pdf > 0) & (wi[:, 2] > 0)
        ok = ok & ~_blocked(scene, hits, ls.wi, ls.distance, ok)
        dirs.append(wi)
        pdfs.append(ls.pdf)
        radiance.append(ls.radiance)
        valids.append(ok)
    if use_material:
        wi_m, p_m = _sample_material(material, wo, hits, below_one(u[:, 2:4].to(wo.dtype)), fixed)
        ok = front & (p_m > 0) & (wi_m[:, 2] > 0)
        wi_m = torch.where(ok[:, None], wi_m, _up(wi_m))
        world = to_world(wi_m, *frame)
        ok = ok & ~_blocked(scene, hits, world, torch.full_like(p_m, math.inf), ok)
        li, p_light_of_mat = light.eval_pdf(world) if mis else (light.eval(world), None)
        dirs.append(wi_m)
        pdfs.append(p_m)
        radiance.append(li)
        valids.append(ok)

    n = wo.shape[0]
    k = len(dirs)
    wi_all = torch.where(torch.cat(valids)[:, None], torch.cat(dirs), _up(wo).repeat(k, 1))
    f = _eval(material, wi_all, wo.repeat(k, 1), hits, k)
    cos = wi_all[:, 2:3]
    pdf = torch.cat(pdfs)
    valid = torch.cat(valids)
    contrib = f * torch.cat(radiance) * cos / torch.where(valid, pdf, torch.ones_like(pdf))[:, None]
    if mis:
        p_light, p_mat = pdfs
        p_mat_of_light = _material_pdf(material, wo, wi_all[:n], hits, fixed)
        w_light = _power(p_light, p_mat_of_light)
        w_mat = _power(p_mat, p_light_of_mat)
        contrib = contrib * torch.cat([w_light, w_mat])[:, None]
    contrib = torch.where(valid[:, None], contrib, torch.zeros_like(contrib))
    return contrib.reshape(k, n, 3).sum(0)


def below_one(u: torch.Tensor) -> torch.Tensor:
    """u with values that rounding to a narrower dtype carried up to 1 set to the largest value below 1."""
    return u.clamp(max=1.0 - torch.finfo(u.dtype).eps / 2)


def _sample_material(material: Material, wo: torch.Tensor, hits: Hits, u: torch.Tensor, fixed: bool):
    """Light directions (M, 3) drawn from the material (fixed: from the lobe mixture) given the viewer
    direction, and their densities."""
    if fixed:
        wi = sample_lobe_mixture(wo, u)
        return wi, lobe_mixture_pdf(wo, wi)
    if not material.can_sample:
        wi = sample_cosine_hemisphere(u)
        return wi, wi[:, 2].clamp(min=0) / math.pi
    s = material.sample(_query(wo, None, hits, 1), u)
    _check_finite(material, s.pdf, "sample().pdf")
    good = (s.pdf > 0) & torch.isfinite(s.wo).all(-1)
    wi = torch.where(good[:, None], s.wo, _up(wo))
    return _unit(wi), torch.where(good, s.pdf, torch.zeros_like(s.pdf))


def _material_pdf(material: Material, wo: torch.Tensor, wi: torch.Tensor, hits: Hits, fixed: bool) -> torch.Tensor:
    """Density (M,) with which `_sample_material` draws the light directions wi (M, 3)."""
    if fixed:
        return lobe_mixture_pdf(wo, wi)
    if not material.can_sample:
        return wi[:, 2].clamp(min=0) / math.pi
    p = material.pdf(_query(wo, wi, hits, 1))
    _check_finite(material, p, "pdf()")
    return p


def _eval(material: Material, wi: torch.Tensor, wo: torch.Tensor, hits: Hits, k: int) -> torch.Tensor:
    f = material.eval(_query(wi, wo, hits, k))
    _check_finite(material, f, "eval()")
    return f


def _query(wi: torch.Tensor, wo: torch.Tensor | None, hits: Hits, k: int) -> Query:
    """A Query with the hits' uv and footprint repeated k times (for k stacked direction batches)."""
    uv = None if hits.uv is None else hits.uv.repeat(k, 1)
    fp = None if hits.footprint is None else hits.footprint.repeat(k, 1, 1)
    return Query.trusted(wi, wo, uv=uv, footprint=fp)  # unit, finite and shaped by construction


def _blocked(scene: Scene, hits: Hits, wi_world: torch.Tensor, dist: torch.Tensor, active: torch.Tensor):
    """(M,) True where a shadow ray towards wi_world is blocked (only traced for active rows)."""
    blocked = torch.zeros_like(active)
    if scene.needs_visibility and bool(active.any()):
        blocked[active] = scene.occluded(hits.p[active], hits.ng[active], wi_world[active], dist[active])
    return blocked


def _power(p: torch.Tensor, other: torch.Tensor) -> torch.Tensor:
    """Power-heuristic weight p^2 / (p^2 + other^2) (0 where both vanish)."""
    p2, o2 = p * p, other * other
    total = p2 + o2
    return torch.where(total > 0, p2 / torch.where(total > 0, total, torch.ones_like(total)), torch.zeros_like(p))


def _check_finite(material: Material, t: torch.Tensor, what: str) -> None:
    # fast path: one sum is finite when every entry is (barring overflow, which the exact check then clears)
    if bool(torch.isfinite(t.sum())) or bool(torch.isfinite(t).all()):
        return
    bad = int((~torch.isfinite(t)).reshape(t.shape[0], -1).any(-1).sum())
    name = getattr(material, "name", type(material).__name__)
    raise InputError(f"material {name!r} ({type(material).__name__}): {what} returned non-finite values "
                     f"(NaN or inf) for {bad} of {t.shape[0]} queries")


def _unit(v: torch.Tensor) -> torch.Tensor:
    x, y, z = v.unbind(-1)  # column-wise: much faster than a norm over rows of 3
    return v / (x * x + y * y + z * z).sqrt().clamp(min=1e-12).unsqueeze(-1)


def _up(like: torch.Tensor) -> torch.Tensor:
    """The normal direction (0, 0, 1), as a placeholder for invalid rows, shaped like `like`."""
    return like.new_tensor([0.0, 0.0, 1.0]).expand_as(like)
