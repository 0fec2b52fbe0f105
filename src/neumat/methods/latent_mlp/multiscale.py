"""Multi-scale gated neural (SV)BRDF (Timonen, Kemppinen, Lehtinen 2025).

    log f(wi, wo | uv, Sigma) = MLP(z_h, z_d),   z_h = H z_s,  z_d = D z_s                  (paper Eq. 6)

S: a latent mip pyramid (`neumat.nn.latent_texture`); H, D: polar latent textures (`neumat.nn.angular_texture`)
addressed through learned radial warps; learned shading frames, preconditioned textures, SiLU, exp output.
`homogeneous=True`: no spatial texture.

Details: src/neumat/methods/latent_mlp/NOTES.md, section `neumat.methods.latent_mlp.multiscale`.
"""
from __future__ import annotations

import math
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
from neumat.methods.latent_mlp.spatial_latent import SpatialLatent, fused_adam
from neumat.nn import cpu_kernels
from neumat.nn.angular_texture import AngularTexture, disk_polar, half_difference
from neumat.nn.codebook import float_bits, storage_bytes
from neumat.nn.latent_texture import LatentPyramid, check_footprint
from neumat.nn.mlp import MLP, log_median
from neumat.nn.preconditioner import FrequencyPreconditioner, preconditioner_kernel
from neumat.nn.radial_warp import RadialWarp
from neumat.nn.shading_frames import ShadingFrame, lift_to_hemisphere


@dataclass
class Config:
    """Hyper-parameters of the gated multi-scale model; defaults follow the paper (see module docstring)."""

    homogeneous: bool = False
    """True for spatially uniform BRDFs: no spatial texture, H and D hold z_h, z_d directly."""
    spatial_channels: int = 8
    """D_s, channels of the spatial latent z_s."""
    spatial_size: int = 1024
    """Finest level of the spatial pyramid, texels a side (a power of two)."""
    half_channels: int = 8
    """D_h, dimension of z_h."""
    diff_channels: int = 8
    """D_d, dimension of z_d."""
    angular_radial: int = 16
    """Rows (radii) of the angular textures."""
    angular_phi: int = 40
    """Columns (azimuths) of the angular textures."""
    hidden: int = 16
    """Hidden channels c of the decoder MLP."""
    hidden_layers: int = 1
    """Hidden layers L of the decoder MLP."""
    warp_terms: int = 2
    """Components of each radial warp (Eq. 7)."""
    shading_frame: bool = True
    """Learned shading frame from z_s (spatially varying only)."""
    frame_weight_scale: float = 0.1
    """Factor on the shading-frame decoder's weights, i.e. its relative learning rate under Adam
    (`neumat.nn.shading_frames`; 1 measured ~1.7x worse mean FLIP on Wood092)."""
    gating: bool = True
    """z_h = H z_s, z_d = D z_s (Eq. 6). False: H, D hold vectors and the MLP reads [z_h, z_d, z_s]
    concatenated (the tripleplane conditioning, Eq. 5)."""
    radial_warps: bool = True
    """Learned radial warps of the angular coordinates (Eq. 7); False reads the textures at r directly."""
    spatial_precondition: float = 10.0
    """Preconditioner strength A of the spatial pyramid."""
    angular_precondition: float = 5.0
    """Preconditioner strength A of the angular textures."""
    max_probes: int = 16
    """Most anisotropic-filtering probes along the major axis."""
    init_std: float = 1.0
    """Standard deviation of the (preconditioned) spatial latents and of z_h, z_d at initialisation."""
    init_log_value: float = -2.0
    """Initial bias of the MLP output (log f) until a fit's first batch replaces it (`init_from_data`): exp(-2)
    = 0.14 is on the scale of diffuse BRDF values. The paper does not state its initialisation; starting near 1
    leaves the prediction-relative loss on a plateau (relative error ~1, small gradients) for the first few
    hundred steps."""
    init_from_data: bool = True
    """Start the MLP's output biases at log of the median target of the fit's first batch, per channel
    (`init_from_targets`), instead of init_log_value: at -2 the CPU recipe's fits lost a quarter to a half of
    their 1000 steps overpredicting (NOTES.md, "output initialisation")."""
    output_bound: bool = True
    """Bound the fitted model's output per channel by the largest target its fit saw (`target_max`; not in the
    paper): a whole 1K set's fit at the CPU recipe reached 100-10,000x the reference at grazing forward reflection
    on up to 1.7e-4 of queries (fireflies; NOTES.md, "output bound"). Applies outside training only."""


