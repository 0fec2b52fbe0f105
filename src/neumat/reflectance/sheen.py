"""The sheen lobe of layered materials (cloth and dust fuzz) and its directional albedo table.

"Charlie" sheen (Estevez and Kulla 2017) with Neubelt and Pettineo's visibility, divided by its directional
albedo where that exceeds 1 so that it stays energy-bounded and reciprocal; tabulated on the grid of
`neumat.reflectance.coat_albedo.CoatAlbedo`.

Details: docs/notes/reflectance.md, section `neumat.reflectance.sheen`.
"""
from __future__ import annotations

import math

import torch

from ..core.errors import InputError
from ..warp.hemisphere import sample_cosine_hemisphere
from .coat_albedo import CoatAlbedo


#: smallest sheen alpha (lookups and the layer clamp to it): sin^20 is already a thin grazing rim
SHEEN_ALPHA_MIN = 0.05


def charlie_sheen(wi: torch.Tensor, wo: torch.Tensor, alpha: torch.Tensor | float) -> torch.Tensor:
    """D V (N,), the unnormalised Charlie lobe, for directions (N, 3) in the geometric frame and alphas (N,) or a
    number (module docstring); 0 where either direction is below the horizon."""
    alpha = torch.as_tensor(alpha, dtype=wi.dtype, device=wi.device).clamp(SHEEN_ALPHA_MIN, 1)
    h = torch.nn.functional.normalize(wi + wo, dim=-1)
    sin2 = (1 - h[:, 2] * h[:, 2]).clamp(min=0)
    d = (2 + 1 / alpha) * sin2.pow(0.5 / alpha) / (2 * math.pi)
    mu_i, mu_o = wi[:, 2].clamp(min=0), wo[:, 2].clamp(min=0)
    v = 1 / (4 * (mu_i + mu_o - mu_i * mu_o)).clamp(min=1e-12)
    return torch.where((wi[:, 2] > 0) & (wo[:, 2] > 0), d * v, torch.zeros_like(d))


def _interp(table_row: torch.Tensor, mu: torch.Tensor) -> torch.Tensor:
    """Piecewise-linear lookup of a row (M,) on the uniform mu grid of [0, 1] at mu (S,)."""
    x = mu.clamp(0, 1) * (len(table_row) - 1)
    j = x.floor().clamp(0, len(table_row) - 2).long()
    s = x - j
    return table_row[j] * (1 - s) + table_row[j + 1] * s


class SheenAlbedo(CoatAlbedo):
    """The normalised sheen lobe (`brdf`) and its E(mu, alpha), E_avg(alpha) (module docstring); lookups as
    `CoatAlbedo` (alphas clamped to [SHEEN_ALPHA_MIN, 1]); `raw` looks up E_0. Both tables come from one pass
    over the same samples (the normalisation of a sample is E_0 interpolated at its two cosines)."""

    def __init__(self, mu_nodes: int = 33, alpha_nodes: int = 16, samples: int = 4096) -> None:
        if mu_nodes < 2 or alpha_nodes < 2 or samples < 16:
            raise InputError(f"SheenAlbedo: need at least 2 x 2 nodes and 16 samples, got {mu_nodes} x "
                             f"{alpha_nodes}, {samples}")
        self.mu = torch.linspace(0, 1, mu_nodes, dtype=torch.float64)
        self.sqrt_alpha = torch.linspace(math.sqrt(SHEEN_ALPHA_MIN), 1, alpha_nodes, dtype=torch.float64)
        u = torch.quasirandom.SobolEngine(2, scramble=True, seed=0).draw(samples, dtype=torch.float64)
        wo = sample_cosine_hemisphere(u.clamp(1e-12, 1 - 1e-12))                       # (S, 3)
        mu = self.mu.clamp(min=1e-4)
        wi = torch.stack([(1 - mu * mu).sqrt(), torch.zeros_like(mu), mu], -1)          # (M, 3)
        w_i, w_o = wi.repeat_interleave(samples, 0), wo.repeat(len(mu), 1)
        raw, table = [], []
        for a in (self.sqrt_alpha ** 2).tolist():
            f = math.pi * charlie_sheen(w_i, w_o, a).view(len(mu), samples)              # (M, S)
            e0 = f.mean(1)
            raw.append(e0)
            table.append((f / _interp(e0, wo[:, 2]).clamp(min=1)).mean(1) / e0.clamp(min=1))
        self.raw = CoatAlbedo.__new__(CoatAlbedo)
        self.raw.mu, self.raw.sqrt_alpha, self.raw.table = self.mu, self.sqrt_alpha, torch.stack(raw)
        self.table = torch.stack(table)
        self.average = self._average()

    def _alpha_weights(self, alpha: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return super()._alpha_weights(alpha.clamp(min=SHEEN_ALPHA_MIN))

    def brdf(self, wi: torch.Tensor, wo: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
        """White sheen value f_sheen (N,) for directions (N, 3) in the geometric frame and alphas (N,)."""
        a = alpha.clamp(min=SHEEN_ALPHA_MIN)
        norm = lambda w: self.raw(w[:, 2].clamp(0, 1), a).clamp(min=1)  # noqa: E731
        return charlie_sheen(wi, wo, alpha) / (norm(wi) * norm(wo))
