"""NeuMIP (Kuznetsov et al. 2021), as a baseline of Timonen et al. 2025 (Sec. 5.2), with its neural offset module
optional (Config.offset, registered on as "neumip-offset", `neumat.methods.latent_mlp.neumip_offset`).

    log f(wi, wo | uv, Sigma) = MLP(z_s, wi, wo),   z_s = T(S, uv', Sigma)

The spatial latent z_s comes from the same learned, preconditioned mip pyramid with anisotropic filtering
as the gated model (`neumat.methods.latent_mlp.multiscale`); the MLP reads it concatenated with the local-frame
Cartesian directions (6 values). SiLU, exponential output, as every model of the paper's common codebase.

Details: src/neumat/methods/latent_mlp/NOTES.md, section `neumat.methods.latent_mlp.neumip`.
"""
from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace

import torch
from torch import nn

from neumat.core.checks import check_int, check_number
from neumat.core.config import resolve_config
from neumat.core.errors import InputError
from neumat.core.material import zero_below_horizon
from neumat.core.query import Query
from neumat.core.tensors import by_rows
from neumat.models.base import LearnedMaterial
from neumat.methods.latent_mlp.multiscale import (kernel_bundle, kernel_latents, preconditioned_noise,
                                                  start_at_data_scale)
from neumat.methods.latent_mlp.spatial_latent import SpatialLatent, fused_adam
from neumat.nn import cpu_kernels
from neumat.nn.angular_texture import half_difference
from neumat.nn.codebook import float_bits, storage_bytes
from neumat.nn.latent_texture import LatentPyramid
from neumat.nn.mlp import MLP
from neumat.nn.preconditioner import FrequencyPreconditioner
from neumat.nn.shading_frames import ShadingFrame

DIRECTIONS = ("cartesian", "rusinkiewicz")
#: FLOPs of the parallax step after the offset MLP (`NeuMIP.flops`)
PARALLAX_FLOPS = 8


@dataclass
class Config:
    """Hyper-parameters of the latent-pyramid + MLP decoders (see module docstring)."""

    spatial_channels: int = 8
    """Channels of the spatial latent z_s."""
    spatial_size: int = 1024
    """Finest level of the spatial pyramid, texels a side (a power of two)."""
    hidden: int = 20
    """Hidden channels of the MLP."""
    hidden_layers: int = 3
    """Hidden layers of the MLP."""
    directions: str = "cartesian"
    """MLP direction inputs: "cartesian" (wi, wo) or "rusinkiewicz" (half and difference vectors)."""
    shading_frame: bool = False
    """Express wi, wo in a shading frame decoded from z_s first (Zeltner et al. 2024)."""
    frames: int = 1
    """Learned shading frames with `shading_frame` (Zeltner et al. decode 2); the MLP reads wi, wo in each."""
    frame_weight_scale: float = 0.1
    """Factor on the shading-frame decoder's weights, i.e. its relative learning rate under Adam
    (`neumat.nn.shading_frames`; 1 measured ~1.7x worse mean FLIP on Wood092)."""
    spatial_precondition: float = 10.0
    """Preconditioner strength A of the spatial pyramid."""
    max_probes: int = 16
    """Most anisotropic-filtering probes along the major axis."""
    init_std: float = 1.0
    """Standard deviation of the (preconditioned) spatial latents at initialisation."""
    init_log_value: float = -2.0
    """Initial bias of the MLP output (log f), as the gated model; replaced by the data's scale with
    `init_from_data`."""
    init_from_data: bool = True
    """Start the MLP's output biases at log of the median target of the fit's first batch, per channel
    (`init_from_targets`): at -2 a fit first spends 250-450 of the CPU recipe's 1000 steps overpredicting
    (NOTES.md, "output initialisation")."""
    level_selection: str = "trilinear"
    """How a fractional mip level is read: "trilinear" (the latents of the two levels blended) or "roulette"
    (Zeltner et al. 2024 Sec. 4.1: one of the two, the coarser with probability t, its fractional weight).
    Training draws the level; `eval` returns the expectation (1 - t) f(z_fine) + t f(z_coarse) (two decodes),
    as the GLSL and Slang exports do. The sampler reads the trilinear latent in both cases."""
    offset: bool = False
    """NeuMIP's neural offset module (module docstring): the lookup of z_s moves by a learned depth along wo."""
    offset_channels: int = 5
    """Channels of the offset latent pyramid (same size and preconditioner as the spatial one)."""
    offset_hidden: int = 6
    """Hidden channels of the offset MLP (inputs: the offset latent and wo; output: the depth)."""
    offset_hidden_layers: int = 1
    """Hidden layers of the offset MLP."""
    offset_min_cos: float = 0.1
    """Least wo.z the parallax divides by: shifts are at most h sqrt(1 - c^2) / c (about 10 h)."""


