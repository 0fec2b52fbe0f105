"""Distributions of training queries.

`QUERY_SAMPLERS.get(name)(source, model)` returns `draw(n, generator, device) -> Query`. Random numbers come
from `generator` (drawn on the generator's device, then moved to `device`), so a fit is reproducible from
its seed and resumable from the generator state. Methods may register their own.

Built-ins: "cosine", "rusinkiewicz", "merl", "cosine_merl", "replay", "replay_cells".

Details: docs/notes/fit.md, section `neumat.fit.query_samplers`.
"""
from __future__ import annotations

import math
from typing import Callable

import torch

from ..core.coords import rusinkiewicz_to_io
from ..core.errors import InputError
from ..core.material import Material, describe_source
from ..core.query import Query
from ..core.registry import Registry
from ..nn import healpix as hpx
from ..warp.hemisphere import sample_cosine_hemisphere
from ..warp.uniform import uniform
from .measured_samples import MeasuredSamples

QueryDraw = Callable[[int, torch.Generator, torch.device], Query]

QUERY_SAMPLERS: Registry = Registry("query sampler")


def _needs_uv(source: Material, model) -> bool:
    return bool(getattr(source, "spatially_varying", False) or getattr(model, "spatially_varying", False))


def _require_hemisphere(source: Material, sampler: str) -> None:
    if getattr(source, "full_sphere", False):
        name = describe_source(source)
        raise InputError(f"query sampler {sampler!r} draws BRDF queries on the upper hemisphere, but the source "
                         f"{name!r} spans the whole sphere")


@QUERY_SAMPLERS.register("cosine")
def cosine_queries(source: Material, model=None) -> QueryDraw:
    """Cosine-weighted wi and wo (see docs/notes/fit.md)."""
    _require_hemisphere(source, "cosine")
    with_uv = _needs_uv(source, model)

    def draw(n: int, generator: torch.Generator, device) -> Query:
        u = uniform(n, 6 if with_uv else 4, generator, device)
        uv = u[:, 4:6] if with_uv else None
        return Query(sample_cosine_hemisphere(u[:, 0:2]), sample_cosine_hemisphere(u[:, 2:4]), uv=uv)

    return draw


def _half_angle_queries(source: Material, model, sampler: str, theta_h_power: int) -> QueryDraw:
    """(theta_h, theta_d) = pi/2 (u0^p, u1), phi_h and phi_d uniform in [0, 2 pi), configurations with wi or wo
    below the horizon rejected; p = 1 is uniform in theta_h, p = 2 MERL's cell density."""
    _require_hemisphere(source, sampler)
    with_uv = _needs_uv(source, model)

    def draw(n: int, generator: torch.Generator, device) -> Query:
        got, count = [], 0
        while count < n:
            u = uniform(2 * (n - count) + 16, 6 if with_uv else 4, generator, device)
            half_pi = 0.5 * math.pi
            wi, wo = rusinkiewicz_to_io(half_pi * u[:, 0] ** theta_h_power, 2 * math.pi * u[:, 1], half_pi * u[:, 2],
                                        2 * math.pi * u[:, 3])
            ok = (wi[:, 2] > 0) & (wo[:, 2] > 0)
            wi, wo, u = wi[ok], wo[ok], u[ok]
            got.append((wi / wi.norm(dim=-1, keepdim=True), wo / wo.norm(dim=-1, keepdim=True), u[:, 4:6]))
            count += wi.shape[0]
        wi, wo, uv = (torch.cat(parts)[:n] for parts in zip(*got))
        return Query(wi, wo, uv=uv if with_uv else None)

    return draw


@QUERY_SAMPLERS.register("rusinkiewicz")
def rusinkiewicz_queries(source: Material, model=None) -> QueryDraw:
    """Uniform (theta_h, phi_h, theta_d, phi_d) with below-horizon configurations rejected."""
    return _half_angle_queries(source, model, "rusinkiewicz", 1)


@QUERY_SAMPLERS.register("merl")
def merl_queries(source: Material, model=None) -> QueryDraw:
    """MERL's cell density in theta_h (see docs/notes/fit.md)."""
    return _half_angle_queries(source, model, "merl", 2)


@QUERY_SAMPLERS.register("cosine_merl")
def cosine_merl_queries(source: Material, model=None) -> QueryDraw:
    """Half "cosine", half "merl" queries (the first n // 2 cosine-weighted); see docs/notes/fit.md."""
    cosine, merl = cosine_queries(source, model), merl_queries(source, model)

    def draw(n: int, generator: torch.Generator, device) -> Query:
        a, b = cosine(n // 2, generator, device), merl(n - n // 2, generator, device)
        uv = None if a.uv is None else torch.cat([a.uv, b.uv])
        return Query(torch.cat([a.wi, b.wi]), torch.cat([a.wo, b.wo]), uv=uv)

    return draw


def _require_samples(source: Material, sampler: str) -> None:
    if not isinstance(source, MeasuredSamples):
        name = describe_source(source)
        raise InputError(f"query sampler {sampler!r} needs a neumat.fit.measured_samples.MeasuredSamples source, "
                         f"got {name!r} ({type(source).__name__})")


@QUERY_SAMPLERS.register("replay")
def replay_queries(source: Material, model=None) -> QueryDraw:
    """Uniform draws of the stored samples of a MeasuredSamples source."""
    _require_samples(source, "replay")

    def draw(n: int, generator: torch.Generator, device) -> Query:
        index = torch.randint(len(source), (n,), generator=generator, device=generator.device).to(device)
        return source.query(index)

    return draw


#: HEALPix N_side of the direction cells "replay_cells" balances its draws over (96 cells per hemisphere): of
#: N_side 4 and 8 the better on a replayed RGL file (docs/neubrdf.md, "Sparse measurements and pruning")
REPLAY_CELLS_NSIDE = 4


def replay_cell_weights(source: MeasuredSamples, nside: int = REPLAY_CELLS_NSIDE) -> torch.Tensor:
    """Draw probability (N,) float64 of each stored sample under "replay_cells": 1 / (occupied cells x samples in
    its cell), a cell being the pair (HEALPix pixel of wi, of wo) at `nside` (uv not split)."""
    pixels = 12 * nside * nside
    cell = hpx.vec2pix(nside, source.wi) * pixels + hpx.vec2pix(nside, source.wo)
    _, inverse, counts = torch.unique(cell, return_inverse=True, return_counts=True)
    return 1.0 / (counts.numel() * counts[inverse].double())


@QUERY_SAMPLERS.register("replay_cells")
def replay_cells_queries(source: Material, model=None) -> QueryDraw:
    """Draws of the stored samples of a MeasuredSamples source in which every occupied (wi, wo) direction cell
    is equally likely (uniform within a cell): measurements crowd where their device put them (an RGL file's
    nodes into the specular peak), and the fit learns the rest of the hemisphere only if it is drawn."""
    _require_samples(source, "replay_cells")
    cdf = torch.cumsum(replay_cell_weights(source), 0)
    cdf /= cdf[-1].clone()

    def draw(n: int, generator: torch.Generator, device) -> Query:
        u = torch.rand(n, generator=generator, device=generator.device, dtype=torch.float64)
        index = torch.searchsorted(cdf.to(u.device), u, right=True).clamp(max=len(source) - 1)
        return source.query(index.to(device))

    return draw
