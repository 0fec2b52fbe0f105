"""Neural importance sampling for any (homogeneous) BRDF: the importance-sampling decoder of Real-Time Neural
Appearance Models (Zeltner et al. 2024, Sec. 4.3, 5.2), a small MLP that maps the incident direction to the 9
parameters of the analytic two-lobe proxy (`neumat.warp.microfacet_proxy`), sampled and evaluated in closed
form, so density and sampler agree exactly.

- `ProxySampler`: MLP wi (N, 3) -> raw (N, 9) -> `ProxyLobes`; starts at w_d = 0.5, alpha = 0.5, no tilt.
- `fit_sampler(material, sampler)`: trains it against the material's f cos(theta_o) as the paper trains its
  sampler against the learned BRDF: directions drawn from the current proxy are scored with the KL divergence
  KL(f cos / a || p), through its score-function gradient -E_p[(f cos / p) grad log p] (Mueller et al. 2019);
  f is the luminance of the material's value and wi uniform over the upper hemisphere. One sample per wi, so
  the per-wi normaliser a(wi) is replaced by the batch mean of f cos / p: directions wi with a higher albedo
  weigh more.
- `SampledMaterial(material, sampler)`: the material with the sampler attached (`can_sample = True`): eval is
  the material's, `sample` / `pdf` the proxy's, weight = f cos / p.

The paper also feeds the latent code z(x) of its spatially varying model; here only wi is an input, so
spatially varying materials are refused.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import torch
from torch import nn

from neumat.core.config import resolve_config
from neumat.core.errors import InputError
from neumat.core.material import Material, sample_weight
from neumat.core.query import Query, Sample
from neumat.metrics.tonemap import LUMINANCE
from neumat.nn.mlp import MLP
from neumat.warp.hemisphere import sample_uniform_hemisphere
from neumat.warp.microfacet_proxy import ProxyLobes, proxy_from_raw, proxy_pdf, sample_proxy


@dataclass
class Config:
    """Sizes of the sampling decoder (the paper does not state its sampler's; ours: 2 x 32, ReLU)."""

    hidden: int = 32
    """Neurons per hidden layer."""
    hidden_layers: int = 2
    """Hidden layers."""


class ProxySampler(nn.Module):
    """MLP from wi (N, 3) (local frame) to the two-lobe proxy's parameters."""

    def __init__(self, config: Config | None = None, **kwargs) -> None:
        super().__init__()
        self.cfg = resolve_config(Config, config, kwargs, "ProxySampler")
        self.mlp = MLP(3, self.cfg.hidden, self.cfg.hidden_layers, 9)
        self.mlp.start_constant(torch.zeros(9))

    def lobes(self, wi: torch.Tensor) -> ProxyLobes:
        dtype = self.mlp.linears()[0].weight.dtype
        lobes = proxy_from_raw(self.mlp(wi.to(dtype)))
        return ProxyLobes(*(t.to(wi.dtype) for t in lobes))

    def sample(self, wi: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """wo (N, 3) for wi (N, 3) and u (N, 2) in [0, 1)^2."""
        return sample_proxy(self.lobes(wi), wi, u)

    def pdf(self, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        """Solid-angle density (N,) of `sample`."""
        return proxy_pdf(self.lobes(wi), wi, wo)

    def flops(self) -> int:
        """MLP operations per query (activations and the proxy's closed forms not counted)."""
        return self.mlp.flops()


class SampledMaterial(Material):
    """`material` with `sampler` for importance sampling (module docstring)."""

    can_sample = True

    def __init__(self, material: Material, sampler: ProxySampler) -> None:
        _check_homogeneous(material, "SampledMaterial")
        self.material, self.sampler = material, sampler
        self.name = f"{getattr(material, 'name', 'material')}+proxy-sampler"

    def eval(self, q: Query) -> torch.Tensor:
        return self.material.eval(q)

    @torch.no_grad()
    def sample(self, q: Query, u: torch.Tensor) -> Sample:
        if not isinstance(u, torch.Tensor) or u.shape != (len(q), 2):
            raise InputError(f"u: expected a tensor of shape ({len(q)}, 2), got {getattr(u, 'shape', type(u))}")
        lobes = self.sampler.lobes(q.wi)
        wo = sample_proxy(lobes, q.wi, u.to(q.wi.dtype))
        wo = wo / wo.norm(dim=-1, keepdim=True)
        pdf = proxy_pdf(lobes, q.wi, wo)
        f = self.material.eval(q.with_wo(wo))
        return Sample(wo, pdf, sample_weight(f, wo, pdf, pdf > 0))

    @torch.no_grad()
    def pdf(self, q: Query) -> torch.Tensor:
        q.require("wo", who="SampledMaterial.pdf")
        return self.sampler.pdf(q.wi, q.wo)

    def describe(self) -> str:
        return f"{self.material.describe()} + proxy sampler"


@dataclass
class SamplerFit:
    """sampler: the trained sampler (eval mode); history: {"step", "loss"} every `log_every` steps;
    seconds: training time."""

    sampler: ProxySampler
    history: list[dict]
    seconds: float


def _check_homogeneous(material, who: str) -> None:
    if not callable(getattr(material, "eval", None)):
        raise InputError(f"{who}: expected a Material, got {type(material).__name__}")
    if getattr(material, "spatially_varying", False) or getattr(material, "full_sphere", False):
        raise InputError(f"{who}: {type(material).__name__} is spatially varying or translucent; the proxy sampler "
                         "conditions on wi only (homogeneous BRDFs)")


def fit_sampler(material: Material, sampler: ProxySampler | None = None, steps: int = 2000, batch: int = 4096,
                lr: float = 3e-3, seed: int = 0, log_every: int = 100, progress: bool = True) -> SamplerFit:
    """Train `sampler` (default a new `ProxySampler()`) on `material` (module docstring): `steps` Adam steps
    of `batch` (wi, wo) pairs, learning rate `lr` halved at 50% and 75% of the steps."""
    _check_homogeneous(material, "fit_sampler")
    for name, v in (("steps", steps), ("batch", batch), ("log_every", log_every)):
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            raise InputError(f"fit_sampler {name}: expected an integer >= 1, got {v!r}")
    if not lr > 0:
        raise InputError(f"fit_sampler lr: expected > 0, got {lr!r}")
    sampler = sampler if sampler is not None else ProxySampler()
    sampler.train()
    gen = torch.Generator().manual_seed(seed)
    opt = torch.optim.Adam(sampler.parameters(), lr=lr)
    sched = torch.optim.lr_scheduler.MultiStepLR(opt, [steps // 2, 3 * steps // 4], gamma=0.5)
    lum = torch.tensor(LUMINANCE)
    history, running, start = [], 0.0, time.perf_counter()
    iterator = range(steps)
    if progress:
        from rich.progress import track
        iterator = track(iterator, description="fitting the proxy sampler")
    for step in iterator:
        u = torch.rand(batch, 4, generator=gen)
        wi = sample_uniform_hemisphere(u[:, :2])
        lobes = sampler.lobes(wi)
        with torch.no_grad():
            wo = sample_proxy(ProxyLobes(*(t.detach() for t in lobes)), wi, u[:, 2:])
            wo = wo / wo.norm(dim=-1, keepdim=True)
            target = (material.eval(Query(wi, wo)).float() @ lum).clamp(min=0) * wo[:, 2].clamp(min=0)
            if not bool(torch.isfinite(target).all()):
                raise InputError(f"fit_sampler: {material.describe()} returned non-finite values")
        pdf = proxy_pdf(lobes, wi, wo)
        ratio = target / pdf.detach().clamp(min=1e-12)
        loss = -(ratio * pdf.clamp(min=1e-12).log()).mean() / ratio.mean().clamp(min=1e-12)
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        running += loss.item()
        if (step + 1) % log_every == 0 or step + 1 == steps:
            history.append({"step": step + 1, "loss": running / ((step % log_every) + 1)})
            running = 0.0
    sampler.eval()
    return SamplerFit(sampler, history, time.perf_counter() - start)
