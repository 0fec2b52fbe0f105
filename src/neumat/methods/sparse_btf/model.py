"""SparseBTF (Kavoosi et al., EGSR 2023): a BTF stored as sparse coefficients of a dictionary ensemble that
was trained once (`neumat.methods.sparse_btf.dictionary`; its training is in the fit package,
methods/sparse_btf/dictionary_train.py), evaluated as a spatially varying `Material`.

Stored per BTF (Sec. 3.3-3.4), per YUV channel c: for every p x p patch (data point) its dictionary index
(membership), its number of non-zero coefficients (count), and that many values with their 4D index tuples
(l1, l2, l3, l4) into the coefficient tensor; plus the per-image mean and std of the standardisation.
The shared ensemble is kept as buffers (`dict_n`, (3, K, m_n, m_n)).

Details: src/neumat/methods/sparse_btf/NOTES.md, section `neumat.methods.sparse_btf.model`.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import NamedTuple

import torch
from torch import nn

from neumat.core.checks import check_int
from neumat.core.config import resolve_config
from neumat.core.errors import DataFormatError, InputError
from neumat.core.tensors import rows_per_slice
from neumat.core.material import zero_below_horizon
from neumat.core.query import Query
from neumat.models.base import LearnedMaterial
from neumat.nn import cpu_kernels
from neumat.methods.sparse_btf.btf_size import btf_table_size, check_btf_table_size
from neumat.methods.sparse_btf.dictionary import (
    STATISTICS,
    YUV_TO_RGB,
    BTFDictionary,
    Codes,
    Ensemble,
    check_patch_grid,
    code_points_at_rates,
    decode_points,
    dense_coefficients,
    from_data_points,
    keep_largest,
    mode_product,
    model_space_to_rgb,
    prepare_btf,
    unravel,
)
from neumat.reflectance.btf import TabulatedBTF, angular_weights, bilinear_taps

CHANNELS = "YUV"


@dataclass
class Config:
    """SparseBTF sizes; defaults are the paper's UBO2014 setting (Sec. 4)."""

    patch: int = 10
    """p: spatial patch size of a data point (p x p texels)."""
    num_dictionaries: int = 8
    """K: dictionaries per ensemble (one ensemble per YUV channel)."""
    n_light: int = 151
    """m3: light directions of the BTF."""
    n_view: int = 151
    """m4: view directions of the BTF."""
    height: int = 400
    """H texels (a multiple of patch)."""
    width: int = 400
    """W texels (a multiple of patch)."""
    tau: tuple[int, int, int] = (256, 32, 32)
    """tau_t: maximum non-zero coefficients per data point for Y, U, V (the testing sparsity)."""
    tau_train: tuple[int, int, int] = (256, 32, 32)
    """tau_l of the dictionary (Y, U, V); coding requires tau >= tau_train."""
    log_eps: float = 0.01
    """eps of the log transform log(x + eps)."""
    error_threshold: float = 0.0
    """Coding stops adding coefficients once the mean squared error per element (model space) is below this."""
    neighbours: int = 3
    """k nearest direction bins of the angular interpolation (light and view separately)."""
    angular: str = "coefficient"
    """Angular interpolation in "coefficient" space (Eq. 6) or in "value" space (linear RGB)."""
    statistics: str = "image"
    """Standardisation statistics per angular "image" and channel (the paper: 2 L V 3 stored numbers) or per
    "btf" and channel (6 numbers; docs/btf.md, "Statistics overhead")."""


def _check_config(c: Config) -> None:
    for name in ("patch", "num_dictionaries", "n_light", "n_view", "height", "width", "neighbours"):
        check_int(getattr(c, name), f"SparseBTF.{name}")
    check_patch_grid(c.height, c.width, c.patch)
    for name in ("tau", "tau_train"):
        v = getattr(c, name)
        if len(v) != 3 or any(t < 1 for t in v):
            raise InputError(f"SparseBTF.{name}: expected three positive integers (Y, U, V), got {v!r}")
    low = [ch for ch, t, tl in zip(CHANNELS, c.tau, c.tau_train) if t < tl]
    if low:
        raise InputError(f"SparseBTF.tau {tuple(c.tau)} is smaller than the training sparsity tau_train "
                         f"{tuple(c.tau_train)} for channel(s) {', '.join(low)}; the paper requires tau_t >= tau_l")
    if c.statistics not in STATISTICS:
        raise InputError(f"SparseBTF.statistics: expected one of {STATISTICS}, got {c.statistics!r}")
    if c.angular not in ("coefficient", "value"):
        raise InputError(f"SparseBTF.angular: expected 'coefficient' or 'value', got {c.angular!r}")
    if not c.log_eps > 0 or c.error_threshold < 0:
        raise InputError("SparseBTF: log_eps must be > 0 and error_threshold >= 0")


