"""Walker's alias method: O(1) sampling of a discrete distribution (environment-map texels).

Table: bucket k of n equal buckets keeps itself with probability `keep[k]` and otherwise yields `alias[k]`.
Built vectorised with the prefix-sum construction of Huebschle-Schneider and Sanders ("Parallel weighted
random sampling", 2019): with weights scaled to mean 1, light items (w < 1) lay their deficits 1 - w end to
end on one axis, heavy items (w > 1) their excesses w - 1 on another of the same length. A light item takes
its whole deficit from the heavy item whose excess interval holds the start of its deficit interval. A heavy
item whose excess interval ends strictly inside a light item's deficit interval has given away that overlap
beyond its excess; its own bucket then lacks exactly that much and takes it from the next heavy item.
"""
from __future__ import annotations

import torch

from ..core.errors import InputError


class AliasTable:
    """Alias table of non-negative `weights` (n,) (float64 build; sampling in float64 or float32).

    keep: (n,) probability that bucket k returns k; alias: (n,) int64 index returned otherwise.
    """

    def __init__(self, weights: torch.Tensor) -> None:
        w = weights.detach().to(torch.float64).reshape(-1)
        if w.numel() == 0 or not bool(torch.isfinite(w).all()) or bool((w < 0).any()) or not float(w.sum()) > 0:
            raise InputError("alias table: weights must be finite, non-negative, not all zero and non-empty")
        n = w.numel()
        w = w * (n / w.sum())
        keep = torch.ones_like(w)
        alias = torch.arange(n, device=w.device)
        light = torch.nonzero(w < 1).squeeze(-1)
        heavy = torch.nonzero(w > 1).squeeze(-1)
        if light.numel() and heavy.numel():
            deficit = 1 - w[light]
            excess = w[heavy] - 1
            light_start, light_end = _intervals(deficit)
            heavy_start, heavy_end = _intervals(excess)
            last = heavy.numel() - 1
            donor = (torch.searchsorted(heavy_start, light_start, right=True) - 1).clamp(0, last)
            keep[light] = w[light]
            alias[light] = heavy[donor]
            # the light interval holding each heavy item's end; a strictly inner end means a shortfall
            inside = (torch.searchsorted(light_start, heavy_end, right=True) - 1).clamp(0, light.numel() - 1)
            shortfall = (light_end[inside] - heavy_end).clamp(min=0)
            shortfall = torch.where(light_start[inside] < heavy_end, shortfall, torch.zeros_like(shortfall))
            keep[heavy] = (1 - shortfall).clamp(0, 1)
            nxt = (torch.searchsorted(heavy_start, heavy_end, right=True) - 1).clamp(0, last)
            alias[heavy] = torch.where(shortfall > 0, heavy[nxt], heavy)
        self.n = n
        self.keep = keep
        self.alias = alias
        self.keep32 = keep.float()

    def probabilities(self) -> torch.Tensor:
        """The distribution (n,) float64 the table encodes (for tests): (keep_k + sum over aliases to k) / n."""
        p = self.keep.clone()
        p.index_add_(0, self.alias, 1 - self.keep)
        return p / self.n

    def sample(self, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """u (N, 2) in [0, 1)^2 -> indices (N,) int64 and two fresh uniforms (N,), (N,) for positions inside the
        chosen item: the fraction of u[:, 0] * n beyond its bucket, and u[:, 1] rescaled after the keep / alias
        choice. In float32 the first carries only 24 - log2(n) bits; pass float64 u for full resolution."""
        x = u[:, 0] * self.n
        k = x.long().clamp(0, self.n - 1)
        frac = (x - k).clamp(0, 1)
        keep = (self.keep if u.dtype == torch.float64 else self.keep32)[k]
        v = u[:, 1]
        stay = v < keep
        index = torch.where(stay, k, self.alias[k])
        v = torch.where(stay, v / keep.clamp(min=1e-30), (v - keep) / (1 - keep).clamp(min=1e-30))
        return index, frac, v.clamp(0, 1)


def _intervals(lengths: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Start and end (n,), (n,) of intervals of `lengths` laid end to end from 0; each start is bit-for-bit
    the previous end, so searches land in the right interval."""
    end = torch.cumsum(lengths, 0)
    return torch.cat([end.new_zeros(1), end[:-1]]), end
