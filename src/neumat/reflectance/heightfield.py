"""Ray marching a periodic height field in torch (for generating BTFs with mesoscale effects).

Coordinates are in texel units: s along +u (columns, left to right), t along +v (rows, bottom to top), so
texel (row i, col j) of an H x W map has its centre at (s, t) = (j + 0.5, H - i - 0.5), the convention of
`neumat.io.texture_set`. The surface is z = height(s, t) (bilinear between texel centres, wrapping around
in s and t); directions (x, y, z) of the local frame move (s, t, z) by (x, y, z).
"""
from __future__ import annotations

import math

import torch

from ..core.errors import InputError


class HeightField:
    """A periodic height field z (H, W) in texel units with bilinear lookup and ray marching.

    step: horizontal march step in texels (the intersection is then refined by bisection).
    """

    def __init__(self, z: torch.Tensor, step: float = 0.25, refine: int = 10) -> None:
        if z.dim() != 2 or not bool(torch.isfinite(z).all()):
            raise InputError(f"HeightField z: expected a finite (H, W) tensor, got shape {tuple(z.shape)}")
        if not step > 0:
            raise InputError(f"HeightField step: expected > 0, got {step}")
        self.z = z.float()
        self.height, self.width = z.shape
        self.step = step
        self.refine = refine
        self.z_min = float(self.z.min())
        self.z_max = float(self.z.max())
        self.z_ref = float(self.z.mean())

    def sample(self, maps: torch.Tensor, s: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        """Bilinear wrap-around lookup of maps (H, W, C) at (s, t) (N,) -> (N, C)."""
        x = s - 0.5
        y = (self.height - t) - 0.5
        x0, y0 = torch.floor(x), torch.floor(y)
        fx, fy = (x - x0)[:, None], (y - y0)[:, None]
        x0, y0 = x0.long() % self.width, y0.long() % self.height
        x1, y1 = (x0 + 1) % self.width, (y0 + 1) % self.height
        return ((1 - fx) * (1 - fy) * maps[y0, x0] + fx * (1 - fy) * maps[y0, x1]
                + (1 - fx) * fy * maps[y1, x0] + fx * fy * maps[y1, x1])

    def height_at(self, s: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        return self.sample(self.z[..., None], s, t)[:, 0]

    def normals(self) -> torch.Tensor:
        """Unit normals (H, W, 3) from central differences of z (wrap-around)."""
        dz_ds = (torch.roll(self.z, -1, 1) - torch.roll(self.z, 1, 1)) / 2
        dz_dt = -(torch.roll(self.z, -1, 0) - torch.roll(self.z, 1, 0)) / 2  # t grows upwards, rows downwards
        n = torch.stack([-dz_ds, -dz_dt, torch.ones_like(self.z)], -1)
        return n / n.norm(dim=-1, keepdim=True)

    def _steps(self, w: torch.Tensor, dz: float) -> tuple[float, int]:
        """Parameter step and count to cover a vertical extent dz along directions w (N, 3)."""
        horizontal = float(w[:, :2].norm(dim=-1).max())
        z_min = float(w[:, 2].abs().min())
        step = self.step / max(horizontal, 1e-6)
        length = dz / max(z_min, 1e-6)
        step = min(step, max(length, 1e-6) / 2)
        return step, int(length / step) + 2

    def intersect_view(self, s0: torch.Tensor, t0: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        """First hit (N, 3) of the orthographic rays arriving along -wo (wo (N, 3), z > 0) through the reference
        plane z = z_ref at (s0, t0) (N,): parallax and masking come from the first intersection."""
        top = self.z_max + 1e-3
        start = torch.stack([s0, t0, torch.full_like(s0, self.z_ref)], -1) + wo * ((top - self.z_ref) / wo[:, 2:3])
        step, count = self._steps(wo, top - self.z_min + 1e-3)
        d = -wo
        lo = torch.zeros_like(s0)                      # last parameter known above the surface
        hit = torch.full_like(s0, float("inf"))
        for i in range(1, count + 1):
            p = start + d * (i * step)
            below = (p[:, 2] <= self.height_at(p[:, 0], p[:, 1])) & torch.isinf(hit)
            hit = torch.where(below, torch.full_like(hit, i * step), hit)
            lo = torch.where(torch.isinf(hit), torch.full_like(lo, i * step), lo)
            if not bool(torch.isinf(hit).any()):
                break
        hi = torch.where(torch.isinf(hit), lo, hit)
        for _ in range(self.refine):
            mid = (lo + hi) / 2
            p = start + d * mid[:, None]
            below = p[:, 2] <= self.height_at(p[:, 0], p[:, 1])
            hi = torch.where(below, mid, hi)
            lo = torch.where(below, lo, mid)
        p = start + d * hi[:, None]
        return torch.stack([p[:, 0], p[:, 1], self.height_at(p[:, 0], p[:, 1])], -1)

    def visible(self, p: torch.Tensor, wi: torch.Tensor, offset: float = 1e-3) -> torch.Tensor:
        """Whether the directional light along wi (N, 3), z > 0, reaches the surface points p (N, 3): False where
        the height field rises above the ray p + r wi (cast shadows)."""
        start = p + wi * (offset / wi[:, 2:3].clamp(min=1e-6))
        step, count = self._steps(wi, self.z_max - self.z_min + 1e-3)
        lit = torch.ones(p.shape[0], dtype=torch.bool, device=p.device)
        for i in range(1, count + 1):
            q = start + wi * (i * step)
            above_top = q[:, 2] > self.z_max
            blocked = q[:, 2] < self.height_at(q[:, 0], q[:, 1])
            lit = lit & ~(blocked & ~above_top)
            if bool(above_top.all()):
                break
        return lit

    def trace(self, p: torch.Tensor, d: torch.Tensor, offset: float = 1e-3, max_distance: float | None = None
              ) -> tuple[torch.Tensor, torch.Tensor]:
        """First hit (N, 3) of the rays from surface points p (N, 3) along unit directions d (N, 3) (any z), and
        whether they hit (N,) bool. The march starts `offset` above p and steps `step` texels horizontally (at
        most a quarter of the relief vertically), each ray until it hits; it escapes (False) when it rises above
        z_max or has not hit within `max_distance` horizontal texels (default: four periods, 4 max(H, W)). The
        hit returned for an escaping ray is its start."""
        max_distance = 4.0 * max(self.height, self.width) if max_distance is None else float(max_distance)
        start = p + torch.tensor([0.0, 0.0, offset], device=p.device, dtype=p.dtype)
        dz = d[:, 2]
        horizontal = d[:, :2].norm(dim=-1).clamp(min=1e-9)
        dt = torch.minimum(self.step / horizontal, max(self.z_max - self.z_min, 1e-3) / 4 / dz.abs().clamp(min=1e-9))
        t_exit = torch.where(dz > 0, (self.z_max - start[:, 2]) / dz.clamp(min=1e-9),
                             torch.full_like(dz, float("inf")))     # downward rays always meet the surface
        t_max = torch.minimum(t_exit.clamp(min=0), max_distance / horizontal)
        lo = torch.zeros_like(dz)                                   # last parameter known above the surface
        hit = torch.zeros_like(dz, dtype=torch.bool)
        active = torch.arange(p.shape[0], device=p.device)          # rays still marching
        i = 0
        while active.numel():
            i += 1
            r = i * dt[active]
            q = start[active] + d[active] * r[:, None]
            below = q[:, 2] <= self.height_at(q[:, 0], q[:, 1])
            hit[active[below]] = True
            lo[active[~below]] = r[~below]
            active = active[~below & (r < t_max[active])]
        hi = torch.where(hit, lo + dt, lo)
        for _ in range(self.refine):
            mid = (lo + hi) / 2
            q = start + d * mid[:, None]
            below = q[:, 2] <= self.height_at(q[:, 0], q[:, 1])
            hi = torch.where(hit & below, mid, hi)
            lo = torch.where(hit & ~below, mid, lo)
        q = start + d * torch.where(hit, hi, torch.zeros_like(hi))[:, None]
        return torch.stack([q[:, 0], q[:, 1], self.height_at(q[:, 0], q[:, 1])], -1), hit
