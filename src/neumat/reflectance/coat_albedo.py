"""Directional albedo of a rough dielectric coat's reflection lobe, tabulated for albedo-scaled layering.

For GGX reflection with separable Smith shadowing and unpolarised dielectric Fresnel (relative index eta),

    E(mu, alpha) = int f_coat(wi, wo) cos_o dwo,   wi = (sqrt(1 - mu^2), 0, mu),

is estimated per grid node with scrambled-Sobol visible-normal samples (Heitz 2018): wo = reflect(wi, m),
m ~ D_wi(m), weight F(wi . m) G1(wo), in float64. The grid is uniform in mu in [0, 1] and in sqrt(alpha) over
[ALPHA_MIN, 1]; lookups interpolate bilinearly. The cosine-weighted average E_avg(alpha) = int E 2 mu dmu is
integrated exactly from the same piecewise-linear interpolant, so that

    int (1 - E(mu_o)) 2 mu_o dmu_o = 1 - E_avg

holds to float precision for the interpolated table: albedo scaling by (1 - E(mu_i))(1 - E(mu_o)) / (1 - E_avg)
over a white Lambertian base then conserves energy up to the table's own error (about 1e-3).
"""
from __future__ import annotations

import math

import torch

from ..core.errors import InputError
from ..warp.ggx import sample_ggx_vndf
from ..warp.ggx_distribution import smith_g1
from .microfacet import fresnel_dielectric

#: smallest alpha tabulated (lookups clamp to it)
ALPHA_MIN = 1e-3


class CoatAlbedo:
    """E(mu, alpha) and E_avg(alpha) of one coat index `eta` (module docstring).

    mu_nodes, alpha_nodes: grid size; samples: Sobol samples per node (a power of two).
    """

    def __init__(self, eta: float, mu_nodes: int = 33, alpha_nodes: int = 32, samples: int = 4096) -> None:
        if not (isinstance(eta, (int, float)) and 1.0 <= eta <= 4.0):
            raise InputError(f"CoatAlbedo eta: expected a number in [1, 4], got {eta!r}")
        if mu_nodes < 2 or alpha_nodes < 2 or samples < 16:
            raise InputError(f"CoatAlbedo: need at least 2 x 2 nodes and 16 samples, got {mu_nodes} x {alpha_nodes}, "
                             f"{samples}")
        self.eta = float(eta)
        self.mu = torch.linspace(0, 1, mu_nodes, dtype=torch.float64)
        self.sqrt_alpha = torch.linspace(math.sqrt(ALPHA_MIN), 1, alpha_nodes, dtype=torch.float64)
        self.table = self._tabulate(samples)                  # (alpha_nodes, mu_nodes)
        self.average = self._average()                         # (alpha_nodes,)

    def _tabulate(self, samples: int) -> torch.Tensor:
        u = torch.quasirandom.SobolEngine(2, scramble=True, seed=0).draw(samples, dtype=torch.float64)
        u = u.clamp(1e-12, 1 - 1e-12)
        mu = self.mu.clamp(min=1e-4)
        rows = []
        for alpha in (self.sqrt_alpha ** 2).tolist():
            wi = torch.stack([(1 - mu * mu).sqrt(), torch.zeros_like(mu), mu], -1)      # (M, 3)
            w = wi.repeat_interleave(samples, 0)
            m = sample_ggx_vndf(w, u.repeat(len(mu), 1), alpha, alpha)
            cos_h = (w * m).sum(-1)
            wo = 2 * cos_h.unsqueeze(-1) * m - w
            weight = fresnel_dielectric(cos_h, self.eta) * smith_g1(wo, alpha, alpha)
            weight = torch.where(wo[:, 2] > 0, weight, torch.zeros_like(weight))
            rows.append(weight.view(len(mu), samples).mean(1))
        return torch.stack(rows)

    def _average(self) -> torch.Tensor:
        """int_0^1 E(mu) 2 mu dmu of the piecewise-linear interpolant in mu, per alpha node (exact)."""
        a, b = self.mu[:-1], self.mu[1:]
        ea, eb = self.table[:, :-1], self.table[:, 1:]
        h = b - a
        # int_a^b (ea (b - x) + eb (x - a)) / h 2x dx
        return (h / 3 * (ea * (2 * a + b) + eb * (a + 2 * b))).sum(-1)

    def _alpha_weights(self, alpha: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        s = alpha.to(torch.float64).clamp(ALPHA_MIN, 1).sqrt()
        x = (s - float(self.sqrt_alpha[0])) / float(self.sqrt_alpha[1] - self.sqrt_alpha[0])
        i = x.floor().clamp(0, len(self.sqrt_alpha) - 2).long()
        return i, (x - i).clamp(0, 1)

    def __call__(self, mu: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
        """E (N,) at cosines mu (N,) (clamped to [0, 1]) and alphas (N,) (clamped to [ALPHA_MIN, 1])."""
        i, t = self._alpha_weights(alpha)
        x = mu.to(torch.float64).clamp(0, 1) * (len(self.mu) - 1)
        j = x.floor().clamp(0, len(self.mu) - 2).long()
        s = x - j
        e = self.table.to(mu.device)
        lo = e[i, j] * (1 - s) + e[i, j + 1] * s
        hi = e[i + 1, j] * (1 - s) + e[i + 1, j + 1] * s
        return (lo * (1 - t) + hi * t).to(mu.dtype)

    def averaged(self, alpha: torch.Tensor) -> torch.Tensor:
        """E_avg (N,) at alphas (N,): linear in sqrt(alpha), so it is the exact average of the interpolated E."""
        i, t = self._alpha_weights(alpha)
        average = self.average.to(alpha.device)
        return (average[i] * (1 - t) + average[i + 1] * t).to(alpha.dtype)
