"""GGX baseline fitted by optimisation: a Lambertian diffuse lobe plus a GGX microfacet lobe with
Schlick Fresnel (Walter et al. 2007; the "GGX" row of NeuBRDF's Table 3).

    f(wi, wo) = diffuse / pi + D(h) G1(wi) G1(wo) F_schlick(wi . h; specular) / (4 cos_i cos_o)

Parameters are stored unconstrained and mapped to valid values: diffuse and specular (the Schlick F0)
RGB in (0, 1) by a sigmoid, alpha in (alpha_min, alpha_max) by a scaled sigmoid; one alpha
(isotropic) or alpha_x, alpha_y (anisotropic, aligned with the tangent frame). The model samples:
a one-sample mixture of cosine-weighted hemisphere sampling and GGX visible-normal sampling (Heitz
2018) reflected about the micro-normal, with lobe weight from the diffuse / specular albedo ratio.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from types import SimpleNamespace

import torch
from torch import nn

from neumat.core.checks import check_shape
from neumat.core.config import resolve_config
from neumat.core.errors import InputError
from neumat.core.material import sample_weight, upper_hemisphere
from neumat.core.query import Query, Sample
from neumat.core.tensors import by_rows
from neumat.models.base import LearnedMaterial
from neumat.nn import cpu_kernels
from neumat.nn.codebook import float_bits, storage_bytes
from neumat.warp.ggx import ggx_reflection_pdf, sample_ggx_reflection
from neumat.warp.hemisphere import cosine_hemisphere_pdf, sample_cosine_hemisphere

#: hand count of floating-point operations of one isotropic evaluation, by term (see `GGXFit.flops`)
FLOPS_ISOTROPIC = {
    "half vector (add, normalise)": 12,
    "wi . h": 5,
    "D(h)": 8,
    "G1(wi), G1(wo)": 16,
    "Schlick Fresnel (RGB)": 13,
    "D G F / (4 cos_i cos_o)": 8,
    "diffuse / pi + specular": 6,
}
#: extra operations of the anisotropic D (+4) and the two anisotropic G1 (+3 each)
FLOPS_ANISOTROPIC_EXTRA = 10


@dataclass
class Config:
    """GGX baseline fit settings."""

    anisotropic: bool = False
    """Fit alpha_x and alpha_y separately (tangent-aligned anisotropy) instead of one alpha."""
    alpha_min: float = 1e-3
    """Smallest reachable GGX alpha (keeps D finite)."""
    alpha_max: float = 1.0
    """Largest reachable GGX alpha."""
    init_diffuse: float = 0.25
    """Initial diffuse albedo (all channels)."""
    init_specular: float = 0.2
    """Initial Schlick F0 (all channels)."""
    init_alpha: float = 0.3
    """Initial GGX alpha."""
    min_lobe_probability: float = 0.05
    """Lower bound of each lobe's selection probability when sampling (keeps both lobes covered)."""


def _check_config(c: Config) -> None:
    if not isinstance(c.anisotropic, bool):
        raise InputError(f"GGXFit.anisotropic: expected true/false, got {c.anisotropic!r}")
    if not 0 < c.alpha_min < c.alpha_max:
        raise InputError(f"GGXFit.alpha_min/alpha_max: expected 0 < alpha_min < alpha_max, got "
                         f"{c.alpha_min!r}, {c.alpha_max!r}")
    if not c.alpha_min < c.init_alpha < c.alpha_max:
        raise InputError(f"GGXFit.init_alpha: expected a value in ({c.alpha_min}, {c.alpha_max}), got {c.init_alpha!r}")
    for name in ("init_diffuse", "init_specular"):
        v = getattr(c, name)
        if not 0 < v < 1:
            raise InputError(f"GGXFit.{name}: expected a value in (0, 1), got {v!r}")
    if not 0 < c.min_lobe_probability <= 0.5:
        raise InputError(f"GGXFit.min_lobe_probability: expected a value in (0, 0.5], got {c.min_lobe_probability!r}")


def _logit(p: float) -> float:
    return math.log(p / (1 - p))


