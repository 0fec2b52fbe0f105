"""Prefiltering a spatially varying point function over a Gaussian texture footprint (Timonen et al. 2025, Eq. 1).

    f(wi, wo | uv, Sigma) = E_{x ~ N(uv, Sigma)} f(wi, wo | x)

estimated with `samples` Monte Carlo positions per query, in chunks of at most `chunk` point evaluations.
Shared by the textured references (`neumat.reflectance.svbrdf`, `neumat.reflectance.layered`).
"""
from __future__ import annotations

from typing import Callable

import torch

from ..core.query import Query
from ..core.tensors import rows_per_slice
from ..nn.latent_texture import check_footprint, isotropic_footprint


def query_footprint(q: Query, width: int) -> torch.Tensor | None:
    """The query's footprint covariance (N, 2, 2) in uv^2, the isotropic one of q.lod for a texture `width` texels
    wide, or None (a point query)."""
    if q.footprint is not None:
        return check_footprint(q.footprint, "Query.footprint")
    if q.lod is not None:
        return isotropic_footprint(q.lod, width)
    return None


def filtered_eval(point_eval: Callable[[torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor], q: Query,
                  cov: torch.Tensor, samples: int, chunk: int, generator: torch.Generator,
                  mean_eval: Callable[[torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor] | None = None
                  ) -> torch.Tensor:
    """Mean of point_eval(wi, wo, x) (N, 3) over `samples` positions x ~ N(q.uv, cov) per query; cov (N, 2, 2).
    Positions come from `generator` (fresh ones every call). mean_eval(wi (n, 3), wo (n, 3), x (n, samples, 2)), where
    given, computes a chunk's means at once (a fused kernel), from the same positions."""
    chol = torch.linalg.cholesky(cov.double()).to(q.dtype)
    per_chunk = max(1, rows_per_slice(chunk, q.device) // samples)
    out = []
    for s in range(0, len(q), per_chunk):
        e = min(len(q), s + per_chunk)
        z = torch.randn(e - s, samples, 2, generator=generator, device=generator.device).to(q.device, q.dtype)
        pts = q.uv[s:e, None, :] + torch.einsum("nij,nkj->nki", chol[s:e], z)
        if mean_eval is not None:
            out.append(mean_eval(q.wi[s:e], q.wo[s:e], pts))
            continue
        rep = lambda t: t[s:e, None, :].expand(-1, samples, -1).reshape(-1, t.shape[-1])  # noqa: E731
        f = point_eval(rep(q.wi), rep(q.wo), pts.reshape(-1, 2))
        out.append(f.reshape(e - s, samples, 3).mean(1))
    return torch.cat(out) if out else q.wi.new_zeros(0, 3)
