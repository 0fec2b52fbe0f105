"""Piecewise-constant 2D distribution on [0, 1]^2 (environment-map importance sampling).

values[i, j] covers y in [i/H, (i+1)/H] and x in [j/W, (j+1)/W]; points are p = (x, y). Sampling picks a
row from the marginal with u[:, 1], then a column from that row's conditional with u[:, 0]; both steps are
continuous and monotone, so the warp is invertible.
"""
from __future__ import annotations

import torch

from ..core.checks import check_shape
from ..core.errors import InputError
from ._checks import check_u


class Tabulated2D:
    """Distribution proportional to a non-negative table `values` (H, W).

    Tables are kept in float64 on the device of `values`; inputs must live on that device, outputs take
    the dtype of the input.
    """

    def __init__(self, values: torch.Tensor):
        check_shape(values, "values", (-1, -1))
        if values.numel() == 0:
            raise InputError(f"values: expected a non-empty (H, W) table, got shape {tuple(values.shape)}")
        v = values.detach().to(torch.float64)
        if bool(torch.isnan(v).any()) or bool(torch.isinf(v).any()):
            raise InputError("values: table holds NaN or inf")
        if v.min().item() < 0:
            raise InputError(f"values: must be non-negative, got min {v.min().item():.4g}")
        total = v.sum()
        if total.item() <= 0:
            raise InputError("values: table is all zeros, nothing to sample")
        self.height, self.width = v.shape
        self._density = v * (self.height * self.width / total)  # pdf on [0, 1]^2
        rows = v.sum(1)
        self._row_cdf = torch.cat([rows.new_zeros(1), torch.cumsum(rows, 0) / total])
        self._row_cdf[-1] = 1.0
        cond = torch.cumsum(v, 1)
        row_tot = cond[:, -1:]
        uniform = torch.arange(1, self.width + 1, dtype=v.dtype, device=v.device) / self.width
        cond = torch.where(row_tot > 0, cond / torch.where(row_tot > 0, row_tot, torch.ones_like(row_tot)), uniform)
        cond[:, -1] = 1.0
        cond = torch.cat([cond.new_zeros(self.height, 1), cond], 1)  # (H, W + 1)
        self._cond_cdf = cond
        # row i's conditional cdf shifted by i: one monotone array for a single batched search
        offsets = torch.arange(self.height, dtype=v.dtype, device=v.device).unsqueeze(1)
        self._flat_cdf = (cond + offsets).reshape(-1)

    def sample(self, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """u (N, 2) in [0, 1)^2 -> points p (N, 2) in [0, 1]^2 and their density pdf (N,)."""
        check_u(u)
        H, W = self.height, self.width
        dtype = u.dtype
        u = u.to(torch.float64)
        u0, u1 = u[:, 0].clamp(0, 1), u[:, 1].clamp(0, 1)
        i = (torch.searchsorted(self._row_cdf, u1, right=True) - 1).clamp(0, H - 1)
        lo, hi = self._row_cdf[i], self._row_cdf[i + 1]
        fy = ((u1 - lo) / torch.where(hi > lo, hi - lo, torch.ones_like(hi))).clamp(0, 1)
        key = u0 + i
        k = torch.searchsorted(self._flat_cdf, key, right=True) - 1
        j = (k - i * (W + 1)).clamp(0, W - 1)
        k = i * (W + 1) + j
        lo, hi = self._flat_cdf[k], self._flat_cdf[k + 1]
        fx = ((key - lo) / torch.where(hi > lo, hi - lo, torch.ones_like(hi))).clamp(0, 1)
        p = torch.stack([(j + fx) / W, (i + fy) / H], -1)
        return p.to(dtype), self._density[i, j].to(dtype)

    def pdf(self, p: torch.Tensor) -> torch.Tensor:
        """Density (N,) at points p (N, 2) with respect to area on [0, 1]^2 (0 outside)."""
        check_shape(p, "p", (-1, 2))
        i, j, _, _ = self._cell(p)
        inside = ((p >= 0) & (p <= 1)).all(-1)
        d = self._density[i, j]
        return torch.where(inside, d, torch.zeros_like(d)).to(p.dtype)

    def invert(self, p: torch.Tensor) -> torch.Tensor:
        """Inverse of `sample`: points p (N, 2) in [0, 1]^2 -> u (N, 2)."""
        check_shape(p, "p", (-1, 2))
        i, j, fx, fy = self._cell(p)
        u1 = self._row_cdf[i] + fy * (self._row_cdf[i + 1] - self._row_cdf[i])
        u0 = self._cond_cdf[i, j] + fx * (self._cond_cdf[i, j + 1] - self._cond_cdf[i, j])
        return torch.stack([u0, u1], -1).to(p.dtype)

    def _cell(self, p: torch.Tensor):
        """Row, column and in-cell fractions (float64) of points p (N, 2)."""
        q = p.to(torch.float64).clamp(0, 1)
        x, y = q[:, 0] * self.width, q[:, 1] * self.height
        j = x.floor().long().clamp(0, self.width - 1)
        i = y.floor().long().clamp(0, self.height - 1)
        return i, j, x - j, y - i
