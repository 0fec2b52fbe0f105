"""Analytic reference materials: Lambert, GGX (isotropic / anisotropic, Fresnel choices), Plastic, Principled.

Parameters are floats or RGB triples, validated at construction (InputError names the parameter and its range).
`describe()` returns a spec string that `neumat.reflectance.spec.parse_spec` turns back into the material.
Every material samples wo given wi (cosine, GGX visible-normal reflection, or a mixture), is reciprocal, and
returns 0 unless wi and wo are both above the surface.

Roughness: `GGX` and `Plastic` take the GGX alpha itself (Mitsuba's `alpha`), `Principled` takes perceptual
roughness with alpha = roughness^2 (glTF / Disney).

Details: docs/notes/reflectance.md, section `neumat.reflectance.analytic`.
"""
from __future__ import annotations

import difflib
import math
import numpy as np
import torch

from ..core.errors import InputError, UnknownNameError
from ..core.material import Material, check_sample_u, sample_weight
from ..core.query import Query, Sample
from ..core.tensors import by_rows
from ..nn import cpu_kernels
from ..warp.ggx import ggx_reflection_pdf, sample_ggx_reflection
from ..warp.ggx_distribution import ggx_ndf, smith_g1
from ..warp.hemisphere import sample_cosine_hemisphere
from .microfacet import (_dot, _half_vector, _microfacet_brdf, fresnel_conductor, fresnel_dielectric, fresnel_schlick,
                         principled_eval, principled_pdf, principled_sample)
from .spec_registry import register_spec

#: RGB complex refractive indices (eta, k) of conductors, as Mitsuba 3 (rgb variants) derives them from its spectra
CONDUCTORS: dict[str, tuple[tuple[float, float, float], tuple[float, float, float]]] = {
    "gold": ((0.143036, 0.375307, 1.44205), (3.983, 2.38556, 1.60336)),
    "silver": ((0.155276, 0.116728, 0.138388), (4.82835, 3.12222, 2.1469)),
    "copper": ((0.201005, 0.92375, 1.10222), (3.91326, 2.45305, 2.14209)),
    "aluminium": ((1.6575, 0.880405, 0.521244), (9.22381, 6.2695, 4.837)),
    "chromium": ((4.36967, 2.91651, 1.6549), (5.20655, 4.23131, 3.7547)),
    "tungsten": ((4.37082, 3.30025, 2.99841), (3.50064, 2.60487, 2.27323)),
}
FRESNEL_MODES = ("conductor", "dielectric", "schlick", "none")
#: GGX alpha range accepted by `GGX` and `Plastic`
ALPHA_RANGE = (1e-4, 1.0)

_RGB = tuple[float, float, float]


def _is_number(x) -> bool:
    return isinstance(x, (int, float, np.floating, np.integer)) and not isinstance(x, bool)


def _check_value(v: float, name: str, lo: float, hi: float, lo_open: bool) -> None:
    if not math.isfinite(v) or v > hi or v < lo or (lo_open and v == lo):
        bracket = "(" if lo_open else "["
        raise InputError(f"{name}: expected a value in {bracket}{lo:g}, {hi:g}], got {v!r}")


def scalar_param(value, name: str, lo: float, hi: float, lo_open: bool = False) -> float:
    """A number in [lo, hi] ((lo, hi] with lo_open) as a float; 0-d tensors and arrays are accepted."""
    if isinstance(value, (torch.Tensor, np.ndarray)) and np.prod(value.shape) == 1:
        value = value.item()
    if not _is_number(value):
        raise InputError(f"{name}: expected a number, got {value!r}")
    v = float(value)
    _check_value(v, name, lo, hi, lo_open)
    return v


def rgb_param(value, name: str, lo: float, hi: float, lo_open: bool = False) -> _RGB:
    """A number (grey) or three numbers (linear RGB), each in [lo, hi], as a tuple of 3 floats."""
    if isinstance(value, torch.Tensor):
        value = value.detach().cpu().numpy()
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if _is_number(value):
        value = (value, value, value)
    if not isinstance(value, (list, tuple)) or len(value) != 3 or not all(_is_number(v) for v in value):
        raise InputError(f"{name}: expected a number or an RGB triple of 3 numbers, got {value!r}")
    out = tuple(float(v) for v in value)
    for v in out:
        _check_value(v, name, lo, hi, lo_open)
    return out  # type: ignore[return-value]