def _check_config(c: Config, who: str) -> None:
    for name, lo in (("spatial_channels", 1), ("spatial_size", 1), ("hidden", 1), ("hidden_layers", 0),
                     ("max_probes", 1), ("frames", 1), ("offset_channels", 1), ("offset_hidden", 1),
                     ("offset_hidden_layers", 0)):
        check_int(getattr(c, name), f"{who}.{name}", lo)
    if c.spatial_size & (c.spatial_size - 1):
        raise InputError(f"{who}.spatial_size: expected a power of two, got {c.spatial_size}")
    if c.level_selection not in ("trilinear", "roulette"):
        raise InputError(f"{who}.level_selection: expected 'trilinear' or 'roulette', got {c.level_selection!r}")
    if c.directions not in DIRECTIONS:
        raise InputError(f"{who}.directions: expected one of {', '.join(DIRECTIONS)}, got {c.directions!r}")
    if c.frames > 1 and (not c.shading_frame or c.directions != "cartesian"):
        raise InputError(f"{who}.frames: {c.frames} frames need shading_frame=True and cartesian directions")
    if not isinstance(c.offset, bool):
        raise InputError(f"{who}.offset: expected true or false, got {c.offset!r}")
    for name in ("spatial_precondition", "init_std", "init_log_value", "frame_weight_scale", "offset_min_cos"):
        check_number(getattr(c, name), f"{who}.{name}")
    if not 0 < c.offset_min_cos <= 1:
        raise InputError(f"{who}.offset_min_cos: expected a cosine in (0, 1], got {c.offset_min_cos}")
    if c.spatial_precondition < 0 or c.init_std < 0 or c.frame_weight_scale < 0:
        raise InputError(f"{who}: spatial_precondition, init_std and frame_weight_scale must be >= 0")


