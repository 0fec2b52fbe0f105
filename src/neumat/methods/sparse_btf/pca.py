"""PCA baseline for BTFs (the paper's Table 5): per BTF and YUV channel, a truncated PCA of the matrix whose
rows are texels and whose columns are the L x V angular samples, in the same model space as SparseBTF
(log(x + eps), RGB -> YUV). Stored: per channel a mean over texels (L V), r basis vectors (L V x r) and
r coefficients per texel (H W x r), all float16. The solve is training code (methods/sparse_btf/pca_solve.py:
`decompose` computes the principal components once per BTF, exactly from the smaller Gram matrix, or by
randomised subspace iteration when both sides are large, as for 151 x 151 directions and 100 x 100 texels;
`best_ranks` (of the decomposition's eigenvalues) gives the least-error split over Y, U, V of a component
count); `rank_budget` gives the component count of a storage budget, so PCA can be compared with SparseBTF at
equal storage. Lookup: the same wrap-around bilinear and k-nearest angular
interpolation as `TabulatedBTF`, in linear RGB.
"""
from __future__ import annotations

import numbers
from dataclasses import dataclass, replace

import torch
from torch import nn

from neumat.core.config import resolve_config
from neumat.core.errors import DataFormatError, InputError
from neumat.core.material import zero_below_horizon
from neumat.core.query import Query
from neumat.models.base import LearnedMaterial
from neumat.methods.sparse_btf.btf_size import btf_table_size, check_btf_table_size
from neumat.methods.sparse_btf.dictionary import YUV_TO_RGB, model_space_to_rgb
from neumat.nn import cpu_kernels
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
    ranks: tuple[int, ...] = ()
    """Principal components kept for Y, U, V; empty: chosen when solved, the most that fit the recipe's storage
    budget (by default SparseBTF's per-BTF bytes: the paper's comparison at equal storage), split by least error
    (`neumat.methods.sparse_btf.pca_solve.budget_components`)."""
    log_eps: float = 0.01
    """eps of the log transform."""
    neighbours: int = 3
    """k nearest direction bins of the angular interpolation."""


class PCABTF(LearnedMaterial):
    """Truncated PCA of a BTF (module docstring). Build with `fit_pca(btf, ranks)` (methods/sparse_btf/pca_solve.py) or
    `fit(PCABTF.for_btf(btf, ranks=...), btf)`."""

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
        _check_ranks(cfg.ranks, allow_empty=True)
        self.cfg = cfg
        lv = cfg.n_light * cfg.n_view
        self.register_buffer("light_dirs", torch.zeros(cfg.n_light, 3))
        self.register_buffer("view_dirs", torch.zeros(cfg.n_view, 3))
        self.register_buffer("mean", torch.zeros(3, lv))
        self._size_components()
        self._runtime = False
        self.register_state_dict_post_hook(stored_components)
        self.register_load_state_dict_pre_hook(unpack_components)

    @classmethod
    def for_btf(cls, btf: TabulatedBTF, **fields) -> "PCABTF":
        """A model sized for `btf` (direction counts, texels), other Config fields from `fields`: what
        the trainer's `fit(model, btf)` solves (recipe methods/sparse_btf/pca_train.py)."""
        return cls(Config(**{**fields, **btf_table_size(btf, "pca-btf")}))

    def check_source(self, btf: TabulatedBTF) -> None:
        """Raise InputError unless `btf` is a tabulated BTF of this model's size."""
        check_btf_table_size(btf, self.cfg, "pca-btf", "PCABTF.for_btf")

    def set_ranks(self, ranks: tuple[int, int, int]) -> "PCABTF":
        """Keep `ranks` components for Y, U, V from now on (a model built without ranks gets them when solved);
        the components are zeroed until `load_components`. Returns self."""
        _check_ranks(ranks, allow_empty=False)
        self.cfg = replace(self.cfg, ranks=tuple(int(r) for r in ranks))
        self._size_components()
        return self

    def _size_components(self) -> None:
        c, dev = self.cfg, self.mean.device
        r = max(max(c.ranks, default=0), 1)
        self.register_buffer("basis", torch.zeros(3, c.n_light * c.n_view, r, device=dev))
        self.register_buffer("coeffs", torch.zeros(3, c.height * c.width, r, device=dev))

    @torch.no_grad()
    def load_components(self, decomposition, light_dirs: torch.Tensor, view_dirs: torch.Tensor) -> "PCABTF":
        """Keep the leading cfg.ranks components of `decomposition` (a `Decomposition` of
        methods/sparse_btf/pca_solve.py, of a BTF of this size and log eps: mean (3, LV), eigenvalues, basis (3, LV, R),
        coeffs (3, HW, R)); returns self."""
        c = self.cfg
        if not c.ranks:
            raise InputError("PCABTF.load_components: the model has no ranks yet; choose them first (set_ranks, "
                             "or fit it through its recipe, which picks them from a storage budget)")
        dec = decomposition
        lv, hw = c.n_light * c.n_view, c.height * c.width
        if dec.mean.shape[1] != lv or dec.coeffs.shape[1] != hw or dec.log_eps != c.log_eps:
            raise InputError(f"PCABTF: the decomposition is of another BTF ({dec.mean.shape[1]} angular samples, "
                             f"{dec.coeffs.shape[1]} texels, log_eps {dec.log_eps}) than this one ({lv}, {hw}, "
                             f"{c.log_eps})")
        if any(r > len(e) and len(e) < min(lv, hw) for r, e in zip(c.ranks, dec.eigenvalues)):
            raise InputError(f"PCABTF: ranks {tuple(c.ranks)} exceed the {[len(e) for e in dec.eigenvalues]} "
                             "components the decomposition kept")
        self.light_dirs.copy_(light_dirs)
        self.view_dirs.copy_(view_dirs)
        self.mean.copy_(dec.mean)
        for i in range(3):
            r = min(c.ranks[i], len(dec.eigenvalues[i]))
            self.basis[i, :, :r] = dec.basis[i, :, :r]
            self.coeffs[i, :, :r] = dec.coeffs[i, :, :r]
        return self

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
        if 1 <= c.neighbours <= 8 and cpu_kernels.usable(q.wi, q.wo, q.uv, self.basis):
            return cpu_kernels.pca_btf_eval(self, q.wi, q.wo, q.uv, YUV_TO_RGB)  # the same within float32 rounding
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
        f = zero_below_horizon(f, wi, wo)
        return f.to(q.wi.device, q.wi.dtype)

    @property
    def is_runtime(self) -> bool:
        """Whether `runtime()` is in effect (model files record it and re-enter it on load)."""
        return self._runtime

    @torch.no_grad()
    def runtime(self) -> "PCABTF":
        """Round mean, basis and coefficients to fp16, as `storage` counts them; the model file then stores them
        as fp16 (`stored_components`). Returns self."""
        for t in (self.mean, self.basis, self.coeffs):
            t.copy_(t.half())
        self._runtime = True
        return self

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
        return int(4 * k * k * 3 * (2 * max(self.cfg.ranks, default=0) + 10))

    def describe(self) -> str:
        c = self.cfg
        return f"pca-btf ({c.height}x{c.width} texels, {c.n_light}x{c.n_view} directions, ranks {tuple(c.ranks)})"


