"""White-furnace test: Monte Carlo directional albedo a(wi) = int f(wi, wo) cos(theta_o) dwo of a Material.

An energy-conserving BRDF has a(wi) <= 1 for every wi and channel; a white Lambertian surface has exactly 1.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ..core.checks import check_directions
from ..core.errors import InputError
from ..core.query import Query
from ..warp.hemisphere import sample_cosine_hemisphere

_METHODS = ("cosine", "material")


def mirror_cone_samples(theta_o: float, cone: float, n: int, gen: torch.Generator):
    """Directions to estimate a directional albedo int f cos dwi at wo = (sin theta_o, 0, cos theta_o) where a
    sharp lobe would defeat cosine sampling: half of the n directions uniform on the hemisphere, half uniform in
    the cone of half-angle `cone` (radians) around the mirror direction (balance heuristic). Returns the Query
    (wi above the horizon), the weights cos / (n pdf) (M, 1) and whether each wi lies in the cone (M,); the same
    directions serve every material compared, so ratios of estimates are far less noisy than either."""
    from ..methods.neural_appearance.directional_blur import sample_cone
    from ..warp.hemisphere import sample_uniform_hemisphere

    wo = torch.tensor([math.sin(theta_o), 0.0, math.cos(theta_o)])
    mirror = torch.tensor([-wo[0], 0.0, wo[2]])
    u = torch.rand(n, 2, generator=gen)
    wi = torch.cat([sample_uniform_hemisphere(u)[: n // 2], sample_cone(mirror[None], cone, u[None])[0][n // 2:]])
    wi = wi / wi.norm(dim=-1, keepdim=True)
    in_cone = wi @ mirror >= math.cos(cone)
    pdf = 0.5 / (2 * math.pi) + 0.5 / (2 * math.pi * (1 - math.cos(cone))) * in_cone.to(wi.dtype)
    keep = wi[:, 2] > 0
    weight = (wi[keep, 2] / (n * pdf[keep])).unsqueeze(-1)
    return Query(wi[keep], wo.expand(int(keep.sum()), 3).contiguous()), weight, in_cone[keep]
_BATCH = 1 << 18  # queries per material call


@dataclass
class FurnaceResult:
    """Directional albedo estimates (M, 3) and their Monte Carlo standard errors (M, 3), float64."""

    albedo: torch.Tensor
    stderr: torch.Tensor


def white_furnace(material, wi, n_samples: int = 2 ** 16, seed: int = 0, method: str = "cosine",
                  uv=None, dtype: torch.dtype = torch.float32, device=None) -> FurnaceResult:
    """Estimate a(wi) for incident directions wi (M, 3) or (3,) (upper hemisphere, local frame).

    method: "cosine" samples wo with density cos/pi and averages f pi; "material" averages the weights of
    `material.sample` (checks the sampler too; needs can_sample). n_samples per direction; seed fixes the
    uniform numbers. Spatially varying materials are evaluated at one texel uv (2,).
    """
    wi = _directions(wi)
    if not isinstance(n_samples, int) or n_samples < 2:
        raise InputError(f"n_samples: expected an integer >= 2, got {n_samples!r}")
    if method not in _METHODS:
        raise InputError(f"method: expected one of {', '.join(_METHODS)}, got {method!r}")
    _check_material(material, "white_furnace")
    if method == "material" and not getattr(material, "can_sample", False):
        raise InputError(f"white_furnace: {type(material).__name__} cannot sample (can_sample = False); "
                         "use method='cosine'")
    uv = _texel(material, uv, "white_furnace")
    device = wi.device if device is None else torch.device(device)
    gen = torch.Generator(device="cpu").manual_seed(seed)
    total = torch.zeros(wi.shape[0], 3, dtype=torch.float64)
    total_sq = torch.zeros_like(total)
    rows = max(1, _BATCH // wi.shape[0])
    for start in range(0, n_samples, rows):
        k = min(rows, n_samples - start)
        u = torch.rand(k * wi.shape[0], 2, generator=gen, dtype=torch.float64).to(dtype=dtype, device=device)
        w_in = wi.to(dtype=dtype, device=device).repeat(k, 1)
        extra = {} if uv is None else {"uv": uv.to(dtype=dtype, device=device).expand(len(w_in), 2)}
        if method == "cosine":
            wo = sample_cosine_hemisphere(u)
            value = material.eval(Query(w_in, wo, **extra)) * math.pi
            value = torch.where((wo[:, 2] > 0).unsqueeze(-1), value, torch.zeros_like(value))
        else:
            value = material.sample(Query(w_in, **extra), u).weight
        value = value.detach().to("cpu", torch.float64).reshape(k, wi.shape[0], 3)
        if not bool(torch.isfinite(value).all()):
            raise InputError(f"white_furnace: {type(material).__name__} returned non-finite values "
                             f"({'eval' if method == 'cosine' else 'sample weights'})")
        total += value.sum(0)
        total_sq += (value * value).sum(0)
    mean = total / n_samples
    var = (total_sq / n_samples - mean * mean).clamp(min=0) * n_samples / (n_samples - 1)
    return FurnaceResult(albedo=mean, stderr=(var / n_samples).sqrt())


def _directions(wi) -> torch.Tensor:
    if not isinstance(wi, torch.Tensor):
        raise InputError(f"wi: expected a torch.Tensor of shape (M, 3) or (3,), got {type(wi).__name__}")
    if wi.dim() == 1:
        wi = wi.unsqueeze(0)
    check_directions(wi, "wi")
    if wi.shape[0] == 0:
        raise InputError("wi: expected at least one direction")
    return wi


def _check_material(material, who: str) -> None:
    if not callable(getattr(material, "eval", None)):
        raise InputError(f"{who}: expected a neumat Material (an object with eval(Query)), "
                         f"got {type(material).__name__}")
    if getattr(material, "full_sphere", False):
        raise InputError(f"{who}: {type(material).__name__} spans the whole sphere (full_sphere = True); "
                         "this tool checks surface BRDFs on the upper hemisphere")


def _texel(material, uv, who: str):
    """The texel (1, 2) at which a spatially varying material is evaluated, or None."""
    if not getattr(material, "spatially_varying", False):
        if uv is not None:
            raise InputError(f"{who}: uv is only used for spatially varying materials")
        return None
    if uv is None:
        raise InputError(f"{who}: {type(material).__name__} is spatially varying; pass uv=(u, v) in [0, 1]")
    uv = torch.as_tensor(uv, dtype=torch.float64).reshape(-1)
    if uv.shape != (2,) or not bool(((uv >= 0) & (uv <= 1)).all()):
        raise InputError(f"{who}: uv must be two numbers in [0, 1], got {uv.tolist()}")
    return uv.unsqueeze(0)
