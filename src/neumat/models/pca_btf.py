"""PCA baseline for BTFs (the paper's Table 5): per BTF and YUV channel, a truncated PCA of the matrix whose
rows are texels and whose columns are the L x V angular samples, in the same model space as SparseBTF
(log(x + eps), RGB -> YUV). Stored: per channel a mean over texels (L V), r basis vectors (L V x r) and
r coefficients per texel (H W x r), all float16. `rank_budget` gives the component count of a storage
budget and `best_ranks` (of `channel_spectra`) its least-error split over Y, U, V, so PCA can be compared with SparseBTF at equal
storage. Lookup: the same wrap-around bilinear and k-nearest angular interpolation as `TabulatedBTF`, in
linear RGB.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from neumat.core.config import resolve_config
from neumat.core.errors import InputError
from neumat.core.material import Material, upper_hemisphere
from neumat.core.query import Query
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
class PCABTF(nn.Module, Material):
    """Truncated PCA of a BTF (module docstring). Build with `PCABTF.fit(btf, ranks)`."""

    name = "pca-btf"
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
            neighbours: int = 3) -> "PCABTF":
        """Truncated PCA of `btf` with `ranks` components for Y, U, V."""
        l, v, h, w, _ = btf.data.shape
        cfg = Config(n_light=l, n_view=v, height=h, width=w, ranks=tuple(int(r) for r in ranks), log_eps=log_eps,
                     neighbours=neighbours)
        model = cls(cfg).to(btf.data.device)
        model.light_dirs.copy_(btf.light_dirs)
        model.view_dirs.copy_(btf.view_dirs)
        yuv = rgb_to_model_space(btf.data.float(), log_eps)                       # (L, V, H, W, 3)
        for c in range(3):
            x = yuv[..., c].reshape(l * v, h * w).T.double()                       # texels x angles
            mean = x.mean(0)
            xc = x - mean
            r = min(cfg.ranks[c], min(xc.shape))
            model.mean[c] = mean.float()
            if r > 0:
                _, vecs = torch.linalg.eigh(xc.T @ xc)
                basis = vecs[:, -r:].flip(-1)                                       # (LV, r)
                model.basis[c, :, :r] = basis.float()
                model.coeffs[c, :, :r] = (xc @ basis).float()
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


def channel_spectra(btf: TabulatedBTF, log_eps: float = 0.01) -> list[torch.Tensor]:
    """Eigenvalues, largest first, of the Y, U and V channels' centred texel x angle matrices in the model
    space (log(x + eps), YUV): the squared error each principal component removes."""
    l, v, h, w, _ = btf.data.shape
    yuv = rgb_to_model_space(btf.data.float(), log_eps)
    spectra = []
    for c in range(3):
        x = yuv[..., c].reshape(l * v, h * w).double()
        x = x - x.mean(1, keepdim=True)                                              # centred over texels
        gram = x @ x.T if l * v <= h * w else x.T @ x
        spectra.append(torch.linalg.eigvalsh(gram).flip(0).clamp_min(0))
    return spectra


def best_ranks(spectra: list[torch.Tensor], total: int) -> tuple[int, int, int]:
    """The split of `total` principal components over Y, U, V with the least squared error, given the
    channels' `channel_spectra`: the `total` largest eigenvalues of the three, counted per channel (every
    component costs the same, and each channel's eigenvalues fall)."""
    if total < 0:
        raise InputError(f"best_ranks: expected a non-negative component count, got {total!r}")
    channel = torch.cat([torch.full((len(e),), c) for c, e in enumerate(spectra)])
    order = torch.cat(spectra).argsort(descending=True, stable=True)[:total]
    return tuple(int((channel[order] == c).sum()) for c in range(3))
