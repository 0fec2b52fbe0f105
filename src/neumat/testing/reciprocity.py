"""Helmholtz reciprocity check: f(wi, wo) == f(wo, wi) on random upper-hemisphere direction pairs."""
from __future__ import annotations

from dataclasses import dataclass

import torch

from ..core.errors import InputError
from ..core.query import Query
from ..warp.hemisphere import sample_uniform_hemisphere
from .furnace import _check_material


@dataclass
class ReciprocityResult:
    """max_abs: largest |f(wi, wo) - f(wo, wi)|; max_rel: the same over max(|f|) where that exceeds atol;
    passed: every pair agrees within atol + rtol * max(|f(wi, wo)|, |f(wo, wi)|). Truthy when passed."""

    max_abs: float
    max_rel: float
    passed: bool

    def __bool__(self) -> bool:
        return self.passed


def reciprocity_check(material, n: int = 4096, seed: int = 0, rtol: float = 1e-4, atol: float = 1e-6,
                      dtype: torch.dtype = torch.float32, device=None) -> ReciprocityResult:
    """Compare f(wi, wo) with f(wo, wi) for n random pairs (uniform on the upper hemisphere).

    Spatially varying materials get a random uv per pair (the same for both orders). The defaults suit
    float32 evaluation; measured data is usually reciprocal only to about a percent.
    """
    _check_material(material, "reciprocity_check")
    if not isinstance(n, int) or n < 1:
        raise InputError(f"n: expected a positive integer, got {n!r}")
    if rtol < 0 or atol < 0:
        raise InputError(f"rtol / atol: expected non-negative tolerances, got {rtol}, {atol}")
    gen = torch.Generator(device="cpu").manual_seed(seed)
    u = torch.rand(n, 5, generator=gen, dtype=torch.float64)
    wi = sample_uniform_hemisphere(u[:, 0:2]).to(dtype=dtype, device=device)
    wo = sample_uniform_hemisphere(u[:, 2:4]).to(dtype=dtype, device=device)
    extra = {}
    if getattr(material, "spatially_varying", False):
        extra["uv"] = torch.rand(n, 2, generator=gen, dtype=torch.float64).to(dtype=dtype, device=device)
    f = material.eval(Query(wi, wo, **extra)).detach().to("cpu", torch.float64)
    g = material.eval(Query(wo, wi, **extra)).detach().to("cpu", torch.float64)
    if f.shape != (n, 3) or g.shape != (n, 3):
        raise InputError(f"reciprocity_check: {type(material).__name__}.eval returned shape {tuple(f.shape)}, "
                         f"expected ({n}, 3)")
    if not bool(torch.isfinite(f).all() and torch.isfinite(g).all()):
        raise InputError(f"reciprocity_check: {type(material).__name__}.eval returned non-finite values")
    diff = (f - g).abs()
    scale = torch.maximum(f.abs(), g.abs())
    big = scale > atol
    max_rel = float((diff[big] / scale[big]).max()) if bool(big.any()) else 0.0
    passed = bool((diff <= atol + rtol * scale).all())
    return ReciprocityResult(max_abs=float(diff.max()), max_rel=max_rel, passed=passed)
