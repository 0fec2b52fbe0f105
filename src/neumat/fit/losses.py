"""Training losses between predicted and target BRDF values.

A loss is built as `LOSSES.get(name)()` and called `loss(pred (N, 3), target (N, 3), q: Query)` -> scalar.
Losses are `nn.Module`s, so a loss that keeps state (running statistics) keeps it in buffers, which the
trainer checkpoints. Methods may register their own at import time.

Built-ins: "log_cos", "log_cos_eps", "log_cos_eps_linear", "l1", "l2", "relative", "relative_l2_mix",
"relative_l2_huber", "relative_l2_robust".

Details: docs/notes/fit.md, section `neumat.fit.losses`.
"""
from __future__ import annotations

import math

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
    """Eq. 10: prediction-relative L2 mixed with plain L2 (stop-gradient on the denominator). `clip`: see
    `RelativeL2HuberLoss` (None: the paper's loss)."""

    def __init__(self, weight: float = 0.9999, eps: float = 1e-6, clip: float | None = None) -> None:
        super().__init__()
        self.weight, self.eps, self.clip = weight, eps, clip

    def forward(self, pred: torch.Tensor, target: torch.Tensor, q: Query) -> torch.Tensor:
        sq = (pred - target).square().sum(-1)
        rel = sq / (pred.detach() + self.eps).square().sum(-1)
        if self.clip is not None:  # Huber in the relative residual r = sqrt(rel): linear beyond r = clip
            c2 = self.clip ** 2
            r = rel.clamp(min=c2).sqrt()  # clamped first: no infinite sqrt gradient at rel = 0 in the other branch
            rel = torch.where(rel > c2, 2 * self.clip * r - c2, rel)
        return (self.weight * rel + (1 - self.weight) * sq).mean()


#: relative residual beyond which "relative_l2_huber" grows linearly (issue 55: `RelativeL2HuberLoss`)
HUBER_CLIP = 10.0


@LOSSES.register("relative_l2_huber")
class RelativeL2HuberLoss(RelativeL2MixLoss):
    """Eq. 10 with each query's relative residual r = |f_hat - f| / |sg(f_hat) + eps| Huberised beyond `clip`
    (r^2 up to clip, 2 clip r - clip^2 beyond): the same loss and gradient wherever the prediction is within
    `clip` times the target's scale, and one query's pull on log f_hat bounded by 2 clip instead of 2 f / f_hat.
    On a near-mirror (alpha ~ 0.008) the Eq. 10 gradient of the handful of queries that hit an unresolved peak
    (f / f_hat ~ 1e3) outweighs the rest of a 4096-query batch and the fit does not settle (issue 55,
    benchmarks/studies/multiscale/results/polished_metal_stability.md)."""

    def __init__(self, weight: float = 0.9999, eps: float = 1e-6, clip: float = HUBER_CLIP) -> None:
        super().__init__(weight, eps, clip)


#: the smallest |f_hat| "relative_l2_robust" divides by (a prediction that underflowed to 0 gets no gradient anyway)
_TINY = 1e-30


@LOSSES.register("relative_l2_robust")
class RelativeL2RobustLoss(nn.Module):
    """Eq. 10 up to relative residual `clip`, and beyond it (a query under-predicted more than `clip` times its
    prediction's scale) c^2 + 2 c log((1 + q) / (1 + c)), q = |f_hat - f| / |f_hat| without stop-gradient or eps.

    Each such query pulls log f_hat up by 2 c, as `relative_l2_huber` does wherever f_hat >> eps (one peak query
    does not outweigh a batch), but (1) without its dead zone: with eps in the denominator, a prediction that fell
    far below eps (1e-6; the exp decoders reach 1e-16 on a near-mirror, against targets of 1e-4) pulled log f_hat
    by 2 c f_hat / (f_hat + eps) -> 0 however far below its target it was; and (2) the recorded value is the
    potential of that pull, so the fit's loss records track what it descends: the stop-gradient denominator made
    the Huber value grow as f / f_hat while the step pulled by a constant, and a fit that (correctly, for that
    gradient) let an unresolved mirror peak go recorded a loss 30x above its first (issue 55,
    benchmarks/studies/multiscale/results/polished_metal_stability.md). Wherever r <= clip (every query of a rough
    set after the first steps) it is Eq. 10."""

    def __init__(self, weight: float = 0.9999, eps: float = 1e-6, clip: float = HUBER_CLIP) -> None:
        super().__init__()
        self.weight, self.eps, self.clip = weight, eps, clip

    def forward(self, pred: torch.Tensor, target: torch.Tensor, q: Query) -> torch.Tensor:
        c = self.clip
        sq = (pred - target).square().sum(-1)
        rel = sq / (pred.detach() + self.eps).square().sum(-1)
        tail = rel > c * c
        ratio = sq.clamp(min=_TINY).sqrt() / pred.norm(dim=-1).clamp(min=_TINY)
        ratio = torch.where(tail, ratio, torch.full_like(ratio, c))  # no gradient through the other branch
        rel = torch.where(tail, c * c + 2 * c * (torch.log1p(ratio) - math.log1p(c)), rel)
        return (self.weight * rel + (1 - self.weight) * sq).mean()
