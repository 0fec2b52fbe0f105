"""GGX parameter mip-map, the analytic baseline of Timonen et al. 2025 (Sec. 5.2, item 4).

A pyramid of 12 GGX parameters per texel (albedo, F0, normal slopes, anisotropic roughness and its
rotation), every level optimised directly and filtered by the query footprint like the latent pyramids, then
evaluated as one analytic BRDF.

Details: src/neumat/methods/latent_mlp/NOTES.md, section `neumat.methods.latent_mlp.ggx_mipmap`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from neumat.core.checks import check_int
from neumat.core.config import resolve_config
from neumat.core.errors import InputError
from neumat.core.frames import frame_from_normal_tangent, to_local
from neumat.core.material import upper_hemisphere
from neumat.core.query import Query
from neumat.core.tensors import by_rows
from neumat.models.base import LearnedMaterial
from neumat.methods.latent_mlp.multiscale import kernel_latents
from neumat.nn import cpu_kernels
from neumat.nn.codebook import float_bits, storage_bytes
from neumat.nn.latent_texture import LatentPyramid, check_footprint
from neumat.nn.preconditioner import FrequencyPreconditioner
from neumat.reflectance.microfacet import fresnel_schlick, microfacet_brdf

CHANNELS = 12
MIN_ALPHA, MAX_ALPHA = 1e-3, 2.0


def _softplus_inverse(x: float) -> float:
    return math.log(math.expm1(x))


@dataclass
class Config:
    """GGX mip-map hyper-parameters."""

    spatial_size: int = 1024
    """Finest level of the parameter pyramid, texels a side (a power of two)."""
    spatial_precondition: float = 10.0
    """Preconditioner strength A of the pyramid."""
    max_probes: int = 16
    """Most anisotropic-filtering probes along the major axis."""
    init_albedo: float = 0.3
    """Initial (uniform) diffuse albedo."""
    init_f0: float = 0.04
    """Initial (uniform) specular F0."""
    init_alpha: float = 0.3
    """Initial (uniform) GGX alpha."""


class GGXMipmap(LearnedMaterial):
    """Filtered GGX parameters evaluated analytically (see module docstring); eval -> (N, 3)."""

    name = "ggx-mipmap"
    paper = "GGX parameter mip-map: baseline of the multi-scale gated model (Timonen et al. 2025)"
    source_kinds = ("svbrdf",)
    can_sample = False
    spatially_varying = True
    Config = Config

    def __init__(self, config: Config | None = None, **kwargs) -> None:
        nn.Module.__init__(self)
        cfg = resolve_config(Config, config, kwargs, self.name)
        for name in ("spatial_size", "max_probes"):
            check_int(getattr(cfg, name), f"ggx-mipmap.{name}")
        if cfg.spatial_size & (cfg.spatial_size - 1):
            raise InputError(f"ggx-mipmap.spatial_size: expected a power of two, got {cfg.spatial_size}")
        for name in ("init_albedo", "init_f0", "init_alpha"):
            v = getattr(cfg, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 < v <= MAX_ALPHA:
                raise InputError(f"ggx-mipmap.{name}: expected a number in (0, {MAX_ALPHA}], got {v!r}")
        self.cfg = cfg
        self.spatial = LatentPyramid(CHANNELS, cfg.spatial_size, max_probes=cfg.max_probes,
                                     precondition=FrequencyPreconditioner(cfg.spatial_precondition))
        init = torch.tensor([_softplus_inverse(cfg.init_albedo)] * 3 + [_softplus_inverse(cfg.init_f0)] * 3
                            + [0.0, 0.0] + [math.log(cfg.init_alpha)] * 2 + [1.0, 0.0])
        with torch.no_grad():
            for p in self.spatial.raw:  # constants pass the preconditioner unchanged (K(0, 0) = 1)
                p.copy_(init.view(-1, 1, 1).expand_as(p))

    @property
    def config(self) -> Config:
        return self.cfg

    def parameters_at(self, q: Query) -> dict[str, torch.Tensor]:
        """Filtered GGX parameters of the queries: albedo, f0 (N, 3), normal, tangent (N, 3), alpha_x, alpha_y (N,)."""
        q.require("uv", who="ggx-mipmap (spatially varying)")
        footprint = None if q.footprint is None else check_footprint(q.footprint, "Query.footprint")
        p = self.spatial(q.uv, footprint, q.lod)
        n = torch.cat([p[:, 6:8], torch.ones_like(p[:, :1])], -1)
        n = n / n.norm(dim=-1, keepdim=True)
        t, b = frame_from_normal_tangent(n, torch.zeros_like(n).index_fill_(1, torch.tensor([0], device=n.device), 1))
        phi = 0.5 * torch.atan2(p[:, 11], p[:, 10])
        tangent = torch.cos(phi).unsqueeze(-1) * t + torch.sin(phi).unsqueeze(-1) * b
        alpha = p[:, 8:10].exp().clamp(MIN_ALPHA, MAX_ALPHA)
        return {"albedo": F.softplus(p[:, 0:3]), "f0": F.softplus(p[:, 3:6]), "normal": n, "tangent": tangent,
                "alpha_x": alpha[:, 0], "alpha_y": alpha[:, 1]}

    def eval(self, q: Query) -> torch.Tensor:
        """BRDF value (N, 3), linear RGB, cosine excluded (module docstring)."""
        q.require("wo", who="ggx-mipmap.eval")
        fast = self._kernel_eval(q)
        return fast if fast is not None else by_rows(self._eval_rows, self.eval_chunk, q)

    def _kernel_eval(self, q: Query) -> torch.Tensor | None:
        """`eval` as one fused C call, the parameter read (finest level, lod or footprint) included
        (`neumat.nn.cpu_kernels.ggx_mipmap_eval`), or None where it does not apply (autograd, other dtypes, no
        compiler). Why: the torch path is some 100 small tensor operations."""
        if not cpu_kernels.usable(q.wi, q.wo, self.spatial.raw[0]):
            return None
        tables = cpu_kernels.prepared(self, lambda: cpu_kernels.PyramidTables(self.spatial))
        latents = kernel_latents(self, tables, q)
        return None if latents is None else cpu_kernels.ggx_mipmap_eval(latents, q.wi, q.wo)

    def _eval_rows(self, q: Query) -> torch.Tensor:
        p = self.parameters_at(q)
        n, t = p["normal"], p["tangent"]
        b = torch.cross(n, t, dim=-1)
        wi, wo = q.wi.to(n.dtype), q.wo.to(n.dtype)
        li, lo = to_local(wi, t, b, n), to_local(wo, t, b, n)
        up = upper_hemisphere(q.wi, q.wo) & (li[:, 2] > 0) & (lo[:, 2] > 0)
        li = torch.where(up.unsqueeze(-1), li, torch.tensor([0.0, 0.0, 1.0], dtype=li.dtype, device=li.device))
        lo = torch.where(up.unsqueeze(-1), lo, torch.tensor([0.0, 0.0, 1.0], dtype=lo.dtype, device=lo.device))
        spec = microfacet_brdf(li, lo, p["alpha_x"], p["alpha_y"], lambda c: fresnel_schlick(c, p["f0"]))
        ratio = 0.5 * (li[:, 2] / wi[:, 2].clamp(min=1e-6) + lo[:, 2] / wo[:, 2].clamp(min=1e-6))
        f = (p["albedo"] / math.pi + spec) * ratio.unsqueeze(-1)
        return torch.where(up.unsqueeze(-1), f, torch.zeros_like(f)).to(q.dtype)

    def forward(self, q: Query) -> torch.Tensor:
        return self.eval(q)

    def size_bytes(self, precision: str = "fp16") -> int:
        """Stored size: the 12-channel pyramid, all levels."""
        return storage_bytes(self.spatial.num_parameters() * float_bits(precision))

    def flops(self) -> int:
        """Per evaluation, counted by hand: parameter transforms (softplus 6 x 4, exp 2, atan2/sincos ~20),
        frame (normalise 8, Gram-Schmidt 12, rotation 12, cross 9), two transforms into it (30), half vector
        (10), D (12), two G1 (2 x 10), Schlick (3 x 3 + 6), combination (12), cosine ratio (5): ~190
        (the paper: ~100 for its shader)."""
        return 24 + 2 + 20 + 8 + 12 + 12 + 9 + 30 + 10 + 12 + 20 + 15 + 12 + 5