def _ggx_eval(wi: torch.Tensor, wo: torch.Tensor, diffuse_pi: torch.Tensor, f0: torch.Tensor,
              one_minus_f0: torch.Tensor, a2: torch.Tensor, inv_a2: torch.Tensor, pi_ax_ay: torch.Tensor,
              zero: torch.Tensor) -> torch.Tensor:
    """diffuse / pi + D(h) G1(wi) G1(wo) F(wi . h) / (4 cos_i cos_o) (N, 3), 0 unless both directions are up:
    `microfacet_brdf` with Schlick Fresnel in few tensor operations, so that a small batch costs little more than
    their dispatch. G1(w) / (2 cos) = 1 / (w_z + sqrt(ax^2 x^2 + ay^2 y^2 + z^2)) for both directions at once (wi, wo
    stacked; the squares weighted by one product with the column a2 = (ax^2, ay^2, 1) (3, 1)), which cancels the
    4 cos_i cos_o; scalars per query are (N, 1) columns."""
    w = torch.stack((wi, wo))                                   # (2, N, 3)
    z = w[..., 2:]                                              # (2, N, 1)
    # with max(w_z, 0) the factors are >= min(alpha) > 0 below the horizon too (masked there): no 1 / 0 in gradients
    g1_den = (z.clamp(min=0) + torch.matmul(w * w, a2).sqrt_()).prod(0)
    h = wi + wo
    h = h / torch.linalg.vector_norm(h, dim=-1, keepdim=True).clamp(min=1e-12)
    # D(h) G1 G1 / (4 cos_i cos_o) = 1 / (pi ax ay q^2 g1_den), q = x^2 / ax^2 + y^2 / ay^2 + z^2 of h
    s = torch.matmul(h * h, inv_a2).square_().mul_(pi_ax_ay).mul_(g1_den).reciprocal_()
    fw = torch.sub(1, (wi * h).sum(-1, keepdim=True).clamp_(0, 1)).pow_(5)  # Schlick weight (1 - cos)^5
    f = torch.addcmul(f0, one_minus_f0, fw).mul_(s).add_(diffuse_pi)
    return torch.where(z.amin(0) > zero, f, zero)


