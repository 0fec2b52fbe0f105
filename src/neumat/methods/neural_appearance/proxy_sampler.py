"""Neural importance sampling for any BRDF: the importance-sampling decoder of Real-Time Neural Appearance
Models (Zeltner et al. 2024, Sec. 4.3, 5.2), a small MLP that maps the incident direction (and, on spatially
varying materials, a per-point feature vector) to the 9 parameters of the analytic two-lobe proxy
(`neumat.warp.microfacet_proxy`), sampled and evaluated in closed form, so density and sampler agree exactly.

`ProxySampler` is the decoder; `SampledMaterial(material, sampler)` attaches it to a material, mixed with a
defensive cosine share (why: it bounds every weight f cos / p).

Details: src/neumat/methods/neural_appearance/NOTES.md, section `neumat.methods.neural_appearance.proxy_sampler`.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import torch
from torch import nn

from neumat.core.checks import check_int
from neumat.core.config import resolve_config
from neumat.core.errors import InputError
from neumat.core.material import Material, check_sample_u, material_device, sample_weight
from neumat.core.query import Query, Sample
from neumat.models.base import LearnedMaterial
from neumat.nn.mlp import MLP
from neumat.warp.hemisphere import cosine_hemisphere_pdf, sample_cosine_hemisphere
from neumat.warp.microfacet_proxy import ProxyLobes, proxy_from_raw, proxy_pdf, sample_proxy

#: raw outputs of the sampler MLP per lobe family (Config.lobes): the paper's elliptical, non-centred GGX and tilted
#: cosine lobe (9), and the ablation's centred isotropic GGX and untilted cosine lobe (2: w_d, alpha)
LOBE_OUTPUTS = {"anisotropic": 9, "isotropic": 2}

#: probability of drawing a cosine-weighted direction instead of the proxy's (defensive mixture)
DEFENSIVE = 0.05


def sample_defensive(lobes: ProxyLobes, wi: torch.Tensor, u: torch.Tensor, check: bool = True) -> torch.Tensor:
    """wo (N, 3) from (1 - DEFENSIVE) proxy + DEFENSIVE cosine; u (N, 2), u_x picks and is rescaled; check as
    in `sample_proxy`."""
    cosine = u[:, 0] < DEFENSIVE
    u0 = torch.where(cosine, u[:, 0] / DEFENSIVE, (u[:, 0] - DEFENSIVE) / (1 - DEFENSIVE)).clamp(0, 1 - 1e-7)
    v = torch.stack([u0, u[:, 1]], -1)
    wo = torch.where(cosine[:, None], sample_cosine_hemisphere(v), sample_proxy(lobes, wi, v, check))
    return wo / wo.norm(dim=-1, keepdim=True)


def defensive_pdf(lobes: ProxyLobes, wi: torch.Tensor, wo: torch.Tensor, check: bool = True) -> torch.Tensor:
    """Solid-angle density (N,) of `sample_defensive`; check as in `sample_proxy`."""
    return (1 - DEFENSIVE) * proxy_pdf(lobes, wi, wo, check) + DEFENSIVE * cosine_hemisphere_pdf(wo)


def draw_sample(lobes: ProxyLobes, q: Query, u: torch.Tensor, brdf: Callable[[torch.Tensor], torch.Tensor]) -> Sample:
    """`Material.sample` with the lobes of q (from `proxy_from_raw`): wo from `sample_defensive`, its density and
    the weight brdf(wo) cos / pdf, brdf(wo) (N, 3) the material's value at q with those wo. Only u is checked:
    q's directions and the lobes are valid already."""
    u = check_sample_u(q, u)  # in [0, 1) (so finite), in the query's dtype and device
    wo = sample_defensive(lobes, q.wi, u, check=False)
    pdf = defensive_pdf(lobes, q.wi, wo, check=False)
    return Sample(wo, pdf, sample_weight(brdf(wo), wo, pdf, pdf > 0))


@dataclass
class Config:
    """Sizes of the sampling decoder: the paper's 3 hidden layers of 32 (its Tables 4-5); ReLU (not stated)."""

    features: int = 0
    """F, per-point features of a spatially varying material (0 for homogeneous BRDFs)."""
    hidden: int = 32
    """Neurons per hidden layer."""
    hidden_layers: int = 3
    """Hidden layers."""
    lobes: str = "anisotropic"
    """The lobe family (`LOBE_OUTPUTS`): "anisotropic" (the paper's 9 parameters) or "isotropic" (its ablation:
    diffuse weight and one roughness; centred GGX, untilted cosine lobe)."""


def check_lobe_family(value, name: str) -> None:
    """InputError naming `name` unless value is a key of `LOBE_OUTPUTS`."""
    if not isinstance(value, str) or value not in LOBE_OUTPUTS:
        raise InputError(f"{name}: expected one of {', '.join(map(repr, LOBE_OUTPUTS))}, got {value!r}")


def isotropic_raw(raw: torch.Tensor) -> torch.Tensor:
    """The 9 raw proxy parameters (N, 9) of `proxy_from_raw` from the isotropic sampler's (N, 2) [w_d logit,
    alpha]: w_s logit, tilt, mean slopes and rho 0 (centred, untilted, uncorrelated), alpha_x = alpha_y."""
    padded = torch.cat([raw, raw.new_zeros(len(raw), 1)], -1)
    return padded[:, [0, 2, 2, 2, 1, 1, 2, 2, 2]]