def stored_components(module: PCABTF, state_dict: dict, prefix: str, local_metadata) -> None:
    """State-dict hook: basis and coefficients as `storage` counts them, each channel's first ranks[c] columns
    side by side ("basis" (L V, sum ranks), "coeffs" (H W, sum ranks)) instead of padded to the largest rank,
    and "ranks" (3,) when the model has them, so a model built without ranks (chosen when solved) can load a
    solved state, e.g. a fit's checkpoint; fp16 with the mean in runtime mode. `unpack_components` inverts it (the
    padding is zero)."""
    ranks = module.cfg.ranks or (0, 0, 0)                    # no ranks yet (an unsolved model): no columns
    for name in ("basis", "coeffs"):
        t = state_dict[prefix + name]
        state_dict[prefix + name] = torch.cat([t[c, :, :r] for c, r in enumerate(ranks)], -1)
    if module.cfg.ranks:
        state_dict[prefix + "ranks"] = torch.tensor(module.cfg.ranks, dtype=torch.int32)
    if module.is_runtime:
        for name in ("mean", "basis", "coeffs"):
            state_dict[prefix + name] = state_dict[prefix + name].half()


def unpack_components(module: PCABTF, state_dict: dict, prefix: str, local_metadata, strict, missing_keys,
                      unexpected_keys, error_msgs) -> None:
    """Load-state-dict pre-hook inverting `stored_components`: a model without ranks takes the stored ones
    (DataFormatError when they differ from the model's, or a stored matrix does not have their sum of columns)."""
    stored = state_dict.pop(prefix + "ranks", None)
    if stored is not None:
        stored = tuple(int(r) for r in stored.reshape(-1).tolist())
        if not module.cfg.ranks and len(stored) == 3 and min(stored) >= 0:
            module.set_ranks(stored)
        elif stored != tuple(module.cfg.ranks):
            raise DataFormatError(f"pca-btf: the stored state has ranks {stored}, the model {tuple(module.cfg.ranks)}")
    ranks = module.cfg.ranks
    for name in ("basis", "coeffs"):
        key = prefix + name
        if key not in state_dict or state_dict[key].ndim != 2:
            continue
        t, full = state_dict[key], getattr(module, name)
        if t.shape != (full.shape[1], sum(ranks)):
            raise DataFormatError(f"pca-btf {name}: expected ({full.shape[1]}, {sum(ranks)}) (rows, sum of the ranks "
                                  f"{tuple(ranks)}), got {tuple(t.shape)}")
        padded = torch.zeros(full.shape, dtype=torch.float32)
        start = 0
        for c, r in enumerate(ranks):
            padded[c, :, :r] = t[:, start:start + r].float()
            start += r
        state_dict[key] = padded
    if prefix + "mean" in state_dict:
        state_dict[prefix + "mean"] = state_dict[prefix + "mean"].float()


def _check_ranks(ranks, allow_empty: bool) -> None:
    if (len(ranks) != 3 and not (allow_empty and len(ranks) == 0)) or any(
            not isinstance(r, numbers.Integral) or isinstance(r, bool) or r < 0 for r in ranks):
        also = " (or none: chosen when solved)" if allow_empty else ""
        raise InputError(f"PCABTF.ranks: expected three non-negative integers{also}, got {tuple(ranks)!r}")


def rank_budget(budget: int, n_light: int, n_view: int, height: int, width: int, value_bytes: int = 2) -> int:
    """The most principal components, over the three channels together, whose storage (means, bases,
    per-texel coefficients) fits in `budget` bytes."""
    lv, hw = n_light * n_view, height * width
    free = budget - 3 * lv * value_bytes
    if free < 0:
        raise InputError(f"rank_budget: a budget of {budget} bytes does not even hold the PCA means")
    return free // ((lv + hw) * value_bytes)
