"""NeuMIP on UV textures (Kuznetsov et al. 2021): the texture-space baseline NeuPreSS compares a whole translucent
object against (TG et al., Sec. 5, Table 2: "To enable a fair comparison with NeuMIP, we render textures in UV space
to train the networks").

S_hat = max(MLP([z(uv(x)), wi', wo']), 0) over a latent texture in the object's spherical UV space;
"surface-brdf-uv" reads the same network as a surface BRDF (the stand-in for NeRFactor).

Details: src/neumat/methods/neupress/NOTES.md, section `neumat.methods.baselines.neumip_uv`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from types import SimpleNamespace

import torch
from torch import nn

from neumat.core.checks import check_int
from neumat.core.config import resolve_config
from neumat.core.errors import InputError
from neumat.core.frames import frame_from_normal_tangent, to_local
from neumat.core.query import Query
from neumat.core.tensors import by_rows
from neumat.models.base import LearnedMaterial
from neumat.nn import cpu_kernels
from neumat.nn.codebook import float_bits, storage_bytes
from neumat.nn.latent_texture import LatentPyramid
from neumat.nn.mlp import MLP


@dataclass
class Config:
    """NeuMIP-UV sizes."""

    spatial_size: int = 128
    """Latent texture texels a side (a power of two)."""
    spatial_channels: int = 8
    """Latent channels (NeuMIP: 8)."""
    hidden: int = 64
    """Neurons per hidden layer."""
    hidden_layers: int = 4
    """Hidden ReLU layers."""
    init_std: float = 0.1
    """Standard deviation of the initial latents."""
    surface: bool = False
    """A surface BRDF instead of transport: softplus(MLP) times max(wi'_z, 0), so nothing reaches x from behind
    its tangent plane (the registered "surface-brdf-uv" sets it; module docstring)."""


def _check_config(c: Config) -> None:
    for name in ("spatial_channels", "hidden", "hidden_layers"):
        check_int(getattr(c, name), f"NeuMIPUV.{name}")
    if not c.init_std > 0:
        raise InputError(f"NeuMIPUV.init_std: expected > 0, got {c.init_std!r}")


def sphere_uv(p: torch.Tensor) -> torch.Tensor:
    """uv (N, 2) in [0, 1] of points p (N, 3) relative to a centre: the spherical projection of the docstring."""
    r = p.norm(dim=-1).clamp(min=1e-12)
    u = torch.atan2(p[:, 1], p[:, 0]) / (2 * math.pi) + 0.5
    v = torch.acos((p[:, 2] / r).clamp(-1, 1)) / math.pi
    return torch.stack([u, v], -1)


def local_frame(p: torch.Tensor, n: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(t, b, n) at points p relative to the centre with unit normals n (N, 3): t along +phi (-y, x, 0), or +x
    at the poles, made orthogonal to n."""
    t = torch.stack([-p[:, 1], p[:, 0], torch.zeros_like(p[:, 0])], -1)
    pole = t.norm(dim=-1) < 1e-6 * p.norm(dim=-1).clamp(min=1e-12)
    t = torch.where(pole.unsqueeze(-1), torch.tensor([1.0, 0.0, 0.0], dtype=p.dtype, device=p.device), t)
    t, b = frame_from_normal_tangent(n, t)
    return t, b, n


class NeuMIPUV(LearnedMaterial):
    """S_hat(wi; x, wo) from a UV latent texture and an MLP (see the module docstring)."""

    name = "neumip-uv"
    paper = "NeuMIP on the object's UV textures: baseline of NeuPreSS (TG et al.)"
    source_kinds = ("translucent",)
    full_sphere = True
    can_sample = False
    Config = Config

    def __init__(self, config: Config | None = None, **kwargs) -> None:
        nn.Module.__init__(self)
        self.cfg = resolve_config(type(self).Config, config, kwargs, type(self).__name__)
        _check_config(self.cfg)
        c = self.cfg
        self.spatial = LatentPyramid(c.spatial_channels, c.spatial_size, init_std=c.init_std)
        self.mlp = MLP(c.spatial_channels + 6, c.hidden, c.hidden_layers, 3, activation="relu")
        self.register_buffer("centre", torch.zeros(3))

    @property
    def config(self) -> Config:
        return self.cfg

    def set_bounds(self, lo: torch.Tensor, hi: torch.Tensor) -> None:
        """The object's bounding box (3,), (3,): the projection centre is its middle."""
        if lo.shape != (3,) or hi.shape != (3,) or not bool((hi >= lo).all()):
            raise InputError(f"NeuMIPUV.set_bounds: expected lo <= hi of shape (3,), got {tuple(lo.shape)}, "
                             f"{tuple(hi.shape)}")
        with torch.no_grad():
            self.centre.copy_((lo + hi) / 2)

    def raw(self, wi: torch.Tensor, x: torch.Tensor, wo: torch.Tensor, n: torch.Tensor) -> torch.Tensor:
        """The unclamped output (N, 3) for object-space wi, x, wo and the unit normal n at x (what fitting sees)."""
        p = x - self.centre
        frame = local_frame(p, n)
        z = self.spatial(sphere_uv(p))
        local_wi = to_local(wi, *frame)
        out = self.mlp(torch.cat([z, local_wi, to_local(wo, *frame)], -1))
        if self.cfg.surface:
            return torch.nn.functional.softplus(out) * local_wi[:, 2:].clamp(min=0)
        return out

    def eval(self, q: Query) -> torch.Tensor:
        """S_hat (N, 3), clamped at 0."""
        q.require("x", "wo", "n", who="NeuMIPUV.eval")
        if cpu_kernels.usable(q.wi, q.x, q.wo, q.n, self.spatial.raw[0], owner=self):
            k = cpu_kernels.prepared(self, self._kernel_bundle)
            if k is not None:  # the same values within float32 rounding
                return cpu_kernels.neumip_uv_eval(k.mlp, k.tables, q.wi, q.x, q.wo, q.n, self.centre, self.cfg.surface)
        return by_rows(self._eval_rows, self.eval_chunk, q)

    def _kernel_bundle(self) -> SimpleNamespace | None:
        """What the fused kernel (`cpu_kernels.neumip_uv_eval`) reads: the MLP packed and the latent pyramid's
        tables; None where the kernel lacks the sizes or the activation."""
        mlp = cpu_kernels.PackedMLP.pack(self.mlp.net)
        if mlp is None or not cpu_kernels.neumip_fits(self.cfg.spatial_channels, 0):
            return None
        return SimpleNamespace(mlp=mlp, tables=cpu_kernels.PyramidTables(self.spatial))

    def _eval_rows(self, q: Query) -> torch.Tensor:
        dtype = self.centre.dtype
        return self.raw(q.wi.to(dtype), q.x.to(dtype), q.wo.to(dtype), q.n.to(dtype)).clamp(min=0).to(q.dtype)

    def forward(self, q: Query) -> torch.Tensor:
        return self.eval(q)

    def size_bytes(self, precision: str = "fp16") -> int:
        """The latent pyramid and the MLP."""
        return storage_bytes(sum(p.numel() for p in self.parameters()) * float_bits(precision))

    def flops(self) -> int:
        """Per query: the MLP's multiply-adds (2 per weight) and a bilinear lookup (4 taps per channel)."""
        weights = sum(layer.weight.numel() for layer in self.mlp.linears())
        return 2 * weights + 8 * self.cfg.spatial_channels


@dataclass
class SurfaceConfig(Config):
    """NeuMIP-UV sizes, read as a surface BRDF."""

    surface: bool = True


class SurfaceBRDFUV(NeuMIPUV):
    """softplus(MLP([z(uv(x)), wi', wo'])) max(wi'_z, 0): the surface-reflectance baseline (module docstring)."""

    name = "surface-brdf-uv"
    paper = "surface BRDF on UV textures (stand-in for NeRFactor): baseline of NeuPreSS (TG et al.)"
    source_kinds = ("translucent",)
    Config = SurfaceConfig