def _check_config(c: Config) -> None:
    for name, lo in (("spatial_channels", 1), ("spatial_size", 1), ("half_channels", 1), ("diff_channels", 1),
                     ("angular_radial", 2), ("angular_phi", 1), ("hidden", 1), ("hidden_layers", 0),
                     ("warp_terms", 1), ("max_probes", 1)):
        check_int(getattr(c, name), f"multiscale.{name}", lo)
    if c.spatial_size & (c.spatial_size - 1):
        raise InputError(f"multiscale.spatial_size: expected a power of two, got {c.spatial_size}")
    check_number(c.init_log_value, "multiscale.init_log_value")
    for name in ("spatial_precondition", "angular_precondition", "init_std", "frame_weight_scale"):
        check_number(getattr(c, name), f"multiscale.{name}", 0)


@torch.no_grad()
def start_at_data_scale(mlp: MLP, target: torch.Tensor, who: str) -> None:
    """The first three output biases of `mlp` (log f) become log(median) per channel of `target` (N, >= 3),
    clamped to >= 1e-4: an exp-output decoder's first predictions sit at the data's scale rather than
    overpredicting a dark material (the relative loss's plateau at relative error ~1)."""
    if target.ndim != 2 or target.shape[1] < 3:
        raise InputError(f"{who}.init_from_targets: expected targets (N, 3), got {tuple(target.shape)}")
    bias = mlp.linears()[-1].bias
    bias[:3] = log_median(target[:, :3]).to(bias)


def preconditioned_noise(shape: tuple[int, ...], std: float, strength: float) -> torch.Tensor:
    """White noise whose preconditioned version (strength A, over the last two axes) has standard deviation
    about `std` (the filter's mean squared gain divided out)."""
    gain = preconditioner_kernel(shape[-2], shape[-1], strength).square().mean().sqrt().item() if strength else 1.0
    return torch.randn(shape) * (std / gain)


def kernel_bundle(model, **extra) -> SimpleNamespace | None:
    """What every latent model's fused kernel reads besides the query, made once per parameter state through
    `cpu_kernels.prepared`: `mlp` (its MLP packed), `tables` (its pyramid's `cpu_kernels.PyramidTables`), `frame`
    (`kernel_frame`) and `extra`'s; None where the kernels do not implement its MLP (another activation)."""
    mlp = cpu_kernels.PackedMLP.pack(model.mlp.net)
    if mlp is None:
        return None
    return SimpleNamespace(mlp=mlp, tables=cpu_kernels.PyramidTables(model.spatial), frame=kernel_frame(model.frame),
                           **extra)


def kernel_frame(frame: ShadingFrame | None) -> tuple[torch.Tensor, torch.Tensor] | None:
    """A shading frame's decode layer as the fused kernels read it: (weight x weight scale, bias), or None."""
    if frame is None:
        return None
    return (frame.decode.weight * frame.weight_scale).contiguous(), frame.decode.bias.detach().clone()


def kernel_latents(model, tables: "cpu_kernels.PyramidTables", q: Query,
                   uv: torch.Tensor | None = None) -> "cpu_kernels.LatentSource | None":
    """The spatial latents of a model with a `LatentPyramid`, read at q.uv (or `uv`) with q's footprint or lod, as
    a fused kernel reads them (`cpu_kernels.LatentSource` of the pyramid's `tables`), or None for other than float32
    inputs. The footprint is checked as the torch path checks it."""
    q.require("uv", who=f"{model.name} (spatially varying)")
    footprint = None if q.footprint is None else check_footprint(q.footprint, "Query.footprint")
    if any(t is not None and t.dtype != torch.float32 for t in (q.uv, q.lod, footprint)):
        return None
    return cpu_kernels.LatentSource(tables, q.uv if uv is None else uv, q.lod if footprint is None else None,
                                    footprint)


def _kernel_texture(padded: torch.Tensor, channels: int, spatial: int) -> torch.Tensor:
    """A padded polar texture (channels x spatial, R, P + 2) as `cpu_kernels.multiscale_eval` reads it: channels-last,
    the channel c x spatial + i moved to i x channels + c (the gating's sum over i then runs along rows)."""
    r, w = padded.shape[1:]
    return padded.view(channels, spatial, r, w).permute(2, 3, 1, 0).contiguous().view(r, w, spatial * channels)