class SparseBTF(LearnedMaterial):
    """A BTF in SparseBTF form (see module docstring). Build with `SparseBTF.encode(btf, dictionary, tau)`, or
    train dictionary and codes through the trainer: `fit(SparseBTF.for_btf(btf, ...), btf)` (recipe
    methods/sparse_btf/train.py)."""

    name = "sparse-btf"
    paper = "SparseBTF (Kavoosi et al.): sparse coding of BTFs in a dictionary ensemble"
    source_kinds = ("btf",)
    can_sample = False
    spatially_varying = True
    Config = Config

    def __init__(self, config: Config | None = None, **kwargs) -> None:
        nn.Module.__init__(self)
        cfg = resolve_config(Config, config, kwargs, 'SparseBTF')
        _check_config(cfg)
        self.cfg = cfg
        p, k, l, v = cfg.patch, cfg.num_dictionaries, cfg.n_light, cfg.n_view
        n_patches = (cfg.height // p) * (cfg.width // p)
        t = max(cfg.tau)
        for n, m in enumerate((p, p, l, v), start=1):
            self.register_buffer(f"dict_{n}", torch.eye(m).expand(3, k, m, m).clone())
        self.register_buffer("light_dirs", torch.zeros(l, 3))
        self.register_buffer("view_dirs", torch.zeros(v, 3))
        self.register_buffer("mean", torch.zeros(l, v, 3))
        self.register_buffer("std", torch.ones(l, v, 3))
        self.register_buffer("membership", torch.zeros(3, n_patches, dtype=torch.int32))
        self.register_buffer("counts", torch.zeros(3, n_patches, dtype=torch.int32))
        self.register_buffer("values", torch.zeros(3, n_patches, t))
        self.register_buffer("index", torch.zeros(3, n_patches, t, 4, dtype=torch.int32))
        self._runtime = False
        self.register_state_dict_post_hook(stored_codes)
        self.register_load_state_dict_pre_hook(unpack_codes)

    # ------------------------------------------------------------------------------------ building
    @classmethod
    def encode(cls, btf: TabulatedBTF, dictionary: BTFDictionary, tau: int | tuple[int, int, int] | None = None,
               error_threshold: float = 0.0, neighbours: int = 3, angular: str = "coefficient",
               statistics: str = "image") -> "SparseBTF":
        """Sparse representation of `btf` with a trained `dictionary` (Sec. 3.3). tau: tau_t for Y, U, V (one
        int for all); default the dictionary's tau_train. statistics: Config.statistics."""
        return cls.encode_rates(btf, dictionary, [tau], error_threshold, neighbours, angular, statistics)[0]

    @classmethod
    def encode_rates(cls, btf: TabulatedBTF, dictionary: BTFDictionary,
                     taus: list[int | tuple[int, int, int] | None], error_threshold: float = 0.0,
                     neighbours: int = 3, angular: str = "coefficient", statistics: str = "image"
                     ) -> list["SparseBTF"]:
        """`encode` at every tau of `taus` (same results), projecting the BTF's data points on the dictionaries
        once for all of them."""
        if not taus:
            raise InputError("SparseBTF.encode_rates: no tau given")
        taus = [dictionary.tau_train if t is None else (t,) * 3 if isinstance(t, int) else tuple(t) for t in taus]
        l, v, h, w, _ = btf.data.shape
        cfgs = [Config(patch=dictionary.patch, num_dictionaries=dictionary.num_dictionaries, n_light=l, n_view=v,
                       height=h, width=w, tau=tuple(int(t) for t in tau), tau_train=tuple(dictionary.tau_train),
                       log_eps=dictionary.log_eps, error_threshold=error_threshold, neighbours=neighbours,
                       angular=angular, statistics=statistics) for tau in taus]
        for cfg in cfgs:
            _check_config(cfg)
        dictionary.check_compatible(btf.light_dirs, btf.view_dirs, f"BTF {btf.label!r}")
        models = [cls(cfg).to(btf.data.device) for cfg in cfgs]
        points, mean, std = prepare_btf(btf.data, dictionary.patch, dictionary.log_eps, statistics)
        for model in models:
            model.light_dirs.copy_(btf.light_dirs)
            model.view_dirs.copy_(btf.view_dirs)
            model.mean.copy_(mean)
            model.std.copy_(std)
        for c, ens in enumerate(dictionary.ensembles):
            ens = ens.to(btf.data.device)
            codes = code_points_at_rates(points[c], ens, [cfg.tau[c] for cfg in cfgs], error_threshold)
            for model, code in zip(models, codes):
                for n in range(4):
                    getattr(model, f"dict_{n + 1}")[c] = ens.mats[n]
                model._store_codes(c, code)
        return models

    @classmethod
    def for_btf(cls, btf: TabulatedBTF, **fields) -> "SparseBTF":
        """An (uncoded) model sized for `btf` (direction counts, texels); other Config fields from `fields`.
        What the trainer's `fit(model, btf)` trains (recipe methods/sparse_btf/train.py)."""
        return cls(Config(**{**fields, **btf_table_size(btf, "sparse-btf")}))

    def check_source(self, btf: TabulatedBTF) -> None:
        """Raise InputError unless `btf` is a tabulated BTF of this model's size."""
        check_btf_table_size(btf, self.cfg, "sparse-btf", "SparseBTF.for_btf")

    @torch.no_grad()
    def code(self, btf: TabulatedBTF) -> torch.Tensor:
        """Sparse codes of `btf` in this model's own dictionary ensemble (`dict_n` buffers), as `encode`:
        project every data point on every dictionary and keep the cfg.tau largest coefficients (Sec. 3.3).
        Sets the directions, statistics and codes; returns the mean squared error per element (model space)."""
        self.check_source(btf)
        c, dev = self.cfg, self.values.device
        points, mean, std = prepare_btf(btf.data.to(dev), c.patch, c.log_eps, c.statistics)
        self.light_dirs.copy_(btf.light_dirs)
        self.view_dirs.copy_(btf.view_dirs)
        self.mean.copy_(mean)
        self.std.copy_(std)
        errors = []
        for ch in range(3):
            codes = code_points_at_rates(points[ch], self.ensemble(ch), [c.tau[ch]], c.error_threshold)[0]
            self._store_codes(ch, codes)
            errors.append(codes.error.mean())
        return torch.stack(errors).mean()

    def _store_codes(self, c: int, codes: Codes) -> None:
        t = codes.values.shape[1]
        self.membership[c] = codes.membership.to(torch.int32)
        self.counts[c] = codes.counts.to(torch.int32)
        self.values[c].zero_()
        self.index[c].zero_()
        self.values[c, :, :t] = codes.values
        self.index[c, :, :t] = codes.index.to(torch.int32)

    def codes(self, c: int) -> Codes:
        """The sparse codes of channel c (error unknown: zeros)."""
        return Codes(self.membership[c].long(), self.values[c], self.index[c].long(), self.counts[c].long(),
                     torch.zeros_like(self.values[c, :, 0]))

    def ensemble(self, c: int) -> Ensemble:
        return Ensemble([getattr(self, f"dict_{n}")[c] for n in range(1, 5)])

    @property
    def point_shape(self) -> tuple[int, int, int, int]:
        c = self.cfg
        return (c.patch, c.patch, c.n_light, c.n_view)

    # ------------------------------------------------------------------------------------ reconstruction
    def decode_points(self) -> torch.Tensor:
        """Reconstructed standardised data points (3, P, p, p, L, V) (Eq. 4)."""
        return torch.stack([decode_points(self.codes(c), self.ensemble(c)) for c in range(3)])

    def decode(self) -> TabulatedBTF:
        """The full reconstructed BTF (L, V, H, W, 3), linear RGB."""
        z = from_data_points(self.decode_points(), self.cfg.height, self.cfg.width)
        yuv = z * self.std[:, :, None, None, :] + self.mean[:, :, None, None, :]
        return TabulatedBTF(model_space_to_rgb(yuv, self.cfg.log_eps), self.light_dirs, self.view_dirs,
                            self.cfg.neighbours, label="sparse-btf")

    def _gather(self, c: int, patch: torch.Tensor):
        """Membership (...), values (..., T) and index tuples (..., T, 4) of the data points `patch`."""
        return self.membership[c][patch].long(), self.values[c][patch], self.index[c][patch].long()

    def element(self, c: int, patch: torch.Tensor, x1: torch.Tensor, x2: torch.Tensor, x3: torch.Tensor,
                x4: torch.Tensor) -> torch.Tensor:
        """Eq. 5: standardised value (...) of channel c at (x1, x2, x3, x4) of data points `patch` (all (...))."""
        memb, vals, idx = self._gather(c, patch)
        u1 = self.dict_1[c][memb[..., None], x1[..., None], idx[..., 0]]
        u2 = self.dict_2[c][memb[..., None], x2[..., None], idx[..., 1]]
        u3 = self.dict_3[c][memb[..., None], x3[..., None], idx[..., 2]]
        u4 = self.dict_4[c][memb[..., None], x4[..., None], idx[..., 3]]
        return (vals * u1 * u2 * u3 * u4).sum(-1)

    def element_interpolated(self, c: int, patch: torch.Tensor, x1: torch.Tensor, x2: torch.Tensor,
                             light_idx: torch.Tensor, light_w: torch.Tensor, view_idx: torch.Tensor,
                             view_w: torch.Tensor) -> torch.Tensor:
        """Eq. 6: sum_{a,b} light_w[a] view_w[b] * element(.., light_idx[a], view_idx[b]) computed in
        coefficient space. patch, x1, x2: (...); light_idx, light_w: (..., kl); view_idx, view_w: (..., kv)."""
        memb, vals, idx = self._gather(c, patch)
        u1 = self.dict_1[c][memb[..., None], x1[..., None], idx[..., 0]]
        u2 = self.dict_2[c][memb[..., None], x2[..., None], idx[..., 1]]
        m3 = self.dict_3[c][memb[..., None, None], light_idx[..., :, None], idx[..., None, :, 2]]
        m4 = self.dict_4[c][memb[..., None, None], view_idx[..., :, None], idx[..., None, :, 3]]
        u3 = (light_w[..., None] * m3).sum(-2)
        u4 = (view_w[..., None] * m4).sum(-2)
        return (vals * u1 * u2 * u3 * u4).sum(-1)

    def _texel_sum_interpolated(self, c: int, pairs: TapPairs, x1: torch.Tensor, x2: torch.Tensor,
                                tap_w: torch.Tensor, light_idx: torch.Tensor, light_w: torch.Tensor,
                                view_idx: torch.Tensor, view_w: torch.Tensor) -> torch.Tensor:
        """sum_t tap_w[t] * element_interpolated(c, patch[:, t], x1[:, t], x2[:, t], ...) for the 4 bilinear taps
        of N queries (`pairs` = _pairs_of_taps(patch)): x1, x2, tap_w (N, 4); light_idx, light_w (N, kl);
        view_idx, view_w (N, kv) -> (N,).

        The taps of a query that lie in one data point share its coefficients, so they are merged into one
        (query, data point) pair with the spatial factor S = sum_t tap_w[t] U1[x1_t, :] (x) U2[x2_t, :] (p x p);
        the weighted U3 / U4 rows are formed once per pair. Each coefficient then costs three gathers.
        """
        n, p = x1.shape[0], self.cfg.patch
        memb = self.membership[c][pairs.patch].long()                                # (M,)
        memb_tap = memb[pairs.pair_of_tap]                                           # (N, 4)
        r1 = self.dict_1[c][memb_tap, x1] * tap_w[..., None]                         # (N, 4, p)
        r2 = self.dict_2[c][memb_tap, x2]
        outer = (r1[..., :, None] * r2[..., None, :]).reshape(n * 4, p * p)
        s = outer.new_zeros(len(memb), p * p).index_add_(0, pairs.pair_of_tap.reshape(-1), outer)
        q = pairs.query
        r3 = (self.dict_3[c][memb[:, None], light_idx[q]] * light_w[q, :, None]).sum(1)  # (M, L)
        r4 = (self.dict_4[c][memb[:, None], view_idx[q]] * view_w[q, :, None]).sum(1)    # (M, V)
        vals, idx = self.values[c][pairs.patch], self.index[c][pairs.patch].long()   # (M, T), (M, T, 4)
        z = vals * s.gather(1, idx[..., 0] * p + idx[..., 1]) * r3.gather(1, idx[..., 2]) * r4.gather(1, idx[..., 3])
        return z.new_zeros(n).index_add_(0, q, z.sum(-1))

    def _texel_bins(self, c: int, pairs: TapPairs, x1: torch.Tensor, x2: torch.Tensor,
                    light_idx: torch.Tensor, view_idx: torch.Tensor) -> torch.Tensor:
        """Eq. 5 values (N, 4, kl, kv) of channel c at the 4 bilinear taps of N queries (`pairs` =
        _pairs_of_taps(patch); x1, x2: (N, 4)) and every pair of their light / view bins (light_idx (N, kl),
        view_idx (N, kv)). The U3 / U4 entries of a data point's coefficients are gathered once per (query, data
        point) pair and shared by its taps; the kl x kv bin sums of each tap are one batched matrix product."""
        n, kl, kv = x1.shape[0], light_idx.shape[1], view_idx.shape[1]
        memb = self.membership[c][pairs.patch].long()                                # (M,)
        vals, idx = self.values[c][pairs.patch], self.index[c][pairs.patch].long()   # (M, T), (M, T, 4)
        t = vals.shape[1]
        rows3 = self.dict_3[c][memb[:, None], light_idx[pairs.query]]                # (M, kl, L)
        rows4 = self.dict_4[c][memb[:, None], view_idx[pairs.query]]                 # (M, kv, V)
        u3 = rows3.gather(2, idx[:, None, :, 2].expand(-1, kl, t))                   # (M, kl, T)
        u4 = rows4.gather(2, idx[:, None, :, 3].expand(-1, kv, t))                   # (M, kv, T)
        tap_pair = pairs.pair_of_tap.reshape(-1)                                      # (4N,)
        memb_tap = memb[tap_pair]
        u1 = self.dict_1[c][memb_tap, x1.reshape(-1)].gather(1, idx[tap_pair, :, 0])   # (4N, T)
        u2 = self.dict_2[c][memb_tap, x2.reshape(-1)].gather(1, idx[tap_pair, :, 1])
        spatial = vals[tap_pair] * u1 * u2
        z = torch.bmm(spatial[:, None, :] * u3[tap_pair], u4[tap_pair].transpose(1, 2))  # (4N, kl, kv)
        return z.reshape(n, 4, kl, kv)

    def _texels(self, uv: torch.Tensor):
        """Patch index, in-patch row/col (N, 4) and bilinear weights (N, 4) of uv (N, 2)."""
        p, h, w = self.cfg.patch, self.cfg.height, self.cfg.width
        rows, cols, sw = bilinear_taps(uv, h, w)
        patch = (rows // p) * (w // p) + cols // p
        return patch, rows % p, cols % p, sw

    def eval(self, q: Query, batch: int | None = None) -> torch.Tensor:
        """Apparent BRDF (N, 3) at q (wi, wo, uv), `batch` queries at a time (default: 2^18 / max(tau) queries,
        which keeps the gathers in cache)."""
        q.require("uv", who="SparseBTF")
        fast = self._kernel_eval(q)
        if fast is not None:
            return fast
        if batch is None:
            batch = rows_per_slice(max(64, (1 << 18) // max(self.cfg.tau)), q.device)
        if batch < 1:
            raise InputError(f"SparseBTF.eval: batch must be at least 1, got {batch}")
        out = [self._eval_batch(q[s:s + batch]) for s in range(0, len(q), batch)]
        return torch.cat(out) if out else torch.zeros(0, 3, dtype=q.dtype, device=q.device)

    def _kernel_eval(self, q: Query) -> torch.Tensor | None:
        """`eval` as one fused C call (`neumat.nn.cpu_kernels.sparse_btf_eval`; the same values within float32
        rounding), or None where it does not apply: angular interpolation in value space, other dtypes or devices,
        sizes beyond its buffers, no compiler."""
        c = self.cfg
        if c.angular != "coefficient" or not cpu_kernels.usable(q.wi, q.wo, q.uv, self.values) \
                or not cpu_kernels.sparse_btf_fits(c.neighbours, c.patch, c.n_light, c.n_view):
            return None
        return cpu_kernels.sparse_btf_eval(self, q.wi, q.wo, q.uv, YUV_TO_RGB)

    def _eval_batch(self, q: Query) -> torch.Tensor:
        dev = self.values.device
        wi, wo, uv = (t.to(dev, torch.float32) for t in (q.wi, q.wo, q.uv))
        li, lw = angular_weights(self.light_dirs, wi, self.cfg.neighbours)
        vi, vw = angular_weights(self.view_dirs, wo, self.cfg.neighbours)
        patch, x1, x2, sw = self._texels(uv)
        pairs = _pairs_of_taps(patch)
        if self.cfg.angular == "coefficient":
            z = torch.stack([self._texel_sum_interpolated(c, pairs, x1, x2, sw, li, lw, vi, vw)
                             for c in range(3)], -1)                                   # (N, 3)
            bin_w = lw[:, :, None] * vw[:, None, :]
            mean = (self.mean[li[:, :, None], vi[:, None, :]] * bin_w[..., None]).sum((1, 2))
            std = (self.std[li[:, :, None], vi[:, None, :]] * bin_w[..., None]).sum((1, 2))
            f = model_space_to_rgb(z * std + mean, self.cfg.log_eps)
        else:
            n, kl, kv = len(q), li.shape[1], vi.shape[1]
            shape = (n, 4, kl, kv)
            l3 = li[:, None, :, None].expand(shape)
            v4 = vi[:, None, None, :].expand(shape)
            z = torch.stack([self._texel_bins(c, pairs, x1, x2, li, vi) for c in range(3)], -1)  # (N, 4, kl, kv, 3)
            yuv = z * self.std[l3, v4] + self.mean[l3, v4]
            rgb = model_space_to_rgb(yuv, self.cfg.log_eps)
            wts = sw[:, :, None, None] * lw[:, None, :, None] * vw[:, None, None, :]
            f = (rgb * wts[..., None]).sum((1, 2, 3))
        f = zero_below_horizon(f, wi, wo)
        return f.to(q.wi.device, q.wi.dtype)

    # ------------------------------------------------------------------------------------ inter-BTF blending
    @staticmethod
    def blend(a: "SparseBTF", b: "SparseBTF", alpha: float, tau: tuple[int, int, int] | None = None) -> "SparseBTF":
        """(1 - alpha) a + alpha b in coefficient space (Eqs. 7-9), per data point in a's dictionary.

        b's coefficients are moved to a's dictionary by S_b x_n R^(n), R^(n) = U^(n,k)T U^(n,p) (exact for
        orthonormal bases) and the blend keeps the `tau` largest coefficients (default a.tau + b.tau, which
        is exact when both points use the same dictionary). Mean and std are blended linearly.
        """
        if a.cfg.patch != b.cfg.patch or a.point_shape != b.point_shape or \
                (a.cfg.height, a.cfg.width) != (b.cfg.height, b.cfg.width):
            raise InputError("SparseBTF.blend: both BTFs need the same size, patch and direction counts")
        for n in range(1, 5):
            if not torch.equal(getattr(a, f"dict_{n}"), getattr(b, f"dict_{n}")):
                raise InputError("SparseBTF.blend: the two BTFs were coded with different dictionary ensembles")
        tau = tuple(ta + tb for ta, tb in zip(a.cfg.tau, b.cfg.tau)) if tau is None else tuple(tau)
        shape = a.point_shape
        out = SparseBTF(replace(a.cfg, tau=tau, tau_train=tuple(min(t, tl) for t, tl in zip(tau, a.cfg.tau_train)))
                        ).to(a.values.device)
        for n in range(1, 5):
            getattr(out, f"dict_{n}").copy_(getattr(a, f"dict_{n}"))
        out.light_dirs.copy_(a.light_dirs)
        out.view_dirs.copy_(a.view_dirs)
        out.mean.copy_((1 - alpha) * a.mean + alpha * b.mean)
        out.std.copy_((1 - alpha) * a.std + alpha * b.std)
        for c in range(3):
            ca, cb = a.codes(c), b.codes(c)
            sa, sb = dense_coefficients(ca, shape), dense_coefficients(cb, shape)
            for n in range(1, 5):
                u = getattr(a, f"dict_{n}")[c]
                r = u[ca.membership].transpose(1, 2) @ u[cb.membership]        # R^(n): (P, m, m), Eq. 9
                sb = mode_product(sb, r, n)
            s = ((1 - alpha) * sa + alpha * sb).reshape(sa.shape[0], -1)
            vals, idx, counts, err = keep_largest(s, tau[c])
            out._store_codes(c, Codes(ca.membership, vals, unravel(idx, shape), counts, err))
        return out

    # ------------------------------------------------------------------------------------ runtime form
    @property
    def is_runtime(self) -> bool:
        """Whether `runtime()` is in effect (model files record it and re-enter it on load)."""
        return self._runtime

    @torch.no_grad()
    def runtime(self) -> "SparseBTF":
        """Round the coefficient values and the dictionaries to fp16, as `storage` counts them (the statistics
        stay float32); the model file then stores them as fp16 (`stored_codes`). Returns self."""
        for t in (self.values, *(getattr(self, f"dict_{n}") for n in range(1, 5))):
            t.copy_(t.half())
        self._runtime = True
        return self

    # ------------------------------------------------------------------------------------ accounting
    def storage(self, value_bytes: int = 2, index_bytes: int = 2, statistics_bytes: int = 4) -> dict:
        """Bytes of the representation (module docstring): per-BTF parts, the shared ensemble, totals.
        statistics_bytes: per stored mean / std (4 as the authors' files; 2 loses nothing measurable, docs/btf.md)."""
        return storage_bytes(self.cfg, int(self.counts.long().sum()), value_bytes, index_bytes, statistics_bytes)

    def size_bytes(self, precision: str = "fp16") -> int:
        """Total bytes (per-BTF codes + shared ensemble) with values stored at `precision`."""
        value_bytes = {"fp16": 2, "fp32": 4, "bf16": 2, "int8": 1}.get(precision)
        if value_bytes is None:
            raise InputError(f"SparseBTF.size_bytes precision: expected fp16, fp32, bf16 or int8, got {precision!r}")
        return int(self.storage(value_bytes=value_bytes)["total"])

    def flops(self) -> int:
        """Approximate floating-point operations of one `eval` query (coefficient-space path)."""
        k = self.cfg.neighbours
        return int(4 * sum(self.cfg.tau) * (2 * k + 5) + 60)

    def describe(self) -> str:
        c = self.cfg
        return (f"sparse-btf ({c.height}x{c.width} texels, {c.n_light}x{c.n_view} directions, "
                f"tau {tuple(c.tau)}, K={c.num_dictionaries})")


class TapPairs(NamedTuple):
    """The 4 bilinear taps of N queries grouped into M (query, data point) pairs (`_pairs_of_taps`)."""

    pair_of_tap: torch.Tensor
    """(N, 4): the pair of every tap."""
    query: torch.Tensor
    """(M,): the query of every pair."""
    patch: torch.Tensor
    """(M,): the data point of every pair."""



def storage_bytes(cfg: Config, nnz: int | None = None, value_bytes: int = 2, index_bytes: int = 2,
                  statistics_bytes: int = 4) -> dict:
    """Bytes of a SparseBTF of `cfg` holding `nnz` coded coefficients (None: its capacity, every data point at
    tau; what it takes at most, known before coding, so a baseline can be sized to it): per-BTF parts, the shared
    ensemble, totals (`SparseBTF.storage`)."""
    c = cfg
    n_patches = (c.height // c.patch) * (c.width // c.patch)
    n_points = 3 * n_patches
    if nnz is None:
        nnz = n_patches * sum(c.tau)
    d = {
        "coefficients": nnz,
        "values": nnz * value_bytes,
        "indices": nnz * 4 * index_bytes,
        "membership": n_points * index_bytes,
        "counts": n_points * index_bytes,
        "statistics": 2 * (c.n_light * c.n_view if c.statistics == "image" else 1) * 3 * statistics_bytes,
        "dictionary": 3 * c.num_dictionaries * (2 * c.patch ** 2 + c.n_light ** 2 + c.n_view ** 2) * value_bytes,
    }
    d["per_btf"] = d["values"] + d["indices"] + d["membership"] + d["counts"] + d["statistics"]
    d["total"] = d["per_btf"] + d["dictionary"]
    d["uncompressed_fp16"] = c.n_light * c.n_view * c.height * c.width * 3 * 2
    d["compression_ratio"] = d["uncompressed_fp16"] / d["total"]
    return d


def stored_codes(module: SparseBTF, state_dict: dict, prefix: str, local_metadata) -> None:
    """State-dict hook: the codes as `storage` counts them, without the capacity padding: "values" (nnz,) and
    "index" (nnz, 4) int16 hold only the first count[c, p] coefficients of every data point (channel-major),
    "membership" and "counts" are int16; in runtime mode values and dictionaries are fp16. `unpack_codes`
    inverts it exactly (the padding is zero)."""
    counts = state_dict[prefix + "counts"].long()
    live = torch.arange(module.values.shape[-1], device=counts.device) < counts.unsqueeze(-1)   # (3, P, T)
    state_dict[prefix + "values"] = state_dict[prefix + "values"][live]
    state_dict[prefix + "index"] = state_dict[prefix + "index"][live].to(torch.int16)
    for name in ("membership", "counts"):
        state_dict[prefix + name] = state_dict[prefix + name].to(torch.int16)
    if module.is_runtime:
        for name in ("values", *(f"dict_{n}" for n in range(1, 5))):
            state_dict[prefix + name] = state_dict[prefix + name].half()


def unpack_codes(module: SparseBTF, state_dict: dict, prefix: str, local_metadata, strict, missing_keys,
                 unexpected_keys, error_msgs) -> None:
    """Load-state-dict pre-hook inverting `stored_codes`: the compact codes back to the padded (3, P, T) layout
    (DataFormatError when the counts do not match the stored coefficients)."""
    key = prefix + "counts"
    if key not in state_dict or state_dict[prefix + "values"].ndim != 1:
        return
    counts = state_dict[key].long()
    t = module.values.shape[-1]
    if (counts.shape != module.counts.shape
            or (counts.numel() and not (0 <= int(counts.min()) <= int(counts.max()) <= t))):
        raise DataFormatError(f"sparse-btf counts: expected {tuple(module.counts.shape)} integers in [0, {t}], got "
                              f"{tuple(counts.shape)}")
    values, index = state_dict[prefix + "values"], state_dict[prefix + "index"]
    nnz = int(counts.sum())
    if values.shape != (nnz,) or index.shape != (nnz, 4):
        raise DataFormatError(f"sparse-btf codes: the counts add up to {nnz} coefficients, but {tuple(values.shape)} "
                              f"values and {tuple(index.shape)} index tuples are stored")
    live = torch.arange(t) < counts.unsqueeze(-1)
    full_values = torch.zeros(module.values.shape, dtype=torch.float32)
    full_index = torch.zeros(module.index.shape, dtype=torch.int32)
    full_values[live] = values.float()
    full_index[live] = index.to(torch.int32)
    state_dict[prefix + "values"], state_dict[prefix + "index"] = full_values, full_index
    for name in ("membership", "counts"):
        state_dict[prefix + name] = state_dict[prefix + name].to(torch.int32)
    for n in range(1, 5):
        state_dict[prefix + f"dict_{n}"] = state_dict[prefix + f"dict_{n}"].float()


def _pairs_of_taps(patch: torch.Tensor) -> TapPairs:
    """Group the 4 taps of each query (data points `patch` (N, 4)) by data point; pairs are numbered in the
    order of their first taps, row-major."""
    n, taps = patch.shape
    first = (patch[:, :, None] == patch[:, None, :]).int().argmax(-1)                   # (N, 4)
    lead = first == torch.arange(taps, device=patch.device)                              # first tap of its pair
    pair_of_lead = lead.reshape(-1).long().cumsum(0).reshape(n, taps) - 1
    query = torch.arange(n, device=patch.device)[:, None].expand(n, taps)[lead]
    return TapPairs(pair_of_lead.gather(1, first), query, patch[lead])


def mse(reference: TabulatedBTF, test: TabulatedBTF) -> float:
    """Mean squared error of two BTF tables over all entries (linear RGB)."""
    return float(((reference.data - test.data.to(reference.data)) ** 2).mean())


__all__ = ["SparseBTF", "Config", "mse"]
