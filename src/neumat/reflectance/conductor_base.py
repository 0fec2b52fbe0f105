"""A textured rough conductor: the metal base of layered materials (`neumat.reflectance.layered`).

GGX reflection with exact conductor Fresnel (complex IOR eta + i k, RGB; or a preset of
`neumat.reflectance.analytic.CONDUCTORS`), roughness (GGX alpha) a number or an (H, W) map, an optional
normal map (tangent space; the frame as the SVBRDF's, tangent +u projected). In the normal-mapped frame, with
the SVBRDF convention that values exclude the geometric cosine, symmetrised so that it is reciprocal:

    f(wi, wo | uv) = D(h) G1(wi') G1(wo') F(wi' . h) / (4 mu_i mu_o) * (mu_i / wi_z + mu_o / wo_z) / 2

(wi', wo' in the shading frame, mu their cosines). Zero below either horizon. Filtering as the SVBRDF's
(Monte Carlo over `samples` footprint positions); sampling: GGX visible normals in the shading frame at the
footprint centre, mixed with cosine sampling (probability DEFENSIVE_PROBABILITY) so the density is positive
wherever a filtered value can be.
"""
from __future__ import annotations

import torch

from ..core.checks import check_int
from ..core.errors import InputError
from ..core.frames import normal_map_frame, to_local, to_world
from ..core.material import Material, sample_from_direction
from ..core.query import Query, Sample
from ..nn.latent_texture import bilinear_maps
from ..warp.ggx import ggx_reflection_pdf, sample_ggx_reflection
from ..warp.hemisphere import cosine_hemisphere_pdf, sample_cosine_hemisphere
from .analytic import CONDUCTORS
from .coat_albedo import ALPHA_MIN
from .footprint_filter import filtered_eval, query_footprint
from .layered import Coat, coat_maps
from .lean import NormalGroup
from .microfacet import _microfacet_brdf, fresnel_conductor
from .svbrdf import DEFENSIVE_PROBABILITY


def _rgb(value, name: str, lo_open: bool) -> torch.Tensor:
    t = torch.as_tensor(value, dtype=torch.float32) if isinstance(value, (int, float, list, tuple)) else None
    if t is not None and t.dim() == 0:
        t = t.expand(3)
    if t is None or t.shape != (3,) or not bool(torch.isfinite(t).all()) or \
            not bool(((t > 0) if lo_open else (t >= 0)).all()):
        raise InputError(f"TexturedConductor {name}: expected a number or 3 finite values "
                         f"{'> 0' if lo_open else '>= 0'}, got {value!r}")
    return t


