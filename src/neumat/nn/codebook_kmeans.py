"""A VQ feature grid started from dense per-vertex features by k-means: how a dense warm-up of a NeuBRDF-like
model (`NeuBRDF.quantize_from_dense`, `SharedNeuBRDF.quantize_from_dense`) hands over to the codebook model."""
from __future__ import annotations

import torch

from neumat.core.errors import InputError
from neumat.nn.codebook import VQFeatures


def vq_from_dense(feats: torch.Tensor, used: torch.Tensor, bits: int, *, iterations: int = 25, margin: float = 1.0,
                  seed: int = 0, candidates: int = 0, weights: torch.Tensor | None = None,
                  who: str = "quantize_from_dense") -> VQFeatures:
    """A `VQFeatures` of feats.shape[0] vertices whose codebook (2^bits, k) is the k-means clustering (Lloyd,
    `iterations` rounds from a k-means++ start drawn with `seed`) of the features feats (V, k) of the vertices
    `used` (V,) bool, and whose index logits start at 0.01 N(0, 1) plus `margin` on each vertex's nearest codeword
    (so the argmax is the nearest codeword; unused vertices too). `candidates` K in [1, 2^bits]: each vertex keeps
    the logits of its K nearest codewords only (`VQFeatures.restrict`); 0 keeps all. `weights` (V, k), >= 0:
    weighted k-means, the distance of vertex s to codeword c being sum_j weights[s, j] (x_sj - c_j)^2 and each
    codeword the weighted mean of its vertices per channel (nearest codeword and candidates by the same distance);
    None: plain k-means. `who` names the caller in errors."""
    if isinstance(bits, bool) or not isinstance(bits, int) or not 1 <= bits <= 16:
        raise InputError(f"{who} index_bits: expected 1 .. 16, got {bits!r}")
    if isinstance(candidates, bool) or not isinstance(candidates, int) or not 0 <= candidates <= 2 ** bits:
        raise InputError(f"{who} candidates: expected 0 (all) or 1 .. {2 ** bits}, got {candidates!r}")
    if used.shape != feats.shape[:1] or used.dtype != torch.bool or not bool(used.any()):
        raise InputError(f"{who}: expected a non-empty mask ({feats.shape[0]},) of the vertices to cluster")
    feats = feats.detach()
    if weights is not None:
        weights = _checked_weights(weights, feats, who)
    data, w = feats[used], (None if weights is None else weights[used])
    m = 2 ** bits
    gen = torch.Generator(device="cpu").manual_seed(seed)
    # k-means++ start: each next codeword drawn with probability proportional to the squared distance
    # to the nearest one so far (ties of identical features only cost empty clusters)
    start = [data[int(torch.randint(data.shape[0], (1,), generator=gen))]]
    d2 = _row_sq_distance(data, w, start[0])
    for _ in range(m - 1):
        p = d2.double().cpu()
        i = int(torch.multinomial(p, 1, generator=gen)) if float(p.sum()) > 0 else \
            int(torch.randint(data.shape[0], (1,), generator=gen))
        start.append(data[i])
        d2 = torch.minimum(d2, _row_sq_distance(data, w, data[i]))
    code = torch.stack(start)
    mass = torch.ones_like(data) if w is None else w
    moment = data if w is None else w * data  # each vertex's share of its codeword's (weighted) sum
    order = _distance_order(data, w)
    for _ in range(iterations):
        near = order(code).argmin(-1)
        sums = torch.zeros_like(code).index_add_(0, near, moment)
        total = torch.zeros_like(code).index_add_(0, near, mass)
        code = torch.where(total > 0, sums / total.clamp(min=1e-30), code)  # empty clusters keep their place
    vq = VQFeatures(feats.shape[0], feats.shape[1], bits).to(feats.device, feats.dtype)
    with torch.no_grad():
        vq.codebook.copy_(code)
        logits = torch.randn(vq.logits.shape, generator=gen).to(vq.logits) * 0.01
        distance = _distance_order(feats, weights)(code)
        logits[torch.arange(logits.shape[0]), distance.argmin(-1)] += margin
        vq.logits.copy_(logits)
    if candidates:
        vq.restrict(distance.topk(candidates, -1, largest=False).indices)
    return vq


def _checked_weights(weights, feats: torch.Tensor, who: str) -> torch.Tensor:
    """k-means weights checked against the features (V, k) and made positive: + 1e-6 of their mean, so that a
    vertex no query reached (weight 0) still gets a nearest codeword by its features."""
    if not isinstance(weights, torch.Tensor) or weights.shape != feats.shape or not weights.is_floating_point():
        raise InputError(f"{who} weights: expected a float tensor {tuple(feats.shape)} (one per slot and channel), "
                         f"got {getattr(weights, 'shape', type(weights).__name__)}")
    w = weights.detach().to(feats)
    if not bool(torch.isfinite(w).all()) or bool((w < 0).any()) or float(w.sum()) <= 0:
        raise InputError(f"{who} weights: expected finite, non-negative weights, not all 0")
    return w + 1e-6 * w.mean()


def _row_sq_distance(x: torch.Tensor, w: torch.Tensor | None, c: torch.Tensor) -> torch.Tensor:
    """(N,) squared distances of the rows of x (N, k) to one point c (k,): sum_j w_nj (x_nj - c_j)^2 (w = 1 when
    None)."""
    d = (x - c).pow(2)
    return (d if w is None else w * d).sum(-1)


def _distance_order(x: torch.Tensor, w: torch.Tensor | None):
    """A function of codewords code (M, k) giving (N, M), increasing with the distance of each row of x (N, k) to
    each codeword: the Euclidean distance when w is None, else the weighted squared distance
    sum_j w_nj (x_nj - c_mj)^2 (w (N, k)), whose terms in x alone are computed here, once for all calls."""
    if w is None:
        return lambda code: torch.cdist(x, code)
    wx = w * x
    wxx = (wx * x).sum(-1, keepdim=True)
    return lambda code: wxx - 2 * wx @ code.t() + w @ (code * code).t()
