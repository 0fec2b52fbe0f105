"""Directionally blurred training targets for narrow peaks (Zeltner et al. 2024, Sec. 5: "we initially blur the
material directionally by averaging multiple samples from a small cone centered on wo. The angle of the cone
decreases during training, so that the network initially learns broad features of the material before
converging to the reference").

    f_blur(wi, wo) = (1 / K) sum_k f(wi, w_k),   w_k uniform on the spherical cap of half-angle theta around wo,

with f = 0 for w_k below the horizon. The angle follows `blur_angle`: theta_0 at the first step, falling linearly
to 0 at a fraction `until` of the training, the plain reference after that.
"""
from __future__ import annotations

import math
from dataclasses import replace

import torch

from neumat.core.errors import InputError
from neumat.core.frames import frame_from_normal_tangent, to_world
from neumat.core.query import Query


def blur_angle(step: int, total: int, degrees: float, until: float) -> float:
    """Cone half-angle in radians at `step` (0-based) of `total`: degrees at 0, linearly to 0 at until * total."""
    if degrees <= 0 or total <= 0:
        return 0.0
    return math.radians(degrees) * max(0.0, 1.0 - step / max(until * total, 1e-9))


def sample_cone(axis: torch.Tensor, half_angle: float, u: torch.Tensor) -> torch.Tensor:
    """Directions (N, K, 3) uniform on the spherical caps of half-angle `half_angle` (radians) around the unit
    axes (N, 3), from uniforms u (N, K, 2)."""
    n, k = u.shape[:2]
    cos_t = 1 - u[..., 0] * (1 - math.cos(half_angle))
    sin_t = (1 - cos_t * cos_t).clamp(min=0).sqrt()
    phi = 2 * math.pi * u[..., 1]
    local = torch.stack([sin_t * phi.cos(), sin_t * phi.sin(), cos_t], -1).reshape(n * k, 3)
    a = axis[:, None, :].expand(n, k, 3).reshape(n * k, 3)
    helper = torch.where((a[:, :1].abs() < 0.9), torch.tensor([1.0, 0.0, 0.0], dtype=a.dtype, device=a.device),
                         torch.tensor([0.0, 1.0, 0.0], dtype=a.dtype, device=a.device))
    t, b = frame_from_normal_tangent(a, helper)
    return to_world(local, t, b, a).reshape(n, k, 3)


def blurred_eval(source, q: Query, half_angle: float, samples: int, generator: torch.Generator) -> torch.Tensor:
    """f_blur (N, 3) of the source at the queries (module docstring); the plain value when half_angle is 0."""
    if half_angle <= 0:
        return source.eval(q)
    if not (isinstance(samples, int) and samples >= 1):
        raise InputError(f"blurred_eval samples: expected a positive integer, got {samples!r}")
    n = len(q)
    u = torch.rand(n, samples, 2, generator=generator, device=generator.device).to(q.wi)
    w = sample_cone(q.wo, half_angle, u).reshape(n * samples, 3)
    rep = {name: getattr(q, name).repeat_interleave(samples, 0) for name in ("wi", "uv", "footprint", "lod", "x", "n")
           if getattr(q, name) is not None}
    up = w[:, 2] > 0
    w = torch.where(up.unsqueeze(-1), w, torch.tensor([0.0, 0.0, 1.0], dtype=w.dtype, device=w.device))
    f = source.eval(replace(q, wo=w, **rep))
    f = torch.where(up.unsqueeze(-1), f, torch.zeros_like(f))
    return f.reshape(n, samples, 3).mean(1)