class ProxySampler(nn.Module):
    """MLP from wi (N, 3) (local frame) and features (N, F) to the two-lobe proxy's parameters."""

    def __init__(self, config: Config | None = None, **kwargs) -> None:
        super().__init__()
        self.cfg = resolve_config(Config, config, kwargs, "ProxySampler")
        check_int(self.cfg.features, "ProxySampler features", 0)
        check_lobe_family(self.cfg.lobes, "ProxySampler lobes")
        outputs = LOBE_OUTPUTS[self.cfg.lobes]
        self.mlp = MLP(3 + self.cfg.features, self.cfg.hidden, self.cfg.hidden_layers, outputs)
        self.mlp.start_constant(torch.zeros(outputs))

    def lobes(self, wi: torch.Tensor, features: torch.Tensor | None = None) -> ProxyLobes:
        """Proxy parameters for wi (N, 3) and, when the sampler has F > 0 features, features (N, F)."""
        f = self.cfg.features
        got = None if features is None else tuple(features.shape)
        if f == 0 and features is not None:
            raise InputError(f"ProxySampler: this sampler takes no features (F = 0), got features of shape {got}")
        if f > 0 and got != (len(wi), f):
            raise InputError(f"ProxySampler: expected features of shape ({len(wi)}, {f}), got {got}")
        dtype = self.mlp.linears()[0].weight.dtype
        x = wi.to(dtype) if features is None else torch.cat([wi.to(dtype), features.to(dtype)], -1)
        raw = self.mlp(x)
        raw = isotropic_raw(raw) if self.cfg.lobes == "isotropic" else raw
        return ProxyLobes(*(t.to(wi.dtype) for t in proxy_from_raw(raw)))

    def flops(self) -> int:
        """MLP operations per query (activations and the proxy's closed forms not counted)."""
        return self.mlp.flops()


class SampledMaterial(LearnedMaterial):
    """`material` with `sampler` for importance sampling (module docstring). An nn.Module: `to(device)` moves
    the sampler (and the material when it is a module); `train(mode)` switches the sampler alone, the material
    keeps its mode (it is the fixed target of the sampler's fit)."""

    name = "proxy-sampler"
    paper = "Real-Time Neural Appearance Models (Zeltner et al. 2024), Sec. 4.3: the importance-sampling decoder"
    source_kinds = ("brdf", "svbrdf")
    Config = Config
    can_sample = True

    def __init__(self, material: Material, sampler: ProxySampler) -> None:
        super().__init__()
        if feature_dim(material, "SampledMaterial") != sampler.cfg.features:
            raise InputError(f"SampledMaterial: the sampler takes {sampler.cfg.features} features, "
                             f"{type(material).__name__} gives {feature_dim(material, 'SampledMaterial')}")
        self.material, self.sampler = material, sampler
        self.spatially_varying = bool(getattr(material, "spatially_varying", False))

    @property
    def device(self) -> torch.device:
        """Where the material (else the sampler) keeps its tensors: renderers and plugins query there."""
        return material_device(self.material, self.sampler)

    def train(self, mode: bool = True) -> "SampledMaterial":
        self.training = mode
        self.sampler.train(mode)
        return self

    def forward(self, q: Query) -> torch.Tensor:
        return self.eval(q)

    def eval(self, q: Query) -> torch.Tensor:
        return self.material.eval(q)

    def lobes(self, q: Query) -> ProxyLobes:
        return self.sampler.lobes(q.wi, features_of(self.material, q))

    @torch.no_grad()
    def sample(self, q: Query, u: torch.Tensor) -> Sample:
        return draw_sample(self.lobes(q), q, u, lambda wo: self.material.eval(q.with_wo(wo)))

    @torch.no_grad()
    def pdf(self, q: Query) -> torch.Tensor:
        q.require("wo", who="SampledMaterial.pdf")
        return defensive_pdf(self.lobes(q), q.wi, q.wo, check=False)

    def describe(self) -> str:
        return f"{self.material.describe()} + proxy sampler"

    def flops(self) -> int:
        """The sampler's MLP per query (the material's evaluation not counted)."""
        return self.sampler.flops()


def feature_dim(material, who: str) -> int:
    """F of `material`: 0 for a homogeneous BRDF, its `sampling_feature_dim` when spatially varying."""
    if not callable(getattr(material, "eval", None)):
        raise InputError(f"{who}: expected a Material, got {type(material).__name__}")
    if getattr(material, "full_sphere", False):
        raise InputError(f"{who}: {type(material).__name__} is translucent (full sphere); the proxy samples BRDFs")
    if not getattr(material, "spatially_varying", False):
        return 0
    if not callable(getattr(material, "sampling_features", None)):
        raise InputError(f"{who}: {type(material).__name__} is spatially varying but has no sampling_features(q) "
                         "to condition the sampler on")
    return int(material.sampling_feature_dim)


def features_of(material, q: Query) -> torch.Tensor | None:
    """The material's sampling features at q (N, F) without gradient, or None for a homogeneous BRDF."""
    if not getattr(material, "spatially_varying", False):
        return None
    q.require("uv", who=f"{type(material).__name__} sampling features")
    with torch.no_grad():
        return material.sampling_features(q).detach()
