"""A spatially varying principled material from PBR maps, and its prefiltered (apparent) value.

Point value at uv: the maps bilinear at the finest level, a normal-mapped principled GGX BRDF. Apparent
value (paper Eq. 1): the mean over `samples` Gaussian positions of the footprint, symmetrised in wi and wo.

Details: docs/notes/reflectance.md, section `neumat.reflectance.svbrdf`.
"""
from __future__ import annotations

import torch

from ..core.checks import check_int
from ..core.errors import InputError
from ..core.frames import normal_map_frame, to_local, to_world
from ..core.material import Material, sample_from_direction
from ..core.query import Query, Sample
from ..io.texture_set import TextureSet, load_texture_set
from ..nn import cpu_kernels
from ..nn.latent_texture import bilinear_maps, padded_maps
from ..warp.hemisphere import cosine_hemisphere_pdf, sample_cosine_hemisphere
from .footprint_filter import filtered_eval, query_footprint
from .lean import NormalGroup
from .microfacet import principled_eval, principled_pdf, principled_sample

#: probability with which `sample` draws a cosine-weighted direction (defensive mixture)
DEFENSIVE_PROBABILITY = 0.1


class SVBRDF(Material):
    """Principled SVBRDF of a `TextureSet`; `eval` is the prefiltered, symmetrised value (module docstring).

    samples:    Monte Carlo positions per footprint (paper: 256).
    seed:       seed of the footprint sample generator; every eval call draws fresh positions.
    chunk:      queries x samples evaluated at once (memory bound).
    specular:   principled specular level (dielectric F0 = 0.08 specular).

    sample / pdf importance-sample the unfiltered normal-mapped principled lobe at the footprint centre,
    mixed with cosine sampling of the geometric hemisphere (probability DEFENSIVE_PROBABILITY) so the pdf is
    positive wherever the filtered value can be; weight = eval cos / pdf uses the filtered value.
    """

    can_sample = True
    spatially_varying = True

    def __init__(self, textures: TextureSet, samples: int = 256, seed: int = 0, chunk: int = 1 << 20,
                 specular: float = 0.5) -> None:
        if not isinstance(textures, TextureSet):
            raise InputError(f"SVBRDF: expected a TextureSet, got {type(textures).__name__}")
        for key, v in (("samples", samples), ("chunk", chunk)):
            check_int(v, f"SVBRDF.{key}")
        self.textures = textures
        self.samples, self.chunk, self.specular = samples, chunk, float(specular)
        self.name = f"svbrdf:{textures.name}"
        # one (8, H, W) stack: base colour (3), normal (3), roughness, metalness
        self.maps = torch.cat([textures.color, textures.normal, textures.roughness[..., None],
                               textures.metalness[..., None]], -1).permute(2, 0, 1).contiguous()
        self.generator = torch.Generator(device=self.maps.device).manual_seed(seed)

    @classmethod
    def from_folder(cls, folder, height_scale: float | None = None, max_size: int | None = None,
                    crop: int | None = None, crop_origin: tuple[int, int] | None = None, samples: int = 256,
                    seed: int = 0, chunk: int = 1 << 20, specular: float = 0.5) -> "SVBRDF":
        """Read a texture-set folder (`neumat.io.texture_set.load_texture_set`) and wrap it; the other
        arguments are those of the constructor."""
        extra = {} if height_scale is None else {"height_scale": height_scale}
        return cls(load_texture_set(folder, max_size=max_size, crop=crop, crop_origin=crop_origin, **extra),
                   samples=samples, seed=seed,
                   chunk=chunk, specular=specular)

    def to(self, device) -> "SVBRDF":
        """The material with its maps (and sample generator) on `device`."""
        out = SVBRDF(self.textures.to(device), self.samples, 0, self.chunk, self.specular)
        out.generator = torch.Generator(device=out.maps.device).manual_seed(int(self.generator.initial_seed()))
        return out

    def describe(self) -> str:
        h, w = self.textures.size
        return f"{self.name} ({w}x{h} texels, {self.samples} footprint samples)"

    # ------------------------------------------------------------------------------ point value

    def parameters_at(self, uv: torch.Tensor) -> dict[str, torch.Tensor]:
        """Bilinear map values at uv (N, 2): base_color (N, 3), normal (N, 3) unit, roughness, metallic (N,), in
        the dtype of uv (the query's: a float64 query on float32 maps is answered in float64)."""
        m = bilinear_maps(self, self.maps, uv)
        n = m[:, 3:6]
        n = n / n.norm(dim=-1, keepdim=True).clamp(min=1e-12)
        return {"base_color": m[:, 0:3], "normal": n, "roughness": m[:, 6], "metallic": m[:, 7]}

    #: features `sampling_features` gives a learned sampler (`neumat.methods.neural_appearance.proxy_sampler`) and the
    #: encoder of `neumat.methods.neural_appearance.model` (its surface parameters k(x))
    sampling_feature_dim = 8
    #: the normal (channels 3-5) and principled roughness (6, alpha = roughness^2) among them, for LEAN
    #: prefiltering of coarse levels (`neumat.reflectance.lean`)
    surface_normal_groups = (NormalGroup(normal=3, roughness=6, alpha_power=2.0),)

    def sampling_features(self, q: Query) -> torch.Tensor:
        """Texture parameters at q.uv (N, 8): base colour, unit normal, roughness, metalness."""
        q.require("uv", who="SVBRDF.sampling_features")
        p = self.parameters_at(q.uv)
        return torch.cat([p["base_color"], p["normal"], p["roughness"][:, None], p["metallic"][:, None]], -1)

    def eval_point(self, wi: torch.Tensor, wo: torch.Tensor, uv: torch.Tensor,
                   symmetrise: bool = True) -> torch.Tensor:
        """Unfiltered value f(wi, wo | uv) (N, 3) (module docstring), symmetrised unless told not to."""
        if cpu_kernels.usable(wi, wo, uv, self.maps):
            return self._kernel_mean(wi, wo, uv[:, None, :], symmetrise)
        p = self.parameters_at(uv)
        t, b, n = normal_map_frame(p["normal"])
        li, lo = to_local(wi, t, b, n), to_local(wo, t, b, n)
        zero = torch.zeros_like(p["roughness"])
        f = principled_eval(li, lo, p["base_color"], p["metallic"], p["roughness"], zero, self.specular)
        up = (wi[:, 2] > 0) & (wo[:, 2] > 0) & (li[:, 2] > 0) & (lo[:, 2] > 0)
        ratio_i = li[:, 2] / wi[:, 2].clamp(min=1e-12)
        ratio = 0.5 * (ratio_i + lo[:, 2] / wo[:, 2].clamp(min=1e-12)) if symmetrise else ratio_i
        return torch.where(up.unsqueeze(-1), f * ratio.unsqueeze(-1), torch.zeros_like(f))

    def _kernel_mean(self, wi: torch.Tensor, wo: torch.Tensor, pts: torch.Tensor,
                     symmetrise: bool = True) -> torch.Tensor:
        """The mean of `eval_point` over the positions pts (N, S, 2) of each query, by the fused CPU kernel (float32,
        no gradient: `cpu_kernels.usable`). Why: a latent-texture fit's targets (32 positions a query) cost about half
        of its CPU training step in torch."""
        return cpu_kernels.svbrdf_eval(padded_maps(self, self.maps, torch.float32, wi.device), wi, wo, pts,
                                       self.specular, symmetrise)

    # ----------------------------------------------------------------------------- filtered value

    def footprint_of(self, q: Query) -> torch.Tensor | None:
        """The query's footprint covariance (N, 2, 2), the isotropic one of q.lod, or None (point query)."""
        return query_footprint(q, self.textures.size[1])

    def eval(self, q: Query) -> torch.Tensor:
        """Prefiltered, symmetrised value (N, 3) (paper Eq. 1, Monte Carlo with `samples` positions)."""
        q.require("wo", who="SVBRDF.eval")
        q.require("uv", who="SVBRDF.eval")
        cov = self.footprint_of(q)
        if cov is None:
            return self.eval_point(q.wi, q.wo, q.uv)
        fused = self._kernel_mean if cpu_kernels.usable(q.wi, q.wo, q.uv, self.maps) else None
        return filtered_eval(self.eval_point, q, cov, self.samples, self.chunk, self.generator, fused)

    # ---------------------------------------------------------------------------------- sampling

    def _centre_lobe(self, q: Query):
        p = self.parameters_at(q.uv)
        t, b, n = normal_map_frame(p["normal"])
        zero = torch.zeros_like(p["roughness"])
        return (t, b, n), (p["base_color"], p["metallic"], p["roughness"], zero, self.specular)

    def sample(self, q: Query, u: torch.Tensor) -> Sample:
        """Sample wo: principled lobe at the footprint centre, or cosine with DEFENSIVE_PROBABILITY."""
        return sample_from_direction(self, q, u)

    def sample_direction(self, q: Query, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """wo (N, 3) and pdf (N,) of `sample` without its weight (which costs a footprint evaluation)."""
        q.require("uv", who="SVBRDF.sample")
        frame, params = self._centre_lobe(q)
        pick_cos = u[:, 0] < DEFENSIVE_PROBABILITY
        u0 = torch.where(pick_cos, u[:, 0] / DEFENSIVE_PROBABILITY,
                         (u[:, 0] - DEFENSIVE_PROBABILITY) / (1 - DEFENSIVE_PROBABILITY))
        u2 = torch.stack([u0.clamp(0, 1 - 1e-7), u[:, 1]], -1)
        wo_lobe, pdf_lobe = principled_sample(to_local(q.wi, *frame), u2, *params)
        wo = torch.where(pick_cos.unsqueeze(-1), sample_cosine_hemisphere(u2), to_world(wo_lobe, *frame))
        wo = wo / wo.norm(dim=-1, keepdim=True).clamp(min=1e-12)
        pdf = self.pdf(q.with_wo(wo))
        # a failed lobe sample (pdf 0, e.g. wi below the perturbed horizon) is a failed sample
        valid = (wo[:, 2] > 0) & (q.wi[:, 2] > 0) & (pick_cos | (pdf_lobe > 0))
        return wo, torch.where(valid, pdf, torch.zeros_like(pdf))

    def pdf(self, q: Query) -> torch.Tensor:
        """Solid-angle density (N,) of `sample`."""
        q.require("wo", who="SVBRDF.pdf")
        q.require("uv", who="SVBRDF.pdf")
        frame, params = self._centre_lobe(q)
        lobe = principled_pdf(to_local(q.wi, *frame), to_local(q.wo, *frame), *params)
        pdf = DEFENSIVE_PROBABILITY * cosine_hemisphere_pdf(q.wo) + (1 - DEFENSIVE_PROBABILITY) * lobe
        return torch.where((q.wo[:, 2] > 0) & (q.wi[:, 2] > 0), pdf, torch.zeros_like(pdf))
