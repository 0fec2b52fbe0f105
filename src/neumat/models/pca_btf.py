"""PCA baseline for BTFs (the paper's Table 5): per BTF and YUV channel, a truncated PCA of the matrix whose
rows are texels and whose columns are the L x V angular samples, in the same model space as SparseBTF
(log(x + eps), RGB -> YUV). Stored: per channel a mean over texels (L V), r basis vectors (L V x r) and
r coefficients per texel (H W x r), all float16. `decompose` computes the principal components once per
BTF (exactly from the smaller Gram matrix, or by randomised subspace iteration when both sides are large, as
for 151 x 151 directions and 100 x 100 texels); `rank_budget` gives the component count of a storage budget
and `best_ranks` (of the decomposition's eigenvalues) its least-error split over Y, U, V, so PCA can be
compared with SparseBTF at equal storage. Lookup: the same wrap-around bilinear and k-nearest angular
interpolation as `TabulatedBTF`, in linear RGB.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn
from neumat.core.config import resolve_config
from neumat.core.errors import InputError
from neumat.core.material import upper_hemisphere
from neumat.core.query import Query
from neumat.models.base import LearnedMaterial
from neumat.models.registry import MODELS
from neumat.models.sparse_dictionary import model_space_to_rgb, rgb_to_model_space
from neumat.reflectance.btf import TabulatedBTF, angular_weights, bilinear_taps


@dataclass
class Config:
    """PCA-BTF sizes."""

    n_light: int = 151
    """Light directions of the BTF."""
    n_view: int = 151
    """View directions of the BTF."""
    height: int = 400
    """H texels."""
    width: int = 400
    """W texels."""
    ranks: tuple[int, int, int] = (64, 16, 16)
    """Principal components kept for Y, U, V."""
    log_eps: float = 0.01
    """eps of the log transform."""
    neighbours: int = 3
    """k nearest direction bins of the angular interpolation."""


@MODELS.register("pca-btf")
class PCABTF(LearnedMaterial):
    """Truncated PCA of a BTF (module docstring). Build with `PCABTF.fit(btf, ranks)`."""

    name = "pca-btf"
    paper = "per-BTF PCA: baseline of SparseBTF (Kavoosi et al.)"
    source_kinds = ("btf",)
    can_sample = False
    spatially_varying = True
    Config = Config

    def __init__(self, config: Config | None = None, **kwargs) -> None:
        nn.Module.__init__(self)
        cfg = resolve_config(Config, config, kwargs, 'PCABTF')
        for name in ("n_light", "n_view", "height", "width", "neighbours"):
            if getattr(cfg, name) < 1:
                raise InputError(f"PCABTF.{name}: expected a positive integer, got {getattr(cfg, name)!r}")
        if len(cfg.ranks) != 3 or any(r < 0 for r in cfg.ranks):
            raise InputError(f"PCABTF.ranks: expected three non-negative integers, got {cfg.ranks!r}")
        self.cfg = cfg
        lv, hw, r = cfg.n_light * cfg.n_view, cfg.height * cfg.width, max(max(cfg.ranks), 1)
        self.register_buffer("light_dirs", torch.zeros(cfg.n_light, 3))
        self.register_buffer("view_dirs", torch.zeros(cfg.n_view, 3))
        self.register_buffer("mean", torch.zeros(3, lv))
        self.register_buffer("basis", torch.zeros(3, lv, r))
        self.register_buffer("coeffs", torch.zeros(3, hw, r))

    @classmethod
    def fit(cls, btf: TabulatedBTF, ranks: tuple[int, int, int], log_eps: float = 0.01,
            neighbours: int = 3, decomposition: "Decomposition | None" = None) -> "PCABTF":
        """Truncated PCA of `btf` with `ranks` components for Y, U, V (from `decomposition`, a `decompose` of
        this BTF with at least max(ranks) components, when given)."""
        l, v, h, w, _ = btf.data.shape
        ranks = tuple(int(r) for r in ranks)
        dec = decomposition if decomposition is not None else decompose(btf, log_eps, max(ranks))
        if dec.mean.shape[1] != l * v or dec.coeffs.shape[1] != h * w or dec.log_eps != log_eps:
            raise InputError(f"PCABTF.fit: the decomposition is of another BTF ({dec.mean.shape[1]} angular samples, "
                             f"{dec.coeffs.shape[1]} texels, log_eps {dec.log_eps}) than this one ({l * v}, {h * w}, "
                             f"{log_eps})")
        if any(r > len(e) and len(e) < min(l * v, h * w) for r, e in zip(ranks, dec.eigenvalues)):
            raise InputError(f"PCABTF.fit: ranks {ranks} exceed the {[len(e) for e in dec.eigenvalues]} components "
                             "the decomposition kept")
        cfg = Config(n_light=l, n_view=v, height=h, width=w, ranks=ranks, log_eps=log_eps, neighbours=neighbours)
        model = cls(cfg).to(btf.data.device)
        model.light_dirs.copy_(btf.light_dirs)
        model.view_dirs.copy_(btf.view_dirs)
        model.mean.copy_(dec.mean)
        for c in range(3):
            r = min(ranks[c], len(dec.eigenvalues[c]))
            model.basis[c, :, :r] = dec.basis[c, :, :r]
            model.coeffs[c, :, :r] = dec.coeffs[c, :, :r]
        return model

    def decode(self) -> TabulatedBTF:
        """The reconstructed BTF (L, V, H, W, 3), linear RGB."""
        c = self.cfg
        chans = [(self.coeffs[i] @ self.basis[i].T + self.mean[i]).T for i in range(3)]   # (LV, HW)
        yuv = torch.stack(chans, -1).reshape(c.n_light, c.n_view, c.height, c.width, 3)
        return TabulatedBTF(model_space_to_rgb(yuv, c.log_eps), self.light_dirs, self.view_dirs, c.neighbours,
                            label="pca-btf")

    def eval(self, q: Query) -> torch.Tensor:
        q.require("uv", who="PCABTF")
        c = self.cfg
        dev = self.basis.device
        wi, wo, uv = (t.to(dev, torch.float32) for t in (q.wi, q.wo, q.uv))
        li, lw = angular_weights(self.light_dirs, wi, c.neighbours)
        vi, vw = angular_weights(self.view_dirs, wo, c.neighbours)
        rows, cols, sw = bilinear_taps(uv, c.height, c.width)
        texel = (rows * c.width + cols)[:, :, None, None]                        # (N, 4, 1, 1)
        ang = (li[:, None, :, None] * c.n_view + vi[:, None, None, :])            # (N, 1, kl, kv)
        yuv = torch.stack([(self.coeffs[i][texel] * self.basis[i][ang]).sum(-1) + self.mean[i][ang]
                           for i in range(3)], -1)                                # (N, 4, kl, kv, 3)
        rgb = model_space_to_rgb(yuv, c.log_eps)
        wts = sw[:, :, None, None] * lw[:, None, :, None] * vw[:, None, None, :]
        f = (rgb * wts[..., None]).sum((1, 2, 3))
        f = torch.where(upper_hemisphere(wi, wo).unsqueeze(-1), f, torch.zeros_like(f))
        return f.to(q.wi.device, q.wi.dtype)

    def storage(self, value_bytes: int = 2) -> dict:
        """Bytes: per channel mean (L V), basis (L V x r) and coefficients (H W x r)."""
        c = self.cfg
        lv, hw = c.n_light * c.n_view, c.height * c.width
        d = {"mean": 3 * lv * value_bytes, "basis": sum(c.ranks) * lv * value_bytes,
             "coefficients": sum(c.ranks) * hw * value_bytes}
        d["total"] = d["mean"] + d["basis"] + d["coefficients"]
        d["compression_ratio"] = lv * hw * 3 * 2 / d["total"]
        return d

    def size_bytes(self, precision: str = "fp16") -> int:
        value_bytes = {"fp16": 2, "fp32": 4, "bf16": 2, "int8": 1}.get(precision)
        if value_bytes is None:
            raise InputError(f"PCABTF.size_bytes precision: expected fp16, fp32, bf16 or int8, got {precision!r}")
        return int(self.storage(value_bytes)["total"])

    def flops(self) -> int:
        k = self.cfg.neighbours
        return int(4 * k * k * 3 * (2 * max(self.cfg.ranks) + 10))

    def describe(self) -> str:
        c = self.cfg
        return f"pca-btf ({c.height}x{c.width} texels, {c.n_light}x{c.n_view} directions, ranks {tuple(c.ranks)})"


def rank_budget(budget: int, n_light: int, n_view: int, height: int, width: int, value_bytes: int = 2) -> int:
    """The most principal components, over the three channels together, whose storage (means, bases,
    per-texel coefficients) fits in `budget` bytes."""
    lv, hw = n_light * n_view, height * width
    free = budget - 3 * lv * value_bytes
    if free < 0:
        raise InputError(f"rank_budget: a budget of {budget} bytes does not even hold the PCA means")
    return free // ((lv + hw) * value_bytes)


@dataclass
class Decomposition:
    """Principal components of a BTF's Y, U, V channels in the model space (log(x + eps), YUV), largest first.

    mean (3, LV) over texels; eigenvalues: per channel (R_c,), the squared error each component removes;
    basis (3, LV, R) orthonormal columns; coeffs (3, HW, R) = centred data @ basis; exact: False when
    computed by randomised subspace iteration (then only the leading R components are kept)."""

    mean: torch.Tensor
    eigenvalues: list[torch.Tensor]
    basis: torch.Tensor
    coeffs: torch.Tensor
    log_eps: float
    exact: bool


def decompose(btf: TabulatedBTF, log_eps: float = 0.01, max_rank: int | None = None, exact_limit: int = 4096,
              oversample: int = 16, power_iterations: int = 6) -> Decomposition:
    """Principal components of `btf` (all of them, or the leading `max_rank`). Exact (eigendecomposition of
    the smaller Gram matrix, float64) unless both sides of the texel x angle matrix exceed `exact_limit` and
    `max_rank` is given: then randomised subspace iteration (`torch.svd_lowrank`, max_rank + `oversample`
    vectors, `power_iterations` passes, float64), whose leading eigenvalues match the exact ones within
    1e-4 relative (test)."""
    l, v, h, w, _ = btf.data.shape
    lv, hw = l * v, h * w
    if max_rank is not None and max_rank < 0:
        raise InputError(f"decompose: expected a non-negative max_rank, got {max_rank!r}")
    r_max = min(lv, hw) if max_rank is None else min(max_rank, lv, hw)
    exact = max_rank is None or min(lv, hw) <= exact_limit or r_max + oversample >= min(lv, hw)
    yuv = rgb_to_model_space(btf.data.float(), log_eps)                            # (L, V, H, W, 3)
    mean = torch.zeros(3, lv, device=btf.data.device)
    basis = torch.zeros(3, lv, max(r_max, 1), device=btf.data.device)
    coeffs = torch.zeros(3, hw, max(r_max, 1), device=btf.data.device)
    eigenvalues = []
    for c in range(3):
        x = yuv[..., c].reshape(lv, hw).T.double()                                  # texels x angles
        mu = x.mean(0)
        xc = x - mu
        mean[c] = mu.float()
        if exact:
            if lv <= hw:
                e, vecs = torch.linalg.eigh(xc.T @ xc)
                e, b = e.flip(0).clamp_min(0)[:r_max], vecs.flip(-1)[:, :r_max]
            else:                                 # texel Gram: basis = xc^T u / sqrt(e), for the kept components only
                e, u = torch.linalg.eigh(xc @ xc.T)
                e, u = e.flip(0).clamp_min(0)[:r_max], u.flip(-1)[:, :r_max]
                live = e > e[0] * 1e-12 if len(e) and e[0] > 0 else torch.zeros_like(e, dtype=torch.bool)
                b = torch.zeros(lv, len(e), dtype=xc.dtype, device=xc.device)
                b[:, live] = (xc.T @ u[:, live]) / e[live].sqrt()
        else:
            with torch.random.fork_rng(devices=[xc.device] if xc.is_cuda else []):
                torch.manual_seed(0)                      # the random test matrix: same components every run
                _, sv, b = torch.svd_lowrank(xc, q=r_max + oversample, niter=power_iterations)
            e, b = sv[:r_max] ** 2, b[:, :r_max]
        eigenvalues.append(e.float())
        basis[c, :, :b.shape[1]] = b.float()
        coeffs[c, :, :b.shape[1]] = (xc @ b).float()
    return Decomposition(mean, eigenvalues, basis, coeffs, log_eps, exact)


def best_ranks(spectra: list[torch.Tensor], total: int) -> tuple[int, int, int]:
    """The split of `total` principal components over Y, U, V with the least squared error, given the
    channels' eigenvalues (`Decomposition.eigenvalues`): the `total` largest eigenvalues of the three,
    counted per channel (every component costs the same, and each channel's eigenvalues fall)."""
    if total < 0:
        raise InputError(f"best_ranks: expected a non-negative component count, got {total!r}")
    channel = torch.cat([torch.full((len(e),), c) for c, e in enumerate(spectra)])
    order = torch.cat(spectra).argsort(descending=True, stable=True)[:total]
    return tuple(int((channel[order] == c).sum()) for c in range(3))
