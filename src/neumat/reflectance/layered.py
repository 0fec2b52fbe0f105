"""Layered reference materials: textured rough dielectric coats and a sheen layer over a base material.

A base (SVBRDF, textured conductor or any material) under rough dielectric coats listed bottom to top,
albedo-scaled (Kelemen and Szirmay-Kalos 2001, Kulla and Conty 2017), and an optional sheen on top: the
layered graphs of Zeltner et al. 2024, Sec. 8. Reciprocal; filtering and sampling as the SVBRDF.

Details: docs/notes/reflectance.md, section `neumat.reflectance.layered`.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import torch

from ..core.checks import check_int
from ..core.errors import InputError
from ..core.frames import normal_map_frame, to_local, to_world
from ..core.material import Material, sample_from_direction
from ..core.query import Query, Sample
from ..nn.latent_texture import bilinear_maps
from ..warp.ggx import ggx_reflection_pdf, sample_ggx_reflection
from ..warp.hemisphere import cosine_hemisphere_pdf, sample_cosine_hemisphere
from .coat_albedo import ALPHA_MIN, CoatAlbedo
from .footprint_filter import filtered_eval, query_footprint
from .lean import NormalGroup
from .microfacet import _microfacet_brdf, fresnel_dielectric
from .sheen import SHEEN_ALPHA_MIN, SheenAlbedo

#: surface parameters one coat adds to `sampling_features`: alpha, weight, unit normal (3)
COAT_FEATURES = 5
#: surface parameters the sheen layer adds to `sampling_features` (after the coats'): alpha, weight
SHEEN_FEATURES = 2


@dataclass
class Coat:
    """One rough dielectric coat. roughness: GGX alpha in [1e-3, 1]; weight: presence in [0, 1] (both numbers or
    (H, W) maps); eta: index of refraction in [1, 4]; tint: RGB transmittance in (0, 1] at normal incidence, in and
    out; normal: optional (H, W, 3) normal map (tangent space, z up)."""

    roughness: float | torch.Tensor = 0.05
    weight: float | torch.Tensor = 1.0
    eta: float = 1.5
    tint: tuple[float, float, float] = (1.0, 1.0, 1.0)
    normal: torch.Tensor | None = None


@dataclass
class Sheen:
    """The sheen layer on top (module docstring). colour: RGB in [0, 1]; roughness: Charlie alpha in
    [SHEEN_ALPHA_MIN, 1]; weight: presence in [0, 1] (both numbers or (H, W) maps)."""

    color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    roughness: float | torch.Tensor = 0.3
    weight: float | torch.Tensor = 1.0


def _map(value, name: str, lo: float, hi: float) -> torch.Tensor:
    """A number or (H, W) map as a float32 (1, H, W) tensor, range-checked."""
    try:
        t = torch.as_tensor(value, dtype=torch.float32)
    except (TypeError, ValueError, RuntimeError):
        raise InputError(f"{name}: expected a number or an (H, W) map, got {type(value).__name__}") from None
    if t.dim() == 0:
        t = t.reshape(1, 1)
    if t.dim() != 2 or min(t.shape) < 1:
        raise InputError(f"{name}: expected a number or an (H, W) map, got shape {tuple(t.shape)}")
    if not bool(torch.isfinite(t).all()) or float(t.min()) < lo or float(t.max()) > hi:
        raise InputError(f"{name}: values must lie in [{lo}, {hi}], got [{float(t.min()):.4g}, {float(t.max()):.4g}]")
    return t[None]


def coat_maps(coat: Coat, who: str) -> torch.Tensor:
    """(5, H, W) maps of a layer's alpha, weight and normal (a coat's, or the same fields of a conductor base or
    sheen layer); maps of different sizes are resampled to the largest; `who` names the layer in errors."""
    alpha = _map(coat.roughness, f"{who} roughness", ALPHA_MIN, 1.0)
    weight = _map(coat.weight, f"{who} weight", 0.0, 1.0)
    if coat.normal is None:
        normal = torch.tensor([0.0, 0.0, 1.0]).view(3, 1, 1)
    else:
        n = torch.as_tensor(coat.normal, dtype=torch.float32)
        if n.dim() != 3 or n.shape[-1] != 3 or not bool(torch.isfinite(n).all()) or not bool((n[..., 2] > 0).all()):
            raise InputError(f"{who} normal: expected an (H, W, 3) map of finite upward normals, got shape "
                             f"{tuple(n.shape)}")
        normal = (n / n.norm(dim=-1, keepdim=True)).permute(2, 0, 1)
    parts = [alpha, weight, normal]
    h = max(p.shape[1] for p in parts)
    w = max(p.shape[2] for p in parts)
    resized = [p if p.shape[1:] == (h, w) else
               torch.nn.functional.interpolate(p[None], size=(h, w), mode="bilinear", align_corners=False)[0]
               for p in parts]
    return torch.cat(resized)


@functools.lru_cache(maxsize=16)
def coat_albedo(eta: float) -> CoatAlbedo:
    """The albedo table of index eta, computed once per process (about 0.5 s)."""
    return CoatAlbedo(eta)


@functools.lru_cache(maxsize=1)
def sheen_albedo() -> SheenAlbedo:
    """The sheen lobe and its albedo table, computed once per process (about 2 s)."""
    return SheenAlbedo()


class LayeredMaterial(Material):
    """Coats (bottom to top) and an optional sheen over `base` (module docstring).

    base:     an SVBRDF or a textured conductor (spatially varying: needs `eval_point`, `sampling_features` and
              `texture_size` or `textures`) or a homogeneous material.
    coats:    a list of `Coat`, bottom to top (may be empty when there is a sheen).
    sheen:    an optional `Sheen` on top.
    samples, seed, chunk: footprint filtering as `neumat.reflectance.svbrdf.SVBRDF`.
    """

    can_sample = True
    spatially_varying = True

    def __init__(self, base: Material, coats: list[Coat], samples: int = 256, seed: int = 0,
                 chunk: int = 1 << 20, name: str | None = None, sheen: Sheen | None = None) -> None:
        if not isinstance(base, Material):
            raise InputError(f"LayeredMaterial base: expected a Material, got {type(base).__name__}")
        if getattr(base, "full_sphere", False):
            raise InputError("LayeredMaterial base: a translucent (full-sphere) material cannot be coated")
        if base.spatially_varying and not all(callable(getattr(base, a, None))
                                              for a in ("eval_point", "sampling_features")):
            raise InputError(f"LayeredMaterial base: the spatially varying {type(base).__name__} must give point "
                             "values (eval_point) and surface parameters (sampling_features), as an SVBRDF does")
        if sheen is not None and not isinstance(sheen, Sheen):
            raise InputError(f"LayeredMaterial sheen: expected a Sheen or None, got {type(sheen).__name__}")
        if not isinstance(coats, (list, tuple)) or not all(isinstance(c, Coat) for c in coats) \
                or (not coats and sheen is None):
            raise InputError("LayeredMaterial coats: expected a non-empty list of Coat (empty only under a sheen)")
        for key, v in (("samples", samples), ("chunk", chunk)):
            check_int(v, f"LayeredMaterial.{key}")
        self.base, self.coats = base, list(coats)
        self.maps = [coat_maps(c, f"coat {i}") for i, c in enumerate(self.coats)]
        self.albedos = []
        for i, c in enumerate(self.coats):
            try:
                tint = torch.as_tensor(c.tint, dtype=torch.float32)
            except (TypeError, ValueError, RuntimeError):
                tint = torch.zeros(0)
            if tint.shape != (3,) or not bool(((tint > 0) & (tint <= 1)).all()):
                raise InputError(f"coat {i} tint: expected 3 values in (0, 1], got {c.tint!r}")
            if isinstance(c.eta, bool) or not isinstance(c.eta, (int, float)):
                raise InputError(f"coat {i} eta: expected a number in [1, 4], got {c.eta!r}")
            self.albedos.append(coat_albedo(float(c.eta)))  # checks the range
        self.sheen, self.sheen_maps = sheen, None
        if sheen is not None:
            try:
                color = torch.as_tensor(sheen.color, dtype=torch.float32)
            except (TypeError, ValueError, RuntimeError):
                color = torch.zeros(0)
            if color.shape != (3,) or not bool(((color >= 0) & (color <= 1)).all()):
                raise InputError(f"sheen color: expected 3 values in [0, 1], got {sheen.color!r}")
            self.sheen_color = color
            self.sheen_maps = coat_maps(Coat(roughness=sheen.roughness, weight=sheen.weight), "sheen")[:2]
            if float(self.sheen_maps[0].min()) < SHEEN_ALPHA_MIN:
                raise InputError(f"sheen roughness: values must lie in [{SHEEN_ALPHA_MIN}, 1], got minimum "
                                 f"{float(self.sheen_maps[0].min()):.4g}")
            self.sheen_albedo = sheen_albedo()
        self.samples, self.chunk = samples, chunk
        self.generator = torch.Generator().manual_seed(seed)
        self.name = name or f"layered:{getattr(base, 'name', type(base).__name__)}+{len(self.coats)} coat(s)"

    def describe(self) -> str:
        coats = ", ".join(f"eta {c.eta:g}" for c in self.coats) or "none"
        sheen = "; sheen on top" if self.sheen is not None else ""
        return f"{self.name} (coats bottom to top: {coats}{sheen}; {self.samples} footprint samples)"

    @property
    def texture_size(self) -> tuple[int, int]:
        """(height, width) in texels of the finest texture, the base's or a coat map's (what a lod refers to)."""
        sizes = [tuple(getattr(self.base, "texture_size", None) or self.base.textures.size)] \
            if self.base.spatially_varying else []
        sizes += [tuple(m.shape[1:]) for m in self.maps + ([self.sheen_maps] if self.sheen is not None else [])]
        return max(s[0] for s in sizes), max(s[1] for s in sizes)

    # ------------------------------------------------------------------------------ parameters

    @property
    def sampling_feature_dim(self) -> int:
        base = int(self.base.sampling_feature_dim) if self.base.spatially_varying else 0
        return base + COAT_FEATURES * len(self.coats) + (SHEEN_FEATURES if self.sheen is not None else 0)

    @property
    def surface_normal_groups(self) -> tuple[NormalGroup, ...]:
        """Normal and roughness channels of every layer in `sampling_features` (LEAN prefiltering)."""
        groups = tuple(getattr(self.base, "surface_normal_groups", ())) if self.base.spatially_varying else ()
        start = int(self.base.sampling_feature_dim) if self.base.spatially_varying else 0
        return groups + tuple(NormalGroup(normal=start + COAT_FEATURES * i + 2, roughness=start + COAT_FEATURES * i,
                                          alpha_power=1.0) for i in range(len(self.coats)))

    def _coat_at(self, i: int, uv: torch.Tensor):
        """alpha (N,), weight (N,) and frame (t, b, n) of coat i at uv (N, 2)."""
        p = bilinear_maps(self, self.maps[i], uv)
        n = p[:, 2:5] / p[:, 2:5].norm(dim=-1, keepdim=True).clamp(min=1e-12)
        return p[:, 0], p[:, 1], normal_map_frame(n)

    def sampling_features(self, q: Query) -> torch.Tensor:
        """Surface parameters at q.uv (N, K): the base's (an SVBRDF's 8), then per coat alpha, weight, normal, then
        the sheen's alpha and weight."""
        q.require("uv", who="LayeredMaterial.sampling_features")
        parts = [self.base.sampling_features(q)] if self.base.spatially_varying else []
        for i in range(len(self.coats)):
            alpha, weight, (_, _, n) = self._coat_at(i, q.uv)
            parts.append(torch.cat([alpha[:, None], weight[:, None], n], -1))
        if self.sheen is not None:
            parts.append(torch.stack(self._sheen_at(q.uv), -1))
        return torch.cat(parts, -1)

    def _sheen_at(self, uv: torch.Tensor):
        """Sheen alpha (N,) and weight (N,) at uv (N, 2)."""
        p = bilinear_maps(self, self.sheen_maps, uv)
        return p[:, 0], p[:, 1]

    # ------------------------------------------------------------------------------ point value

    def _base_point(self, wi: torch.Tensor, wo: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
        if self.base.spatially_varying:
            return self.base.eval_point(wi, wo, uv)
        return self.base.eval(Query(wi, wo))

    def eval_point(self, wi: torch.Tensor, wo: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
        """Unfiltered value f(wi, wo | uv) (N, 3) (module docstring)."""
        f = self._base_point(wi, wo, uv)
        up = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        for i, (coat, table) in enumerate(zip(self.coats, self.albedos)):
            alpha, weight, frame = self._coat_at(i, uv)
            li, lo = to_local(wi, *frame), to_local(wo, *frame)
            ok = up & (li[:, 2] > 0) & (lo[:, 2] > 0)
            mu_i, mu_o = li[:, 2].clamp(min=1e-6), lo[:, 2].clamp(min=1e-6)
            fresnel = lambda c: fresnel_dielectric(c, coat.eta).unsqueeze(-1).expand(-1, 3)  # noqa: E731
            a = alpha.clamp(min=ALPHA_MIN)
            ratio = 0.5 * (mu_i / wi[:, 2].clamp(min=1e-6) + mu_o / wo[:, 2].clamp(min=1e-6))
            top = _microfacet_brdf(li, lo, a, a, fresnel) * ratio.unsqueeze(-1)
            scale = (1 - table(mu_i, a)) * (1 - table(mu_o, a)) / (1 - table.averaged(a)).clamp(min=1e-6)
            top = top + scale.unsqueeze(-1) * self._transmittance(coat, mu_i, mu_o) * f
            covered = torch.where(ok.unsqueeze(-1), top, torch.zeros_like(top))
            f = (1 - weight).unsqueeze(-1) * f + weight.unsqueeze(-1) * covered
        if self.sheen is not None:
            f = self._sheen_over(f, wi, wo, uv)
        return torch.where(up.unsqueeze(-1), f, torch.zeros_like(f))

    def _sheen_over(self, f: torch.Tensor, wi: torch.Tensor, wo: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
        """f (N, 3) under the sheen layer (module docstring)."""
        alpha, weight = self._sheen_at(uv)
        color = self.sheen_color.to(f.device, f.dtype)
        c = float(color.max())
        table = self.sheen_albedo
        mu_i, mu_o = wi[:, 2].clamp(0, 1), wo[:, 2].clamp(0, 1)
        scale = (1 - c * table(mu_i, alpha)) * (1 - c * table(mu_o, alpha)) / (1 - c * table.averaged(alpha))
        top = table.brdf(wi, wo, alpha).unsqueeze(-1) * color + scale.unsqueeze(-1) * f
        return (1 - weight).unsqueeze(-1) * f + weight.unsqueeze(-1) * top

    @staticmethod
    def _transmittance(coat: Coat, mu_i: torch.Tensor, mu_o: torch.Tensor) -> torch.Tensor:
        """T = tint^((1/mu_i_t + 1/mu_o_t) / 2) (N, 3) along the refracted paths (1 for a colourless coat)."""
        tint = torch.as_tensor(coat.tint, dtype=mu_i.dtype, device=mu_i.device)
        if bool((tint == 1).all()):
            return torch.ones(1, 3, dtype=mu_i.dtype, device=mu_i.device)
        refracted = lambda mu: (1 - (1 - mu * mu) / coat.eta ** 2).clamp(min=1e-6).sqrt()  # noqa: E731
        length = 0.5 * (1 / refracted(mu_i) + 1 / refracted(mu_o))
        return torch.exp(length.unsqueeze(-1) * tint.log())

    # ----------------------------------------------------------------------------- filtered value

    def eval(self, q: Query) -> torch.Tensor:
        """Prefiltered value (N, 3): the point value, or its mean over the query's footprint."""
        q.require("wo", who="LayeredMaterial.eval")
        q.require("uv", who="LayeredMaterial.eval")
        cov = query_footprint(q, self.texture_size[1])
        if cov is None:
            return self.eval_point(q.wi, q.wo, q.uv)
        return filtered_eval(self.eval_point, q, cov, self.samples, self.chunk, self.generator)

    # ---------------------------------------------------------------------------------- sampling

    def _mixture(self, wi: torch.Tensor, uv: torch.Tensor):
        """Component probabilities (N, S + C + 1) (the sheen if any, coats top to bottom, then the base), coat
        alphas and frames."""
        coats, probs = [], []
        remaining = torch.ones_like(wi[:, 0])
        if self.sheen is not None:
            alpha, weight = self._sheen_at(uv)
            c = float(self.sheen_color.max())
            probs.append(weight * c * self.sheen_albedo(wi[:, 2].clamp(0, 1), alpha) * (wi[:, 2] > 0))
            remaining = remaining * (1 - probs[-1])
        for i in reversed(range(len(self.coats))):
            alpha, weight, frame = self._coat_at(i, uv)
            mu = to_local(wi, *frame)[:, 2]
            e = weight * self.albedos[i](mu.clamp(min=0), alpha) * (mu > 0)
            probs.append(remaining * e)
            remaining = remaining * (1 - e)
            coats.append((alpha.clamp(min=ALPHA_MIN), frame))
        probs.append(remaining)
        return torch.stack(probs, -1), coats

    @property
    def _first_coat(self) -> int:
        """Index of the top coat among the mixture's components (after the sheen, if any)."""
        return 0 if self.sheen is None else 1

    def _base_query(self, wi: torch.Tensor, uv: torch.Tensor, wo: torch.Tensor | None = None) -> Query:
        return Query(wi, wo, uv=uv) if self.base.spatially_varying else Query(wi, wo)

    def sample(self, q: Query, u: torch.Tensor) -> Sample:
        """Sample wo from the component mixture at the footprint centre (module docstring)."""
        return sample_from_direction(self, q, u)

    def sample_direction(self, q: Query, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """wo (N, 3) and pdf (N,) of `sample` without its weight (which costs a footprint evaluation)."""
        q.require("uv", who="LayeredMaterial.sample")
        probs, coats = self._mixture(q.wi, q.uv)
        cdf = probs.cumsum(-1)
        pick = (u[:, :1] >= cdf[:, :-1]).sum(-1)                                     # (N,) component index
        lo = torch.where(pick > 0, cdf.gather(1, (pick - 1).clamp(min=0)[:, None])[:, 0], torch.zeros_like(u[:, 0]))
        p = probs.gather(1, pick[:, None])[:, 0]
        u0 = ((u[:, 0] - lo) / p.clamp(min=1e-12)).clamp(0, 1 - 1e-7)
        u2 = torch.stack([u0, u[:, 1]], -1)
        if self.base.can_sample:
            wo, base_pdf = self.base.sample_direction(self._base_query(q.wi, q.uv), u2)
            base_ok = base_pdf > 0                         # the base's failed samples stay failed
        else:
            wo, base_ok = sample_cosine_hemisphere(u2), torch.ones_like(pick, dtype=torch.bool)
        up = q.wi.new_tensor([0.0, 0.0, 1.0])
        first = self._first_coat
        if self.sheen is not None:
            wo = torch.where((pick == 0).unsqueeze(-1), sample_cosine_hemisphere(u2), wo)
        for k, (alpha, frame) in enumerate(coats):
            li = to_local(q.wi, *frame)
            safe = torch.where((li[:, 2] > 0).unsqueeze(-1), li, up)
            lw = to_world(sample_ggx_reflection(safe, u2, alpha, alpha), *frame)
            wo = torch.where((pick == first + k).unsqueeze(-1), lw, wo)
        wo = wo / wo.norm(dim=-1, keepdim=True).clamp(min=1e-12)
        pdf = self._mixture_pdf(q.with_wo(wo), probs, coats)
        valid = (wo[:, 2] > 0) & (q.wi[:, 2] > 0) & ((pick < first + len(coats)) | base_ok)
        return wo, torch.where(valid, pdf, torch.zeros_like(pdf))

    def pdf(self, q: Query) -> torch.Tensor:
        """Solid-angle density (N,) of `sample`."""
        q.require("wo", who="LayeredMaterial.pdf")
        q.require("uv", who="LayeredMaterial.pdf")
        return self._mixture_pdf(q, *self._mixture(q.wi, q.uv))

    def _mixture_pdf(self, q: Query, probs: torch.Tensor, coats: list) -> torch.Tensor:
        """The density (N,) at q.wo of the mixture `_mixture` gave for q.wi and q.uv."""
        if self.base.can_sample:
            base = self.base.pdf(self._base_query(q.wi, q.uv, q.wo))
        else:
            base = cosine_hemisphere_pdf(q.wo)
        pdf = probs[:, -1] * base
        if self.sheen is not None:
            pdf = pdf + probs[:, 0] * cosine_hemisphere_pdf(q.wo)
        up = q.wi.new_tensor([0.0, 0.0, 1.0])
        for k, (alpha, frame) in enumerate(coats):
            p = probs[:, self._first_coat + k]
            li, lo = to_local(q.wi, *frame), to_local(q.wo, *frame)
            ok = (p > 0) & (li[:, 2] > 0) & (lo[:, 2] > 0)
            safe_i = torch.where(ok.unsqueeze(-1), li, up)
            safe_o = torch.where(ok.unsqueeze(-1), lo, up)
            lobe = ggx_reflection_pdf(safe_i, safe_o, alpha, alpha)
            pdf = pdf + torch.where(ok, p * lobe, torch.zeros_like(lobe))
        return torch.where((q.wo[:, 2] > 0) & (q.wi[:, 2] > 0), pdf, torch.zeros_like(pdf))