class TexturedConductor(Material):
    """Textured GGX conductor (module docstring).

    material:  a CONDUCTORS preset ("gold", "copper", ...), or None with eta and k (RGB or numbers).
    roughness: GGX alpha in [1e-3, 1], a number or an (H, W) map; normal: optional (H, W, 3) normal map.
    samples, seed, chunk: footprint filtering as `neumat.reflectance.svbrdf.SVBRDF`.
    """

    can_sample = True
    spatially_varying = True
    #: surface parameters in `sampling_features`: alpha, unit normal (3)
    sampling_feature_dim = 4
    surface_normal_groups = (NormalGroup(normal=1, roughness=0, alpha_power=1.0),)

    def __init__(self, material: str | None = "gold", roughness: float | torch.Tensor = 0.2,
                 normal: torch.Tensor | None = None, eta=None, k=None, samples: int = 256, seed: int = 0,
                 chunk: int = 1 << 20, name: str | None = None) -> None:
        if material is not None:
            if material not in CONDUCTORS or eta is not None or k is not None:
                raise InputError(f"TexturedConductor: give a preset of {', '.join(CONDUCTORS)} or eta and k, "
                                 f"got material={material!r}, eta={eta!r}, k={k!r}")
            eta, k = CONDUCTORS[material]
        elif eta is None or k is None:
            raise InputError("TexturedConductor: without a material preset, give both eta and k")
        for key, v in (("samples", samples), ("chunk", chunk)):
            check_int(v, f"TexturedConductor.{key}")
        self.eta, self.k = _rgb(eta, "eta", True), _rgb(k, "k", False)
        maps = coat_maps(Coat(roughness=roughness, normal=normal), "conductor")
        self.maps = torch.cat([maps[:1], maps[2:]])              # (4, H, W): alpha, normal
        self.samples, self.chunk = samples, chunk
        self.generator = torch.Generator().manual_seed(seed)
        self.name = name or f"conductor:{material or 'custom'}"

    @property
    def texture_size(self) -> tuple[int, int]:
        """(height, width) of the maps."""
        return tuple(self.maps.shape[1:])

    def describe(self) -> str:
        return f"{self.name} ({self.texture_size[1]} x {self.texture_size[0]} maps, {self.samples} footprint samples)"

    def _at(self, uv: torch.Tensor):
        """alpha (N,) and shading frame (t, b, n) at uv (N, 2)."""
        p = bilinear_maps(self, self.maps, uv)
        n = p[:, 1:4] / p[:, 1:4].norm(dim=-1, keepdim=True).clamp(min=1e-12)
        return p[:, 0].clamp(min=ALPHA_MIN), normal_map_frame(n)

    def sampling_features(self, q: Query) -> torch.Tensor:
        """Surface parameters at q.uv (N, 4): alpha, unit normal."""
        q.require("uv", who="TexturedConductor.sampling_features")
        alpha, (_, _, n) = self._at(q.uv)
        return torch.cat([alpha[:, None], n], -1)

    def eval_point(self, wi: torch.Tensor, wo: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
        """Unfiltered value f(wi, wo | uv) (N, 3) (module docstring)."""
        alpha, frame = self._at(uv)
        li, lo = to_local(wi, *frame), to_local(wo, *frame)
        ok = (wi[:, 2] > 0) & (wo[:, 2] > 0) & (li[:, 2] > 0) & (lo[:, 2] > 0)
        eta, k = self.eta.to(wi.device, wi.dtype), self.k.to(wi.device, wi.dtype)
        f = _microfacet_brdf(li, lo, alpha, alpha, lambda c: fresnel_conductor(c, eta, k))
        ratio = 0.5 * (li[:, 2] / wi[:, 2].clamp(min=1e-6) + lo[:, 2] / wo[:, 2].clamp(min=1e-6))
        return torch.where(ok.unsqueeze(-1), f * ratio.unsqueeze(-1), torch.zeros_like(f))

    def eval(self, q: Query) -> torch.Tensor:
        """Prefiltered value (N, 3): the point value, or its mean over the query's footprint."""
        q.require("wo", who="TexturedConductor.eval")
        q.require("uv", who="TexturedConductor.eval")
        cov = query_footprint(q, self.texture_size[1])
        if cov is None:
            return self.eval_point(q.wi, q.wo, q.uv)
        return filtered_eval(self.eval_point, q, cov, self.samples, self.chunk, self.generator)

    def sample(self, q: Query, u: torch.Tensor) -> Sample:
        """Sample wo: GGX visible normals in the shading frame, or cosine with DEFENSIVE_PROBABILITY."""
        return sample_from_direction(self, q, u)

    def sample_direction(self, q: Query, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """wo (N, 3) and pdf (N,) of `sample` without its weight."""
        q.require("uv", who="TexturedConductor.sample")
        alpha, frame = self._at(q.uv)
        pick_cos = u[:, 0] < DEFENSIVE_PROBABILITY
        u0 = torch.where(pick_cos, u[:, 0] / DEFENSIVE_PROBABILITY,
                         (u[:, 0] - DEFENSIVE_PROBABILITY) / (1 - DEFENSIVE_PROBABILITY))
        u2 = torch.stack([u0.clamp(0, 1 - 1e-7), u[:, 1]], -1)
        li = to_local(q.wi, *frame)
        lobe_ok = li[:, 2] > 0
        safe = torch.where(lobe_ok.unsqueeze(-1), li, li.new_tensor([0.0, 0.0, 1.0]))
        wo_lobe = to_world(sample_ggx_reflection(safe, u2, alpha, alpha), *frame)
        wo = torch.where(pick_cos.unsqueeze(-1), sample_cosine_hemisphere(u2), wo_lobe)
        wo = wo / wo.norm(dim=-1, keepdim=True).clamp(min=1e-12)
        pdf = self.pdf(q.with_wo(wo))
        valid = (wo[:, 2] > 0) & (q.wi[:, 2] > 0) & (pick_cos | lobe_ok)
        return wo, torch.where(valid, pdf, torch.zeros_like(pdf))

    def pdf(self, q: Query) -> torch.Tensor:
        """Solid-angle density (N,) of `sample`."""
        q.require("wo", who="TexturedConductor.pdf")
        q.require("uv", who="TexturedConductor.pdf")
        alpha, frame = self._at(q.uv)
        li, lo = to_local(q.wi, *frame), to_local(q.wo, *frame)
        ok = (li[:, 2] > 0) & (lo[:, 2] > 0)
        up = li.new_tensor([0.0, 0.0, 1.0])
        lobe = ggx_reflection_pdf(torch.where(ok.unsqueeze(-1), li, up), torch.where(ok.unsqueeze(-1), lo, up),
                                  alpha, alpha)
        pdf = DEFENSIVE_PROBABILITY * cosine_hemisphere_pdf(q.wo) \
            + (1 - DEFENSIVE_PROBABILITY) * torch.where(ok, lobe, torch.zeros_like(lobe))
        return torch.where((q.wo[:, 2] > 0) & (q.wi[:, 2] > 0), pdf, torch.zeros_like(pdf))
