"""Angular latent textures over disk-projected half and difference vectors (Timonen et al. 2025, Sec. 3).

A direction w on the upper hemisphere is projected orthographically to the unit disk, w_perp = (w_x, w_y),
and addressed in polar coordinates r = |w_perp| (= sin theta), phi = atan2(w_y, w_x). A texture is a
(C, R, P) grid: rows are radii r_i = i / (R - 1) (row 0 at the pole, row R - 1 on the rim), columns are
azimuths phi_j = (j + 1/2) period / P. Reads are bilinear with circular padding in phi and repeat padding
in r (clamped at the rim); at the pole the first element [:, 0, 0] is broadcast to all phi, so the texture
is single-valued there.

The half-vector texture has period 2 pi. The difference-vector texture is read with phi_d wrapped to
[0, pi) (period pi): exchanging wi and wo maps d to (-d_x, -d_y, d_z), i.e. phi_d to phi_d + pi, so the
read is reciprocal by construction.
"""
from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from ..core.checks import check_int
from ..core.tensors import derived_from

_EPS = 1e-12


def half_difference(wi: torch.Tensor, wo: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Rusinkiewicz half and difference vectors (N, 3) each, as `neumat.core.coords.io_to_hd`, but without
    acos / atan2 so that gradients with respect to wi, wo stay finite (at h = +z, phi_h = 0 is used)."""
    h = wi + wo
    h = h / h.norm(dim=-1, keepdim=True).clamp(min=_EPS)
    s2 = h[:, 0] ** 2 + h[:, 1] ** 2
    pole = s2 < 1e-14
    s = torch.sqrt(torch.where(pole, torch.ones_like(s2), s2))
    cos_phi = torch.where(pole, torch.ones_like(s), h[:, 0] / s)
    sin_phi = torch.where(pole, torch.zeros_like(s), h[:, 1] / s)
    sin_theta = torch.where(pole, torch.zeros_like(s), s)
    cos_theta = h[:, 2]
    # d = R_y(-theta_h) R_z(-phi_h) wi
    x = cos_phi * wi[:, 0] + sin_phi * wi[:, 1]
    y = -sin_phi * wi[:, 0] + cos_phi * wi[:, 1]
    d = torch.stack([cos_theta * x - sin_theta * wi[:, 2], y, sin_theta * x + cos_theta * wi[:, 2]], -1)
    return h, d


def disk_polar(w: torch.Tensor, period: float = 2 * math.pi) -> tuple[torch.Tensor, torch.Tensor]:
    """(r, phi), each (N,), of the disk projection of unit vectors w (N, 3); phi wrapped to [0, period).
    Finite gradients everywhere (phi's gradient is 0 at the pole)."""
    x, y = w[:, 0], w[:, 1]
    r2 = x * x + y * y
    pole = r2 < 1e-14
    r = torch.sqrt(torch.where(pole, torch.ones_like(r2), r2))
    r = torch.where(pole, torch.zeros_like(r), r).clamp(max=1.0)
    phi = torch.atan2(torch.where(pole, torch.zeros_like(y), y), torch.where(pole, torch.ones_like(x), x))
    return r, torch.remainder(phi, period)


class AngularTexture(nn.Module):
    """A learned (C, R, P) polar texture (module docstring); forward(r (N,), phi (N,)) -> (N, C) (a
    transposed view of the channels-first `read`).

    period: 2 pi (half vectors) or pi (difference vectors). An optional `precondition` module maps the
    raw parameters to the texture of the forward pass.
    """

    def __init__(self, channels: int, radial: int, angular: int, period: float = 2 * math.pi,
                 init_std: float = 0.1, precondition: nn.Module | None = None) -> None:
        super().__init__()
        for name, v, lo in (("channels", channels, 1), ("radial", radial, 2), ("angular", angular, 1)):
            check_int(v, f"AngularTexture.{name}", lo)
        self.channels, self.radial, self.angular, self.period = channels, radial, angular, float(period)
        self.raw = nn.Parameter(torch.randn(channels, radial, angular) * init_std)
        self.precondition = precondition

    def texture(self) -> torch.Tensor:
        """(C, R, P) texture of the forward pass."""
        return self.raw if self.precondition is None else self.precondition(self.raw)

    def padded(self) -> torch.Tensor:
        """(C, R, P + 2) texture with the pole row set to texel (0, 0) and one circular column each side; built
        once while the texture is unchanged and no gradient is wanted (`derived_from`)."""
        return derived_from(self, "padded", [self.raw], self._pad)

    def _pad(self) -> torch.Tensor:
        tex = self.texture()
        rows = torch.cat([tex[:, :1, :1].expand(-1, 1, self.angular), tex[:, 1:]], 1)
        return torch.cat([rows[:, :, -1:], rows, rows[:, :, :1]], 2)

    def read(self, r: torch.Tensor, phi: torch.Tensor) -> torch.Tensor:
        """Channels-first read (C, N) of (r, phi) (N,): one fused bilinear `grid_sample` over `padded`
        (corner-aligned grid: row i at r = i / (R - 1), padded column j + 1 at phi_j)."""
        tex = self.padded()
        column = torch.remainder(phi.to(tex.dtype), self.period) * (self.angular / self.period) + 0.5
        grid = torch.stack([column * (2 / (self.angular + 1)) - 1, r.to(tex.dtype).clamp(0, 1) * 2 - 1], -1)
        out = F.grid_sample(tex.unsqueeze(0), grid.view(1, 1, -1, 2), mode="bilinear", padding_mode="border",
                            align_corners=True)
        return out.view(self.channels, -1)

    def forward(self, r: torch.Tensor, phi: torch.Tensor) -> torch.Tensor:
        return self.read(r, phi).t()

    def num_parameters(self) -> int:
        return self.raw.numel()

    def flops(self) -> int:
        """Bilinear read: 3 lerps (3 FLOPs each: sub, mul, add) per channel, plus ~12 for the addressing."""
        return 9 * self.channels + 12
