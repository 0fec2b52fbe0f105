"""Reflectance-space errors between two Materials over random query configurations.

As in Timonen et al. 2025 (HDR metrics over 2^20 random configurations drawn like the training data):
wi and wo cosine-weighted on the upper hemisphere, uv uniform on [0, 1]^2 for spatially varying
materials; a `query_sampler` replaces this (e.g. to add footprints or object-space positions).
"""
from __future__ import annotations

import math
from typing import Callable

import torch

from ..core.errors import InputError
from ..core.material import Material, material_device
from ..core.query import Query
from ..warp.hemisphere import sample_cosine_hemisphere

#: query_sampler(n, generator, device) -> Query with n queries on `device`
QuerySampler = Callable[[int, torch.Generator, torch.device], Query]


def cosine_queries(n: int, generator: torch.Generator, device: torch.device, with_uv: bool = False) -> Query:
    """n queries with wi, wo drawn independently with density cos(theta)/pi (and uv uniform if `with_uv`).
    Random numbers come from `generator` (CPU), so results do not depend on `device`."""
    wi = sample_cosine_hemisphere(torch.rand(n, 2, generator=generator))
    wo = sample_cosine_hemisphere(torch.rand(n, 2, generator=generator))
    uv = torch.rand(n, 2, generator=generator) if with_uv else None
    return Query(wi, wo, uv=uv).to(device)


def reflectance_errors(model: Material, reference: Material, n: int = 2 ** 20, seed: int = 0, device=None,
                       batch: int = 2 ** 16, query_sampler: QuerySampler | None = None) -> dict[str, float]:
    """Errors of `model` against `reference` over n random queries, averaged over queries and RGB channels.

    With f = reference.eval(q), g = model.eval(q) (N, 3) and cos_i = max(wi_z, 0):
      rmse_hdr = sqrt(mean((g - f)^2))
      mae_hdr  = mean(|g - f|)
      rel_err  = sum(|g - f|) / sum(|f|)          (relative L1; 0 when both vanish, inf when only f does)
      log_err  = mean(|log(1 + max(f cos_i, 0)) - log(1 + max(g cos_i, 0))|)
                 (cosine-weighted log error, the NBRDF loss of Sztrajman et al. 2021).
    Runs under no_grad in batches of `batch` on `device` (default: `material_device(model, reference)`).
    Deterministic for a given (seed, batch): queries come from a CPU generator seeded with `seed`, through
    `query_sampler(n, generator, device)` if given, else `cosine_queries`.
    """
    if int(n) != n or n < 1 or int(batch) != batch or batch < 1:
        raise InputError(f"reflectance_errors: n and batch must be positive integers, got n={n}, batch={batch}")
    if query_sampler is None and (model.full_sphere or reference.full_sphere):
        raise InputError("reflectance_errors: full-sphere (translucent) materials need a query_sampler "
                         "(the default draws directions on the upper hemisphere only)")
    device = torch.device(device) if device is not None else material_device(model, reference)
    with_uv = model.spatially_varying or reference.spatially_varying
    generator = torch.Generator().manual_seed(seed)
    sums = torch.zeros(4, dtype=torch.float64, device=device)   # squared, absolute, |reference|, log
    with torch.no_grad():
        for start in range(0, n, batch):
            m = min(batch, n - start)
            q = query_sampler(m, generator, device) if query_sampler else cosine_queries(m, generator, device, with_uv)
            if len(q) != m:
                raise InputError(f"reflectance_errors: query_sampler returned {len(q)} queries, expected {m}")
            f = _eval(reference, q, "reference")
            g = _eval(model, q, "model")
            cos_i = q.wi[:, 2:3].clamp(min=0).to(torch.float64)
            d = g - f
            log_d = torch.log1p((f * cos_i).clamp(min=0)) - torch.log1p((g * cos_i).clamp(min=0))
            sums += torch.stack([(d * d).sum(), d.abs().sum(), f.abs().sum(), log_d.abs().sum()])
    sq, ab, ref_ab, lg = sums.tolist()
    count = 3 * n
    rel = ab / ref_ab if ref_ab > 0 else (0.0 if ab == 0 else math.inf)
    return {"rmse_hdr": math.sqrt(sq / count), "mae_hdr": ab / count, "rel_err": rel, "log_err": lg / count}


def _eval(material: Material, q: Query, name: str) -> torch.Tensor:
    """material.eval(q) as float64, checked to be (N, 3) and finite (a NaN would make every error NaN)."""
    value = material.eval(q)
    if not isinstance(value, torch.Tensor) or tuple(value.shape) != (len(q), 3):
        shape = tuple(value.shape) if isinstance(value, torch.Tensor) else type(value).__name__
        raise InputError(f"reflectance_errors: {name}.eval returned {shape}, expected ({len(q)}, 3)")
    bad = int((~torch.isfinite(value)).sum())
    if bad:
        raise InputError(f"reflectance_errors: the {name} ({material.describe()}) returned {bad} NaN or infinite "
                         f"value(s) on {len(q)} queries; expected finite values")
    return value.to(device=q.device, dtype=torch.float64)
