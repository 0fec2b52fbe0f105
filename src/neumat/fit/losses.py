"""Training losses between predicted and target BRDF values.

A loss is built as `LOSSES.get(name)()` and called `loss(pred (N, 3), target (N, 3), q: Query)` -> scalar.
Losses are `nn.Module`s, so a loss that keeps state (running statistics) keeps it in buffers, which the
trainer checkpoints. Models and recipe modules may register their own at import time.

Built-ins (means over the N queries and 3 channels):
  "log_cos":  |log(1 + f_hat cos_i) - log(1 + f cos_i)|, cos_i = max(wi_z, 0), f clamped at 0 (measured tables
              hold small negative values, e.g. 12 % of RGL cc_ibiza_sunset's, whose log would be NaN below
              -1 / cos_i; a BRDF is non-negative). The L1 (absolute) form,
              as NBRDF (Sztrajman et al. 2021; their code's `mean_absolute_logarithmic_error` on
              cosine-weighted values) and Neural Appearance Models (Zeltner et al. 2024, "L1 loss in log
              space"); NeuBRDF leaves its loss to the supplement, and follows NBRDF in evaluation.
  "log_cos_eps": |log(eps + f_hat cos_i) - log(eps + f cos_i)|, eps = 0.01: log_cos is this with eps = 1, under
              which values below ~0.01 (the tails of a sharp lobe, 0.007 - 0.04 sr^-1 on MERL chrome 8 - 16 deg
              off the mirror direction) carry almost no gradient (f_hat cos / (1 + f_hat cos)), and fits that also
              see the peak let them fall to 1e-10 (`benchmarks/studies/neubrdf/results/neubrdf_direction_init.md`).
  "log_cos_eps_linear": log_cos_eps + w |f_hat cos_i - f cos_i| / mean(f cos_i), w = 0.5, the linear term per
              channel normalised by the batch's mean cosine-weighted target (stop gradient): in log space its
              gradient on a query is proportional to f_hat cos_i, so it weighs queries by what they add to a
              rendered pixel, where a log loss weighs a sharp lobe's peak like its tails. Measured once on
              MERL-like steel (NeuBRDF, direction_inputs "hd"): image MAE 0.0089 -> 0.0055, chrome 0.0029 ->
              0.0027; no recipe uses it, since warped direction inputs did more
              (`benchmarks/studies/neubrdf/results/neubrdf_table3_hd_warp.md`, section 1).
  "l1":       |f_hat - f|.
  "l2":       (f_hat - f)^2.
  "relative": (f_hat - f)^2 / (sg(f_hat)^2 + eps), eps = 0.01, the prediction-relative L2 of Noise2Noise
              (Lehtinen et al. 2018) used by Timonen et al. 2025 (sg = stop gradient).
  "relative_l2_mix": per query over the RGB vector, averaged over the batch (Timonen et al. 2025, Eq. 10):
              lambda |f - f_hat|^2 / |sg(f_hat) + eps|^2 + (1 - lambda) |f - f_hat|^2, lambda = 0.9999,
              eps = 1e-6; the loss of `neumat.fit.recipes.multiscale`.
"""
from __future__ import annotations

import torch
from torch import nn

from ..core.query import Query
from ..core.registry import Registry

LOSSES: Registry = Registry("loss")


def _cos_i(q: Query, like: torch.Tensor) -> torch.Tensor:
    return q.wi[:, 2:3].clamp(min=0).to(like.dtype)


@LOSSES.register("log_cos")
class LogCosLoss(nn.Module):
    """mean |log(1 + f_hat cos_i) - log(1 + f cos_i)| (NBRDF)."""

    def forward(self, pred: torch.Tensor, target: torch.Tensor, q: Query) -> torch.Tensor:
        c = _cos_i(q, pred)
        return (torch.log1p(pred * c) - torch.log1p(target.clamp(min=0) * c)).abs().mean()


@LOSSES.register("log_cos_eps")
class LogCosEpsLoss(nn.Module):
    """mean |log(eps + f_hat cos_i) - log(eps + f cos_i)|, eps = 0.01."""

    eps = 0.01

    def forward(self, pred: torch.Tensor, target: torch.Tensor, q: Query) -> torch.Tensor:
        c = _cos_i(q, pred)
        return (torch.log(self.eps + pred * c) - torch.log(self.eps + target.clamp(min=0) * c)).abs().mean()


@LOSSES.register("log_cos_eps_linear")
class LogCosEpsLinearLoss(LogCosEpsLoss):
    """log_cos_eps + weight * mean |f_hat cos_i - f cos_i| / mean(f cos_i) (per channel, over the batch)."""

    def __init__(self, weight: float = 0.5) -> None:
        super().__init__()
        self.weight = weight

    def forward(self, pred: torch.Tensor, target: torch.Tensor, q: Query) -> torch.Tensor:
        c = _cos_i(q, pred)
        t = target.clamp(min=0) * c
        scale = t.mean(0).clamp(min=1e-8)
        linear = ((pred * c - t).abs().mean(0) / scale).mean()
        return super().forward(pred, target, q) + self.weight * linear


@LOSSES.register("l1")
class L1Loss(nn.Module):
    """mean |f_hat - f|."""

    def forward(self, pred: torch.Tensor, target: torch.Tensor, q: Query) -> torch.Tensor:
        return (pred - target).abs().mean()


@LOSSES.register("l2")
class L2Loss(nn.Module):
    """mean (f_hat - f)^2."""

    def forward(self, pred: torch.Tensor, target: torch.Tensor, q: Query) -> torch.Tensor:
        return (pred - target).square().mean()


@LOSSES.register("relative")
class RelativeL2Loss(nn.Module):
    """mean (f_hat - f)^2 / (sg(f_hat)^2 + eps) (Noise2Noise's HDR loss)."""

    def __init__(self, eps: float = 0.01) -> None:
        super().__init__()
        self.eps = eps

    def forward(self, pred: torch.Tensor, target: torch.Tensor, q: Query) -> torch.Tensor:
        return ((pred - target).square() / (pred.detach().square() + self.eps)).mean()


@LOSSES.register("relative_l2_mix")
class RelativeL2MixLoss(nn.Module):
    """Eq. 10: prediction-relative L2 mixed with plain L2 (stop-gradient on the denominator)."""

    def __init__(self, weight: float = 0.9999, eps: float = 1e-6) -> None:
        super().__init__()
        self.weight, self.eps = weight, eps

    def forward(self, pred: torch.Tensor, target: torch.Tensor, q: Query) -> torch.Tensor:
        sq = (pred - target).square().sum(-1)
        rel = sq / (pred.detach() + self.eps).square().sum(-1)
        return (self.weight * rel + (1 - self.weight) * sq).mean()