class MultiScale(LearnedMaterial, SpatialLatent):
    """The gated multi-scale model (see module docstring). eval(q) -> (N, 3)."""

    name = "multiscale"
    paper = "Timonen, Kemppinen, Lehtinen 2025: multi-scale gated neural SVBRDF"
    source_kinds = ("svbrdf",)
    can_sample = False
    Config = Config

    def __init__(self, config: Config | None = None, **kwargs) -> None:
        nn.Module.__init__(self)
        cfg = resolve_config(type(self).Config, config, kwargs, self.name)
        _check_config(cfg)
        self.cfg = cfg
        self.spatially_varying = not cfg.homogeneous
        ds, dh, dd = cfg.spatial_channels, cfg.half_channels, cfg.diff_channels
        gated = cfg.gating and not cfg.homogeneous
        gate = ds if gated else 1
        ang = FrequencyPreconditioner(cfg.angular_precondition)
        shape = (cfg.angular_radial, cfg.angular_phi)
        self.half_texture = AngularTexture(dh * gate, *shape, 2 * math.pi, precondition=ang)
        self.diff_texture = AngularTexture(dd * gate, *shape, math.pi, precondition=ang)
        # matrices scaled so that z_h = H z_s has standard deviation init_std for z_s of init_std
        matrix_std = 1 / math.sqrt(ds) if gated else cfg.init_std
        with torch.no_grad():
            for tex in (self.half_texture, self.diff_texture):
                tex.raw.copy_(preconditioned_noise(tuple(tex.raw.shape), matrix_std, cfg.angular_precondition))
        latent = 0 if cfg.homogeneous else ds
        self.warp_h = RadialWarp(cfg.warp_terms, latent) if cfg.radial_warps else None
        self.warp_d = RadialWarp(cfg.warp_terms, latent) if cfg.radial_warps else None
        if cfg.homogeneous:
            self.spatial = None
            self.frame = None
        else:
            self.spatial = LatentPyramid(ds, cfg.spatial_size, max_probes=cfg.max_probes,
                                         precondition=FrequencyPreconditioner(cfg.spatial_precondition))
            with torch.no_grad():
                for p in self.spatial.raw:
                    p.copy_(preconditioned_noise(tuple(p.shape), cfg.init_std, cfg.spatial_precondition))
            self.frame = ShadingFrame(ds, cfg.frame_weight_scale) if cfg.shading_frame else None
        self.mlp = MLP(dh + dd + (0 if gated or cfg.homogeneous else ds), cfg.hidden, cfg.hidden_layers, 3, "silu")
        with torch.no_grad():
            self.mlp.linears()[-1].bias.fill_(cfg.init_log_value)
        #: the largest target per channel that the fit has seen (`observe_targets`); 0: none seen, no bound
        self.register_buffer("target_max", torch.zeros(3))

    @property
    def config(self) -> Config:
        return self.cfg

    def optimizer(self, lr: float, betas: tuple[float, float], eps: float) -> torch.optim.Optimizer:
        """Adam with the fused kernel (`spatial_latent.fused_adam`: the same update, a fifth of the time per step
        on a 1K pyramid)."""
        return fused_adam(self.parameters(), lr, betas, eps)

    def init_from_targets(self, target: torch.Tensor) -> None:
        """With `init_from_data`, the fit starts at the data's scale (`start_at_data_scale`; trainer hook)."""
        if self.cfg.init_from_data:
            start_at_data_scale(self.mlp, target, self.name)

    @torch.no_grad()
    def observe_targets(self, target: torch.Tensor) -> None:
        """Raise `target_max` to the largest value per channel of a training batch's targets (N, 3)."""
        self.target_max.copy_(torch.maximum(self.target_max, target[:, :3].amax(0).to(self.target_max)))

    def _has_bound(self) -> bool:
        """Whether the output is bounded (`Config.output_bound`): configured, and a target seen (not a model from
        before the bound, or never fitted)."""
        return self.cfg.output_bound and bool((self.target_max > 0).all())

    def output_bound_values(self) -> list[float] | None:
        """The per-channel bound on the output outside training, or None (`_has_bound`)."""
        return [float(x) for x in self.target_max] if self._has_bound() else None

    def _bounded(self, f: torch.Tensor) -> torch.Tensor:
        """`f` at most the output bound outside training (inside, its gradient must reach overpredictions)."""
        return f if self.training or not self._has_bound() else torch.minimum(f, self.target_max.to(f.dtype))

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs) -> None:
        # model files from before the output bound have no target_max: they load without a bound
        state_dict.setdefault(prefix + "target_max", torch.zeros(3))
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    def latents(self, q: Query) -> torch.Tensor:
        """MLP input: [z_h, z_d] (N, D_h + D_d), or [z_h, z_d, z_s] without gating."""
        q.require("wo", who="multiscale.eval")
        wi, wo = q.wi, q.wo
        z_s = None
        if self.spatial is not None:
            z_s = self.spatial_latent(q)
        if self.frame is not None:
            wi, wo = self.frame(z_s, wi, wo)
        else:
            wi, wo = lift_to_hemisphere(wi), lift_to_hemisphere(wo)
        h, d = half_difference(wi, wo)
        r_h, phi_h = disk_polar(h)
        r_d, phi_d = disk_polar(d, math.pi)
        if self.warp_h is not None:
            r_h, r_d = self.warp_h(r_h, z_s), self.warp_d(r_d, z_s)
        if z_s is None or not self.cfg.gating:
            a_h, a_d = self.half_texture(r_h, phi_h), self.diff_texture(r_d, phi_d)
            return torch.cat([a_h, a_d] if z_s is None else [a_h, a_d, z_s], -1)
        # gating on channels-first reads: H (D_h, D_s, N) times z_s (D_s, N), summed over D_s
        z = z_s.t().unsqueeze(0)
        z_h = (self.half_texture.read(r_h, phi_h).view(self.cfg.half_channels, -1, len(z_s)) * z).sum(1)
        z_d = (self.diff_texture.read(r_d, phi_d).view(self.cfg.diff_channels, -1, len(z_s)) * z).sum(1)
        return torch.cat([z_h, z_d], 0).t()

    def eval(self, q: Query) -> torch.Tensor:
        """BRDF value (N, 3), linear RGB, cosine excluded; 0 below the geometric horizon."""
        fast = self._kernel_eval(q)
        return self._bounded(fast if fast is not None else by_rows(self._eval_rows, self.eval_chunk, q))

    def _kernel_eval(self, q: Query) -> torch.Tensor | None:
        """`eval` as one fused C call, the spatial read (finest level, lod or footprint) included
        (`neumat.nn.cpu_kernels.multiscale_eval`; the torch path's values within float32 rounding), or None where
        it does not apply: autograd, other dtypes, no compiler, no spatial texture (homogeneous), sizes beyond the
        kernel's buffers. Without gating (tripleplane) the MLP reads the concatenated latents. Why: the torch path
        is some 150 small tensor operations (1.2e6 evaluations per second)."""
        if self.spatial is None or q.wo is None or not cpu_kernels.usable(q.wi, q.wo, self.half_texture.raw):
            return None
        k = cpu_kernels.prepared(self, self._kernel_bundle)
        latents = None if k is None else kernel_latents(self, k.tables, q)
        if latents is None:
            return None
        c = self.cfg
        return cpu_kernels.multiscale_eval(k.mlp, latents, q.wi, q.wo, k.frame, k.warps, k.tex_h, k.tex_d,
                                           c.half_channels, c.diff_channels, gated=c.gating)

    def _kernel_bundle(self) -> SimpleNamespace | None:
        """`kernel_bundle` with the warps' decode layers and the two padded polar textures in the kernel's layout
        (`_kernel_texture`), or None where the model's sizes exceed the kernel's buffers."""
        c = self.cfg
        gate = c.spatial_channels if c.gating else 1
        if (self.frame is not None and self.frame.frames != 1) \
                or not cpu_kernels.multiscale_fits(c.spatial_channels, c.half_channels, c.diff_channels, gate,
                                                   c.warp_terms):
            return None
        warps = None if self.warp_h is None else tuple(
            t.detach().contiguous() for w in (self.warp_h, self.warp_d) for t in (w.decode.weight, w.decode.bias))
        return kernel_bundle(self, warps=warps,
                             tex_h=_kernel_texture(self.half_texture.padded(), c.half_channels, gate),
                             tex_d=_kernel_texture(self.diff_texture.padded(), c.diff_channels, gate))

    def _eval_rows(self, q: Query) -> torch.Tensor:
        f = torch.exp(self.mlp(self.latents(q)))
        return zero_below_horizon(f, q.wi, q.wo).to(q.dtype)

    def forward(self, q: Query) -> torch.Tensor:
        return self.eval(q)

    # ------------------------------------------------------------------------------ cost and size

    def size_bytes(self, precision: str = "fp16") -> int:
        """Stored size: every parameter (spatial pyramid with all levels, angular textures, decoders)."""
        return storage_bytes(sum(p.numel() for p in self.parameters()) * float_bits(precision))

    def flops(self) -> int:
        """Floating-point operations per evaluation, counted as the paper does: decoders, gating, warps,
        shading frame and angular texture reads; not the spatial texture fetch (done by texture units)."""
        c = self.cfg
        total = self.mlp.flops() + 3  # + exp
        total += 3 if self._has_bound() else 0
        total += self.half_texture.flops() + self.diff_texture.flops()
        if self.warp_h is not None:
            total += self.warp_h.flops() + self.warp_d.flops()
        total += 2 * 3 + 30 + 2 * 20  # half vector, rotation into the half frame, two disk-polar conversions
        if not c.homogeneous:
            if c.gating:
                total += 2 * (c.half_channels + c.diff_channels) * c.spatial_channels  # matrix products
            if self.frame is not None:
                total += self.frame.flops()
        return total