class GGXFit(LearnedMaterial):
    """Diffuse + GGX (Schlick) reflectance with learnable parameters (see module docstring)."""

    name = "ggx"
    paper = "fitted GGX microfacet BRDF (Walter et al. 2007): baseline of NeuBRDF and NBRDF"
    source_kinds = ("brdf",)
    can_sample = True
    Config = Config

    def __init__(self, config: Config | None = None, **kwargs) -> None:
        nn.Module.__init__(self)
        cfg = resolve_config(Config, config, kwargs, 'GGXFit')
        _check_config(cfg)
        self.cfg = cfg
        a = (cfg.init_alpha - cfg.alpha_min) / (cfg.alpha_max - cfg.alpha_min)
        self.raw_diffuse = nn.Parameter(torch.full((3,), _logit(cfg.init_diffuse)))
        self.raw_specular = nn.Parameter(torch.full((3,), _logit(cfg.init_specular)))
        self.raw_alpha = nn.Parameter(torch.full((2 if cfg.anisotropic else 1,), _logit(a)))

    @property
    def config(self) -> Config:
        return self.cfg

    # ------------------------------------------------------------------------------- parameters

    @property
    def diffuse(self) -> torch.Tensor:
        """Diffuse albedo (3,) in (0, 1)."""
        return torch.sigmoid(self.raw_diffuse)

    @property
    def specular(self) -> torch.Tensor:
        """Schlick F0 (3,) in (0, 1)."""
        return torch.sigmoid(self.raw_specular)

    @property
    def alpha(self) -> torch.Tensor:
        """(alpha_x, alpha_y) (2,) in (alpha_min, alpha_max); equal when isotropic."""
        c = self.cfg
        a = c.alpha_min + (c.alpha_max - c.alpha_min) * torch.sigmoid(self.raw_alpha)
        return a.expand(2)

    def describe(self) -> str:
        d, s, a = (t.detach().cpu().tolist() for t in (self.diffuse, self.specular, self.alpha))
        fmt = lambda v: "/".join(f"{x:.3g}" for x in v)  # noqa: E731
        return f"ggx: diffuse={fmt(d)}, specular={fmt(s)}, alpha={fmt(a)}"

    # ------------------------------------------------------------------------------------- eval

    def _alphas(self, n: int, dtype: torch.dtype) -> tuple[torch.Tensor, torch.Tensor]:
        a = self.alpha.to(dtype)
        return a[0].expand(n), a[1].expand(n)

    def _eval_constants(self, dtype: torch.dtype) -> tuple[torch.Tensor, ...]:
        """(diffuse / pi (3,), F0 (3,), 1 - F0 (3,), (ax^2, ay^2, 1) (3, 1), (1 / ax^2, 1 / ay^2, 1) (3, 1),
        pi ax ay (), 0 ()) of the current parameters. Without autograd they are cached until a parameter changes
        (in-place updates bump its version, `.to` replaces its storage): eval then costs no parameter maps."""
        params = (self.raw_diffuse, self.raw_specular, self.raw_alpha)
        key = (dtype, *((p.data_ptr(), p._version) for p in params))
        cached = getattr(self, "_constants", None)
        if cached is not None and cached[0] == key and not torch.is_grad_enabled():
            return cached[1]
        f0 = self.specular.to(dtype)
        a = self.alpha.to(dtype)
        a2 = torch.cat([a * a, torch.ones(1, dtype=dtype, device=a.device)]).unsqueeze(-1)
        out = (self.diffuse.to(dtype) / math.pi, f0, 1 - f0, a2, 1 / a2, math.pi * a[0] * a[1],
               torch.zeros((), dtype=dtype, device=a.device))
        if not torch.is_grad_enabled():
            self._constants = (key, out)
        return out

    #: rows per slice of eval (`by_rows`): its element-wise chain is short, so larger slices than the default pay
    eval_chunk = 2 ** 14

    def eval(self, q: Query, chunk: int | None = None) -> torch.Tensor:
        """BRDF value (N, 3), linear RGB, cosine excluded; 0 below the horizon. Without autograd in float32 on the
        CPU one fused C call (`neumat.nn.cpu_kernels.ggx_eval`, the analytic GGX's with the diffuse term); else on
        slices of `chunk` queries (default `eval_chunk`), whose temporaries stay in cache."""
        q.require("wo", who="GGXFit.eval")
        dtype = self.raw_alpha.dtype
        if cpu_kernels.usable(q.wi, q.wo, self.raw_alpha, self.raw_specular, self.raw_diffuse):  # as below in float32
            k = cpu_kernels.prepared(self, lambda: SimpleNamespace(
                alpha=self.alpha.tolist(), f0=self.specular.tolist(), diffuse_pi=(self.diffuse / math.pi).tolist()))
            return cpu_kernels.ggx_eval(q.wi, q.wo, *k.alpha, "schlick", f0=k.f0, diffuse_pi=k.diffuse_pi)
        consts = self._eval_constants(dtype)
        f = by_rows(lambda wi, wo: _ggx_eval(wi, wo, *consts), chunk or self.eval_chunk, q.wi.to(dtype),
                    q.wo.to(dtype))
        return f.to(q.dtype)

    def forward(self, q: Query) -> torch.Tensor:
        return self.eval(q)

    # --------------------------------------------------------------------------------- sampling

    def diffuse_probability(self) -> torch.Tensor:
        """Probability () of sampling the diffuse lobe: mean diffuse / (mean diffuse + mean F0), clamped to
        [p_min, 1 - p_min] with p_min = `min_lobe_probability`."""
        d, s = self.diffuse.mean(), self.specular.mean()
        p = self.cfg.min_lobe_probability
        return (d / (d + s)).clamp(p, 1 - p)

    @torch.no_grad()
    def pdf(self, q: Query) -> torch.Tensor:
        """Solid-angle density (N,) of `sample` at q.wo: p_d cos_o / pi + (1 - p_d) G1(wi) D(h) / (4 cos_i)."""
        q.require("wo", who="GGXFit.pdf")
        dtype = self.raw_alpha.dtype
        return self._mixture_pdf(q.wi.to(dtype), q.wo.to(dtype)).to(q.dtype)

    def _mixture_pdf(self, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        ax, ay = self._alphas(wi.shape[0], wi.dtype)
        p_d = self.diffuse_probability().to(wi.dtype)
        pdf = p_d * cosine_hemisphere_pdf(wo) + (1 - p_d) * ggx_reflection_pdf(wi, wo, ax, ay)
        return torch.where(upper_hemisphere(wi, wo), pdf, torch.zeros_like(pdf))

    @torch.no_grad()
    def sample(self, q: Query, u: torch.Tensor) -> Sample:
        """Sample wo given q.wi and u (N, 2) in [0, 1): u[:, 0] picks the lobe and is rescaled for reuse."""
        n = q.wi.shape[0]
        check_shape(u, "GGXFit.sample u", (n, 2))
        dtype = self.raw_alpha.dtype
        wi, u = q.wi.to(dtype), u.to(dtype)
        normal = torch.tensor([0.0, 0.0, 1.0], dtype=dtype, device=wi.device)
        wi = torch.where((wi[:, 2] > 0).unsqueeze(-1), wi, normal)  # failed below the horizon (pdf 0 there)
        p_d = self.diffuse_probability().to(dtype)
        diffuse = u[:, 0] < p_d
        u0 = torch.where(diffuse, u[:, 0] / p_d, (u[:, 0] - p_d) / (1 - p_d)).clamp(0, 1 - 1e-7)
        uu = torch.stack([u0, u[:, 1]], -1)
        ax, ay = self._alphas(n, dtype)
        wo = torch.where(diffuse.unsqueeze(-1), sample_cosine_hemisphere(uu), sample_ggx_reflection(wi, uu, ax, ay))
        wo = wo / wo.norm(dim=-1, keepdim=True)
        ok = (q.wi[:, 2] > 0) & (wo[:, 2] > 0)
        pdf = torch.where(ok, self._mixture_pdf(wi, wo), torch.zeros_like(u0))
        weight = sample_weight(self.eval(Query.trusted(wi, wo)), wo, pdf, ok)
        return Sample(wo.to(q.dtype), pdf.to(q.dtype), weight.to(q.dtype))

    # ---------------------------------------------------------------------------------- storage

    def size_bytes(self, precision: str = "fp16") -> int:
        """diffuse (3) + specular (3) + alpha (1 or 2) floats at `precision`."""
        return storage_bytes((6 + self.raw_alpha.numel()) * float_bits(precision))

    def flops(self) -> int:
        """Hand count of floating-point operations per evaluation (`FLOPS_ISOTROPIC`, 68; anisotropic + 10)."""
        return sum(FLOPS_ISOTROPIC.values()) + (FLOPS_ANISOTROPIC_EXTRA if self.cfg.anisotropic else 0)