class NeuMIP(LearnedMaterial, SpatialLatent):
    """exp(MLP([z_s, directions])) with z_s from a filtered latent pyramid (module docstring); eval -> (N, 3)."""

    name = "neumip"
    paper = "NeuMIP (Kuznetsov et al. 2021): baseline of the multi-scale gated model (Timonen et al. 2025)"
    source_kinds = ("svbrdf",)
    can_sample = False
    spatially_varying = True
    Config = Config

    def __init__(self, config: Config | None = None, **kwargs) -> None:
        nn.Module.__init__(self)
        cfg = resolve_config(type(self).Config, config, kwargs, self.name)
        _check_config(cfg, self.name)
        self.cfg = cfg
        ds = cfg.spatial_channels
        self.spatial = LatentPyramid(ds, cfg.spatial_size, max_probes=cfg.max_probes,
                                     precondition=FrequencyPreconditioner(cfg.spatial_precondition))
        with torch.no_grad():
            for p in self.spatial.raw:
                p.copy_(preconditioned_noise(tuple(p.shape), cfg.init_std, cfg.spatial_precondition))
        self.frame = ShadingFrame(ds, cfg.frame_weight_scale, cfg.frames) if cfg.shading_frame else None
        self.mlp = MLP(ds + 6 * (cfg.frames if cfg.shading_frame else 1), cfg.hidden, cfg.hidden_layers,
                       self.outputs, "silu")
        with torch.no_grad():
            self.mlp.linears()[-1].bias.fill_(cfg.init_log_value)
        self.offset_texture = self.offset_mlp = None
        if cfg.offset:
            if self.can_sample:
                raise InputError(f"{self.name}.offset: the neural offset reads wo, which the importance sampler's "
                                 "latent cannot (it samples wo)")
            self.offset_texture = LatentPyramid(cfg.offset_channels, cfg.spatial_size, max_probes=cfg.max_probes,
                                                precondition=FrequencyPreconditioner(cfg.spatial_precondition))
            with torch.no_grad():
                for p in self.offset_texture.raw:
                    p.copy_(preconditioned_noise(tuple(p.shape), cfg.init_std, cfg.spatial_precondition))
            self.offset_mlp = MLP(cfg.offset_channels + 3, cfg.offset_hidden, cfg.offset_hidden_layers, 1, "silu")
            self.offset_mlp.start_constant(torch.zeros(1))

    @property
    def config(self) -> Config:
        return self.cfg

    def optimizer(self, lr: float, betas: tuple[float, float], eps: float) -> torch.optim.Optimizer:
        """Adam with the fused kernel (`spatial_latent.fused_adam`: the same update, a fifth of the time per step
        on a 1K pyramid)."""
        return fused_adam(self.parameters(), lr, betas, eps)

    def init_from_targets(self, target: torch.Tensor) -> None:
        """With `init_from_data`, the fit starts at the data's scale (`multiscale.start_at_data_scale`; trainer
        hook, before the first step)."""
        if self.cfg.init_from_data:
            start_at_data_scale(self.mlp, target, self.name)

    @property
    def outputs(self) -> int:
        """MLP outputs: log f (3); subclasses may add more after them."""
        return 3

    def eval(self, q: Query) -> torch.Tensor:
        """BRDF value (N, 3), linear RGB, cosine excluded; 0 below the geometric horizon."""
        q.require("wo", who=f"{self.name}.eval")
        fast = self._kernel_eval(q)
        if fast is not None:
            return fast
        return by_rows(lambda rows: self.filtered_outputs(rows)[:, :3], self.eval_chunk, q)

    def _kernel_eval(self, q: Query) -> torch.Tensor | None:
        """`eval` as fused C calls, the spatial read (finest level, lod or footprint) included
        (`neumat.nn.cpu_kernels.neumip_eval`: NeuMIP, nbrdf-uv, neumip-frame, neural-appearance's BRDF; with the
        offset module, its lookup points first by `cpu_kernels.neumip_offset_uv`), or None where it does not
        apply: autograd, other dtypes, no compiler, more than 4 shading frames, roulette levels, more outputs than
        3."""
        if not cpu_kernels.usable(q.wi, q.wo, self.spatial.raw[0]):
            return None
        k = cpu_kernels.prepared(self, self._kernel_bundle)
        uv = None
        if k is not None and k.offset_mlp is not None:
            offset = kernel_latents(self, k.offset_tables, q)
            if offset is None:
                return None
            uv = cpu_kernels.neumip_offset_uv(k.offset_mlp, offset, q.wo, self.cfg.spatial_size,
                                              self.cfg.offset_min_cos)
        latents = None if k is None else kernel_latents(self, k.tables, q, uv)
        if latents is None:
            return None
        return cpu_kernels.neumip_eval(k.mlp, latents, q.wi, q.wo, k.frame, self.cfg.directions == "rusinkiewicz")

    def _kernel_bundle(self) -> SimpleNamespace | None:
        """`kernel_bundle` with the offset module's MLP packed and its pyramid's tables (None without it), or None
        for the variants the kernel lacks (`_kernel_eval`)."""
        c = self.cfg
        if not cpu_kernels.neumip_fits(c.spatial_channels, 1 if self.frame is None else self.frame.frames) \
                or c.level_selection != "trilinear" or self.outputs != 3:
            return None
        offset_mlp = None if self.offset_mlp is None else cpu_kernels.PackedMLP.pack(self.offset_mlp.net)
        if self.offset_mlp is not None and (offset_mlp is None or not cpu_kernels.neumip_fits(c.offset_channels, 0)):
            return None
        return kernel_bundle(self, offset_mlp=offset_mlp, offset_tables=None if offset_mlp is None else
                             cpu_kernels.PyramidTables(self.offset_texture))

    def spatial_latent(self, q: Query, level_u: torch.Tensor | None = None) -> torch.Tensor:
        """z_s (N, D_s) of the query's uv and footprint (or lod); with Config.level_selection "roulette" a
        training model draws one level per query (level_u, uniform, unless given)."""
        if level_u is None and self.training and self.cfg.level_selection == "roulette":
            level_u = torch.rand(len(q.wi), device=q.wi.device)
        return super().spatial_latent(q, level_u)

    def latent_uv(self, q: Query, footprint: torch.Tensor | None) -> torch.Tensor:
        """q.uv, or with the offset module `offset_uv`."""
        return q.uv if self.offset_mlp is None else self.offset_uv(q, footprint)

    def sampling_features(self, q: Query) -> torch.Tensor:
        """z_s (N, D_s) without gradient for a learned sampler; with the offset module, at q.uv unshifted (a
        sampler's query has no wo)."""
        if self.offset_mlp is None:
            return super().sampling_features(q)
        with torch.no_grad():
            return self.read_latent(q, shifted=False)

    def offset_uv(self, q: Query, footprint: torch.Tensor | None) -> torch.Tensor:
        """The offset module's lookup point uv' (N, 2) of q (module docstring): the offset latent filtered at the
        (checked) footprint or q.lod, its depth h = MLP_o(z_o, wo) / spatial_size (uv units), and
        uv' = uv + h wo.xy / max(wo.z, offset_min_cos)."""
        q.require("wo", who=f"{self.name} offset module")
        z_o = self.offset_texture(q.uv, footprint, q.lod)
        wo = q.wo.to(z_o.dtype)
        h = self.offset_mlp(torch.cat([z_o, wo], -1)) / self.cfg.spatial_size
        return q.uv.to(z_o.dtype) + h * wo[:, :2] / wo[:, 2:].clamp(min=self.cfg.offset_min_cos)

    def filtered_outputs(self, q: Query) -> torch.Tensor:
        """All decoded outputs (N, `outputs`) at q: of the filtered latent, or with roulette level selection
        outside training the expectation over the two levels (Config.level_selection)."""
        if self.training or self.cfg.level_selection != "roulette":
            return self.decode_outputs(self.spatial_latent(q), q)
        n = len(q.wi)
        fine = self.decode_outputs(self.spatial_latent(q, q.wi.new_ones(n)), q)
        coarse = self.decode_outputs(self.spatial_latent(q, q.wi.new_zeros(n)), q)
        t = self.spatial.level_fraction(q.footprint, q.lod, n, q.wi.device).to(fine.dtype).unsqueeze(-1)
        return (1 - t) * fine + t * coarse

    def decode(self, z_s: torch.Tensor, q: Query) -> torch.Tensor:
        """BRDF value (N, 3) of latents z_s (N, D_s) at the directions of q (the decoder without the texture)."""
        return self.decode_outputs(z_s, q)[:, :3]

    def decode_outputs(self, z_s: torch.Tensor, q: Query) -> torch.Tensor:
        """exp of all MLP outputs (N, `outputs`) of latents z_s at the directions of q, 0 below the horizon."""
        wi, wo = q.wi.to(z_s.dtype), q.wo.to(z_s.dtype)
        if self.frame is not None:
            wi, wo = self.frame(z_s, wi, wo)
        directions = torch.cat(half_difference(wi, wo) if self.cfg.directions == "rusinkiewicz" else (wi, wo), -1)
        f = torch.exp(self.mlp(torch.cat([z_s, directions], -1)))
        return zero_below_horizon(f, q.wi, q.wo).to(q.dtype)

    def forward(self, q: Query) -> torch.Tensor:
        return self.eval(q)

    def size_bytes(self, precision: str = "fp16") -> int:
        """Stored size: spatial pyramid (all levels), the offset pyramid if any, and decoders."""
        return storage_bytes(sum(p.numel() for p in self.parameters()) * float_bits(precision))

    def flops(self) -> int:
        """Per evaluation: MLP and exp, the shading frame if any, the Rusinkiewicz transform (~60) if used, the
        offset MLP and its parallax (8: depth scale, clamp, 2 multiplies, 2 divides, 2 adds) if used; not the
        spatial texture fetches (texture units), as Timonen et al. count."""
        total = self.mlp.flops() + 3
        if self.offset_mlp is not None:
            total += self.offset_mlp.flops() + PARALLAX_FLOPS
        if self.frame is not None:
            total += self.frame.flops()
        if self.cfg.directions == "rusinkiewicz":
            total += 60
        return total