def format_value(value) -> str:
    """A parameter as written in spec strings: '0.25', '0.8/0.5/0.2' or a bare name."""
    if isinstance(value, tuple):
        return "/".join(format_value(v) for v in value)
    if isinstance(value, float):
        return repr(value)
    return str(value)


class AnalyticMaterial(Material):
    """Shared plumbing: query checks, sample = draw wo, then the same pdf and eval as `pdf` / `eval`."""

    can_sample = True

    def _eval(self, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    def _draw(self, wi: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    def _pdf(self, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    def spec_params(self) -> dict:
        """Parameters as written in the spec string (name -> float, RGB tuple or name)."""
        raise NotImplementedError

    #: rows per slice of eval, pdf and sample (`by_rows`): the cost per query stays flat up to 2^20 queries
    chunk = 2 ** 14

    def eval(self, q: Query) -> torch.Tensor:
        """BRDF (N, 3), cosine excluded; 0 unless both directions are above the surface."""
        q.require("wo", who=type(self).__name__)
        return by_rows(self._eval, self.chunk, q.wi, q.wo)

    def pdf(self, q: Query) -> torch.Tensor:
        """Solid-angle density (N,) of `sample` at q.wo given q.wi."""
        q.require("wo", who=type(self).__name__)
        return by_rows(self._pdf, self.chunk, q.wi, q.wo)

    def sample(self, q: Query, u: torch.Tensor) -> Sample:
        """Draw wo given q.wi and u (N, 2) in [0, 1)^2; pdf and weight are 0 where sampling failed."""
        u = check_sample_u(q, u)
        return by_rows(self._sample, self.chunk, q.wi, u)

    def _sample(self, wi: torch.Tensor, u: torch.Tensor) -> Sample:
        up = (wi[:, 2] > 0).unsqueeze(-1)
        normal = torch.tensor([0.0, 0.0, 1.0], dtype=wi.dtype, device=wi.device)
        wo = self._draw(torch.where(up, wi, normal), u.to(wi.dtype))
        wo = torch.where(up & torch.isfinite(wo).all(-1, keepdim=True), wo, normal)
        return self._pdf_and_weight(wi, wo)

    def _pdf_and_weight(self, wi: torch.Tensor, wo: torch.Tensor) -> Sample:
        """The Sample of drawn directions wo (N, 3): pdf (N,) and weight eval * cos_o / pdf (N, 3)."""
        pdf = self._pdf(wi, wo)
        return Sample(wo=wo, pdf=pdf, weight=sample_weight(self._eval(wi, wo), wo, pdf, pdf > 0))

    def describe(self) -> str:
        """The spec string of this material."""
        params = ",".join(f"{k}={format_value(v)}" for k, v in self.spec_params().items())
        return f"{self.name}:{params}" if params else self.name

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.describe()!r})"

    @staticmethod
    def _const(value, ref: torch.Tensor) -> torch.Tensor:
        return torch.tensor(value, dtype=ref.dtype, device=ref.device)

    @staticmethod
    def _both_up(wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        return (wi[:, 2] > 0) & (wo[:, 2] > 0)


@register_spec("lambert")
class Lambert(AnalyticMaterial):
    """Ideal diffuse reflector f = albedo / pi; albedo in [0, 1] (number or RGB). Cosine-weighted sampling."""

    name = "lambert"

    def __init__(self, albedo=(0.5, 0.5, 0.5)) -> None:
        self.albedo = rgb_param(albedo, "Lambert albedo", 0.0, 1.0)

    def _eval(self, wi, wo):
        f = (self._const(self.albedo, wi) / math.pi).expand(wi.shape[0], 3)
        return torch.where(self._both_up(wi, wo).unsqueeze(-1), f, torch.zeros_like(f))

    def _draw(self, wi, u):
        return sample_cosine_hemisphere(u)

    def _pdf(self, wi, wo):
        return torch.where(self._both_up(wi, wo), wo[:, 2] / math.pi, torch.zeros_like(wo[:, 2]))

    def spec_params(self) -> dict:
        return {"albedo": self.albedo}


def _alpha_pair(roughness, alpha_x, alpha_y, who: str) -> tuple[float, float]:
    """(alpha_x, alpha_y) from either roughness (isotropic alpha, default 0.3) or both alpha_x and alpha_y."""
    if alpha_x is None and alpha_y is None:
        a = scalar_param(0.3 if roughness is None else roughness, f"{who} roughness", *ALPHA_RANGE)
        return a, a
    if roughness is not None:
        raise InputError(f"{who}: give either roughness or alpha_x/alpha_y, not both")
    if alpha_x is None or alpha_y is None:
        raise InputError(f"{who}: anisotropic roughness needs both alpha_x and alpha_y")
    return scalar_param(alpha_x, f"{who} alpha_x", *ALPHA_RANGE), scalar_param(alpha_y, f"{who} alpha_y", *ALPHA_RANGE)


def _unknown(kind: str, name: str, known) -> UnknownNameError:
    close = difflib.get_close_matches(str(name).lower(), list(known), n=3, cutoff=0.5)
    hint = f"; did you mean {', '.join(close)}?" if close else ""
    return UnknownNameError(f"unknown {kind} {name!r}{hint} (known: {', '.join(known)})")


@register_spec("ggx")
class GGX(AnalyticMaterial):
    """GGX microfacet reflector f = D G1(wi) G1(wo) F(wi.h) / (4 cos_i cos_o), sampled by visible normals.

    roughness:          isotropic GGX alpha in [1e-4, 1] (default 0.3); or alpha_x (tangent) and alpha_y.
    fresnel:            "conductor" (complex IOR eta + i k, RGB; `material` names a preset from CONDUCTORS,
                        default "aluminium"), "dielectric" (eta = n_inside / n_outside, default 1.5),
                        "schlick" (f0 in [0, 1], default 0.04) or "none" (F = 1).
    """

    name = "ggx"

    def __init__(self, roughness=None, *, alpha_x=None, alpha_y=None, fresnel: str = "conductor", eta=None,
                 k=None, f0=None, material: str | None = None) -> None:
        self.alpha_x, self.alpha_y = _alpha_pair(roughness, alpha_x, alpha_y, "GGX")
        self._isotropic = alpha_x is None
        if not isinstance(fresnel, str) or fresnel not in FRESNEL_MODES:
            raise _unknown("GGX fresnel mode", fresnel, FRESNEL_MODES)
        self.fresnel = fresnel
        given = {n for n, v in (("eta", eta), ("k", k), ("f0", f0), ("material", material)) if v is not None}
        allowed = {"conductor": {"eta", "k", "material"}, "dielectric": {"eta"}, "schlick": {"f0"}, "none": set()}
        extra = given - allowed[fresnel]
        if extra:
            raise InputError(f"GGX: parameter(s) {', '.join(sorted(extra))} do not apply to fresnel={fresnel!r} "
                             f"(it takes: {', '.join(sorted(allowed[fresnel])) or 'nothing'})")
        self.material = None
        if fresnel == "conductor":
            if material is not None and ({"eta", "k"} & given):
                raise InputError("GGX: give either material (a conductor preset) or eta and k, not both")
            if material is None and ({"eta", "k"} & given) and not {"eta", "k"} <= given:
                raise InputError("GGX: a conductor needs both eta and k (or a preset material)")
            if material is None and not given:
                material = "aluminium"
            if material is not None:
                if not isinstance(material, str) or material not in CONDUCTORS:
                    raise _unknown("conductor material", material, CONDUCTORS)
                self.material = material
                eta, k = CONDUCTORS[material]
            self.eta = rgb_param(eta, "GGX eta", 0.0, 100.0, lo_open=True)
            self.k = rgb_param(k, "GGX k", 0.0, 100.0)
        elif fresnel == "dielectric":
            self.eta = scalar_param(1.5 if eta is None else eta, "GGX eta", 0.0, 100.0, lo_open=True)
        elif fresnel == "schlick":
            self.f0 = rgb_param(0.04 if f0 is None else f0, "GGX f0", 0.0, 1.0)

    def _fresnel(self, cos: torch.Tensor) -> torch.Tensor:
        if self.fresnel == "conductor":
            return fresnel_conductor(cos, self._const(self.eta, cos), self._const(self.k, cos))
        if self.fresnel == "dielectric":
            return fresnel_dielectric(cos, self.eta).unsqueeze(-1).expand(-1, 3)
        if self.fresnel == "schlick":
            return fresnel_schlick(cos, self._const(self.f0, cos))
        return torch.ones(cos.shape[0], 3, dtype=cos.dtype, device=cos.device)

    def eval(self, q: Query) -> torch.Tensor:
        """BRDF (N, 3), cosine excluded; 0 unless both directions are above the surface. Without autograd, in
        float32 on the CPU, one fused C call (`neumat.nn.cpu_kernels.ggx_eval`; the torch path's values within
        float32 rounding): the torch path is some 40 small tensor operations, 0.2 ms for a call of one query."""
        q.require("wo", who=type(self).__name__)
        if cpu_kernels.usable(q.wi, q.wo):
            rgb = {}
            if self.fresnel == "conductor":
                rgb = {"eta": self.eta, "k": self.k}
            elif self.fresnel == "dielectric":
                rgb = {"eta": (self.eta,) * 3}
            elif self.fresnel == "schlick":
                rgb = {"f0": self.f0}
            return cpu_kernels.ggx_eval(q.wi, q.wo, self.alpha_x, self.alpha_y, self.fresnel, **rgb)
        return super().eval(q)

    def _eval(self, wi, wo):
        return _microfacet_brdf(wi, wo, self.alpha_x, self.alpha_y, self._fresnel)

    def _draw(self, wi, u):
        return sample_ggx_reflection(wi, u, self.alpha_x, self.alpha_y)

    def _pdf(self, wi, wo):
        return self._pdf_at_half_vector(wi, wo, _half_vector(wi, wo))

    def _pdf_at_half_vector(self, wi, wo, h):
        """Visible-normal reflection density G1(wi) D(h) / (4 cos_i) (N,) (as `ggx_reflection_pdf`); 0 unless
        both directions are up."""
        d_vis = smith_g1(wi, self.alpha_x, self.alpha_y) * ggx_ndf(h, self.alpha_x, self.alpha_y)
        pdf = d_vis / (4 * wi[:, 2]).clamp(min=torch.finfo(wi.dtype).tiny)
        return torch.where(self._both_up(wi, wo), pdf, torch.zeros_like(pdf))

    def _pdf_and_weight(self, wi, wo):
        # one half vector for both; weight = f cos_o / pdf simplifies to G1(wo) F(wi.h)
        h = _half_vector(wi, wo)
        pdf = self._pdf_at_half_vector(wi, wo, h)
        weight = self._fresnel(_dot(wi, h)) * smith_g1(wo, self.alpha_x, self.alpha_y).unsqueeze(-1)
        return Sample(wo=wo, pdf=pdf, weight=torch.where((pdf > 0).unsqueeze(-1), weight, torch.zeros_like(weight)))

    def spec_params(self) -> dict:
        p = ({"roughness": self.alpha_x} if self._isotropic else {"alpha_x": self.alpha_x, "alpha_y": self.alpha_y})
        p["fresnel"] = self.fresnel
        if self.material is not None:
            p["material"] = self.material
        elif self.fresnel == "conductor":
            p.update(eta=self.eta, k=self.k)
        elif self.fresnel == "dielectric":
            p["eta"] = self.eta
        elif self.fresnel == "schlick":
            p["f0"] = self.f0
        return p


def diffuse_fresnel_reflectance(eta: float, n_nodes: int = 64) -> float:
    """Hemispherical (cosine-weighted) reflectance of a smooth dielectric interface, seen from the outside.

    Fdr_ext(eta) = int_0^1 F(mu, eta) 2 mu dmu, Gauss-Legendre in float64; the internal one follows from
    1 - Fdr_int = (1 - Fdr_ext) / eta^2.
    """
    x, w = np.polynomial.legendre.leggauss(n_nodes)
    mu = torch.as_tensor((x + 1) / 2, dtype=torch.float64)
    f = fresnel_dielectric(mu, eta).numpy()
    return float(np.sum(w / 2 * f * 2 * mu.numpy()))


@register_spec("plastic")
class Plastic(AnalyticMaterial):
    """Diffuse base under a rough dielectric GGX coat (energy model in the module docstring).

    diffuse: albedo of the base in [0, 1] (number or RGB); roughness: GGX alpha of the coat in [1e-4, 1];
    eta: coat index of refraction in [1, 4]. Sampling mixes cosine and GGX visible-normal reflection with
    probability F(cos_i) / (F(cos_i) + (1 - F(cos_i)) mean(diffuse)) for the coat, as Mitsuba's roughplastic.
    """

    name = "plastic"

    def __init__(self, diffuse=(0.5, 0.5, 0.5), roughness=0.1, eta=1.5) -> None:
        self.diffuse = rgb_param(diffuse, "Plastic diffuse", 0.0, 1.0)
        self.roughness = scalar_param(roughness, "Plastic roughness", *ALPHA_RANGE)
        self.eta = scalar_param(eta, "Plastic eta", 1.0, 4.0)
        #: internal diffuse Fresnel reflectance of the coat
        self.fdr_internal = 1 - (1 - diffuse_fresnel_reflectance(self.eta)) / self.eta ** 2

    def _coat_fresnel(self, cos: torch.Tensor) -> torch.Tensor:
        return fresnel_dielectric(cos, self.eta).unsqueeze(-1).expand(-1, 3)

    def _eval(self, wi, wo):
        spec = _microfacet_brdf(wi, wo, self.roughness, self.roughness, self._coat_fresnel)
        t_i = 1 - fresnel_dielectric(wi[:, 2].clamp(min=0), self.eta)
        t_o = 1 - fresnel_dielectric(wo[:, 2].clamp(min=0), self.eta)
        scale = 1 / (math.pi * self.eta ** 2 * (1 - self.fdr_internal))
        diffuse = self._const(self.diffuse, wi) * (t_i * t_o * scale).unsqueeze(-1)
        return spec + torch.where(self._both_up(wi, wo).unsqueeze(-1), diffuse, torch.zeros_like(diffuse))

    def _coat_probability(self, wi: torch.Tensor) -> torch.Tensor:
        f = fresnel_dielectric(wi[:, 2].clamp(min=0), self.eta)
        total = f + (1 - f) * (sum(self.diffuse) / 3)
        return torch.where(total > 0, f / torch.where(total > 0, total, torch.ones_like(total)), torch.ones_like(f))

    def _draw(self, wi, u):
        p = self._coat_probability(wi)
        coat = u[:, 0] < p
        u0 = torch.where(coat, u[:, 0] / p.clamp(min=1e-12), (u[:, 0] - p) / (1 - p).clamp(min=1e-12))
        u2 = torch.stack([u0.clamp(0, 1), u[:, 1]], -1)
        return torch.where(coat.unsqueeze(-1), sample_ggx_reflection(wi, u2, self.roughness, self.roughness),
                           sample_cosine_hemisphere(u2))

    def _pdf(self, wi, wo):
        p = self._coat_probability(wi)
        pdf = p * ggx_reflection_pdf(wi, wo, self.roughness, self.roughness) + (1 - p) * wo[:, 2] / math.pi
        return torch.where(self._both_up(wi, wo), pdf, torch.zeros_like(pdf))

    def spec_params(self) -> dict:
        return {"diffuse": self.diffuse, "roughness": self.roughness, "eta": self.eta}


@register_spec("principled")
class Principled(AnalyticMaterial):
    """Metallic-roughness material as PBR texture sets use it (model in `neumat.reflectance.microfacet`).

    base_color in [0, 1] (number or RGB); metallic, roughness (perceptual, alpha = roughness^2), anisotropy
    (0 = isotropic, stretches along the tangent x) and specular (dielectric F0 = 0.08 specular) in [0, 1].
    For per-texel parameters use the functional `principled_eval / principled_sample / principled_pdf`.
    """

    name = "principled"

    def __init__(self, base_color=(0.8, 0.8, 0.8), metallic=0.0, roughness=0.5, anisotropy=0.0,
                 specular=0.5) -> None:
        self.base_color = rgb_param(base_color, "Principled base_color", 0.0, 1.0)
        self.metallic = scalar_param(metallic, "Principled metallic", 0.0, 1.0)
        self.roughness = scalar_param(roughness, "Principled roughness", 0.0, 1.0)
        self.anisotropy = scalar_param(anisotropy, "Principled anisotropy", 0.0, 1.0)
        self.specular = scalar_param(specular, "Principled specular", 0.0, 1.0)

    def _args(self, wi: torch.Tensor) -> tuple:
        return (self._const(self.base_color, wi), self.metallic, self.roughness, self.anisotropy, self.specular)

    def _eval(self, wi, wo):
        return principled_eval(wi, wo, *self._args(wi))

    def _draw(self, wi, u):
        return principled_sample(wi, u, *self._args(wi))[0]

    def _pdf(self, wi, wo):
        return principled_pdf(wi, wo, *self._args(wi))

    def spec_params(self) -> dict:
        return {"base_color": self.base_color, "metallic": self.metallic, "roughness": self.roughness,
                "anisotropy": self.anisotropy, "specular": self.specular}
