"""The dipole BSSRDF of a translucent object (Jensen, Marschner, Levoy, Hanrahan 2001), homogeneous or with
textured coefficients: the analytic baselines NeuPreSS compares against, here fitted to the same path-traced
observations by gradient descent (as Deng et al. 2022 fit the textured one by differentiable rendering: the
paper's "Diff." row).

Homogeneous (`texture_resolution` 1, the default: six learned parameters) or textured (a trilinear grid of
log-coefficient offsets over the bounding box); queries need x, wo and n.

Details: src/neumat/methods/neupress/NOTES.md, section `neumat.methods.baselines.dipole_bssrdf`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import nn

import torch.nn.functional as F

from neumat.core.checks import check_int, check_number
from neumat.core.config import resolve_config
from neumat.core.errors import InputError
from neumat.core.tensors import rows_per_slice
from neumat.core.query import Query
from neumat.models.base import LearnedMaterial
from neumat.nn import cpu_kernels
from neumat.nn.codebook import float_bits, storage_bytes
from neumat.reflectance.microfacet import fresnel_dielectric


@dataclass
class Config:
    samples: int = 8192
    """Surface points of the quadrature over incidence points (buffers, set by `set_surface`)."""
    ior: float = 1.5
    """Index of refraction inside (outside 1)."""
    init_sigma_a: float = 0.05
    """Initial absorption coefficient, 1 / object unit, all channels."""
    init_sigma_s: float = 2.0
    """Initial reduced scattering coefficient, 1 / object unit, all channels."""
    batch: int = 1024
    """Queries per chunk of the (queries x samples) sum."""
    texture_resolution: int = 1
    """Texels per side of the coefficient texture over the bounding box (1: homogeneous, six numbers; R > 1: an
    R^3 x 6 grid of log-coefficient offsets, trilinear)."""


def _check_config(c: Config) -> None:
    check_int(c.samples, "DipoleBSSRDF.samples")
    check_int(c.batch, "DipoleBSSRDF.batch")
    check_int(c.texture_resolution, "DipoleBSSRDF.texture_resolution")
    for name in ("ior", "init_sigma_a", "init_sigma_s"):
        check_number(getattr(c, name), f"DipoleBSSRDF.{name}", 0, strict=True)


def diffuse_fresnel_reflectance(eta: float) -> float:
    """F_dr, the polynomial fit to the diffuse Fresnel reflectance that Jensen et al. 2001 use."""
    return -1.440 / eta ** 2 + 0.710 / eta + 0.668 + 0.0636 * eta


def dipole_profile(r: torch.Tensor, sigma_a: torch.Tensor, sigma_s: torch.Tensor, eta: float) -> torch.Tensor:
    """R_d (..., 3) at distances r (...) for coefficients sigma_a, sigma_s' (3,) in 1 / the unit of r."""
    sigma_t = sigma_a + sigma_s
    alpha = sigma_s / sigma_t
    sigma_tr = torch.sqrt(3 * sigma_a * sigma_t)
    f_dr = diffuse_fresnel_reflectance(eta)
    a = (1 + f_dr) / (1 - f_dr)
    z_r = 1 / sigma_t
    z_v = z_r * (1 + 4 * a / 3)
    r2 = (r * r)[..., None]
    d_r, d_v = torch.sqrt(r2 + z_r * z_r), torch.sqrt(r2 + z_v * z_v)
    real = z_r * (sigma_tr * d_r + 1) * torch.exp(-sigma_tr * d_r) / d_r ** 3
    virtual = z_v * (sigma_tr * d_v + 1) * torch.exp(-sigma_tr * d_v) / d_v ** 3
    return alpha / (4 * math.pi) * (real + virtual)


def dipole_total_reflectance(sigma_a: torch.Tensor, sigma_s: torch.Tensor, eta: float) -> torch.Tensor:
    """Integral of R_d over the plane, (alpha' / 2) (1 + e^(-4/3 A sqrt(3 (1 - alpha')))) e^(-sqrt(3 (1 - alpha')))
    (closed form, Jensen and Buhler 2002): the total diffuse reflectance (3,)."""
    alpha = sigma_s / (sigma_a + sigma_s)
    f_dr = diffuse_fresnel_reflectance(eta)
    a = (1 + f_dr) / (1 - f_dr)
    root = torch.sqrt(3 * (1 - alpha))
    return alpha / 2 * (1 + torch.exp(-4 / 3 * a * root)) * torch.exp(-root)


class DipoleBSSRDF(LearnedMaterial):
    """S_hat(wi; x, wo) of an object by the dipole, homogeneous or textured (see the module docstring)."""

    name = "dipole-bssrdf"
    paper = "Jensen et al. 2001 dipole BSSRDF: baseline of NeuPreSS (TG et al.)"
    source_kinds = ("translucent",)
    full_sphere = True
    can_sample = False
    Config = Config

    def __init__(self, config: Config | None = None, **kwargs) -> None:
        nn.Module.__init__(self)
        self.cfg = resolve_config(Config, config, kwargs, "DipoleBSSRDF")
        _check_config(self.cfg)
        n = self.cfg.samples
        self.log_sigma_a = nn.Parameter(torch.full((3,), math.log(self.cfg.init_sigma_a)))
        self.log_sigma_s = nn.Parameter(torch.full((3,), math.log(self.cfg.init_sigma_s)))
        self.register_buffer("points", torch.zeros(n, 3))
        self.register_buffer("normals", torch.zeros(n, 3))
        self.register_buffer("areas", torch.zeros(n))
        r = self.cfg.texture_resolution
        if r > 1:  # the homogeneous model keeps its six numbers (and the files written before the texture)
            self.texture = nn.Parameter(torch.zeros(6, r, r, r))  # log sigma_a, log sigma_s' offsets; (x, y, z)
            self.register_buffer("box_min", torch.zeros(3))
            self.register_buffer("box_max", torch.ones(3))

    @property
    def textured(self) -> bool:
        return self.cfg.texture_resolution > 1

    @property
    def config(self) -> Config:
        return self.cfg

    def set_surface(self, points: torch.Tensor, normals: torch.Tensor, areas: torch.Tensor) -> None:
        """The quadrature: Config.samples surface points (n, 3), unit outward normals (n, 3), areas (n,)."""
        n = self.cfg.samples
        if points.shape != (n, 3) or normals.shape != (n, 3) or areas.shape != (n,):
            raise InputError(f"DipoleBSSRDF.set_surface: expected ({n}, 3), ({n}, 3), ({n},) (Config.samples = {n}), "
                             f"got {tuple(points.shape)}, {tuple(normals.shape)}, {tuple(areas.shape)}")
        if not (torch.isfinite(points).all() and torch.isfinite(normals).all() and bool((areas > 0).all())):
            raise InputError("DipoleBSSRDF.set_surface: points and normals must be finite and areas > 0")
        with torch.no_grad():
            self.points.copy_(points)
            self.normals.copy_(normals / normals.norm(dim=-1, keepdim=True))
            self.areas.copy_(areas)

    def has_surface(self) -> bool:
        """Whether set_surface gave the quadrature (its areas sum above 0); kept while the areas are unchanged
        (their storage and in-place version), since summing them on every call was a tenth of a small call's cost."""
        key = (self.areas.data_ptr(), self.areas._version)
        kept = self.__dict__.get("_has_surface")
        if kept is None or kept[0] != key:
            kept = self.__dict__["_has_surface"] = (key, bool(self.areas.sum() > 0))
        return kept[1]

    def set_bounds(self, lo: torch.Tensor, hi: torch.Tensor) -> None:
        """Object-space bounding box (3,), (3,) that the texture spans (the homogeneous model has none: ignored)."""
        lo, hi = torch.as_tensor(lo, dtype=torch.float32), torch.as_tensor(hi, dtype=torch.float32)
        if lo.shape != (3,) or hi.shape != (3,) or not bool((hi > lo).all()):
            raise InputError(f"DipoleBSSRDF.set_bounds: expected lo < hi of shape (3,), got {lo.tolist()}, "
                             f"{hi.tolist()}")
        if self.textured:
            self.box_min.copy_(lo)
            self.box_max.copy_(hi)

    def coefficients(self, x: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """(sigma_a, sigma_s') in 1 / object unit: the base values (3,) each, or with x (N, 3) those at the
        points x, (N, 3) each (trilinear in the texture; the base values everywhere when homogeneous)."""
        log_a, log_s = self.log_sigma_a, self.log_sigma_s
        if x is None:
            return log_a.exp(), log_s.exp()
        if not self.textured:
            return log_a.exp().expand(x.shape[0], 3), log_s.exp().expand(x.shape[0], 3)
        offset = self.texture_at(x)
        return (log_a + offset[:, :3]).exp(), (log_s + offset[:, 3:]).exp()

    def texture_at(self, x: torch.Tensor) -> torch.Tensor:
        """Trilinear offsets (N, 6) of (log sigma_a, log sigma_s') at points x (N, 3), clamped to the box."""
        u = (x - self.box_min) / (self.box_max - self.box_min) * 2 - 1  # [-1, 1] over the box
        # the texture is (6, x, y, z), grid_sample's (C, D, H, W); its grid's last axis indexes (W, H, D)
        grid = u.to(self.texture.dtype)[None, :, None, None, [2, 1, 0]]
        out = F.grid_sample(self.texture[None], grid, mode="bilinear", padding_mode="border", align_corners=True)
        return out[0, :, :, 0, 0].T

    def smoothness(self) -> torch.Tensor:
        """Mean squared difference of neighbouring texels of the texture (0 for the homogeneous model)."""
        if not self.textured:
            return self.log_sigma_a.new_zeros(())
        t = self.texture
        return sum(((t.diff(dim=d)) ** 2).mean() for d in (1, 2, 3)) / 3

    def raw(self, wi: torch.Tensor, x: torch.Tensor, wo: torch.Tensor, n: torch.Tensor) -> torch.Tensor:
        """S_hat (N, 3) for object-space wi, x, wo and the normal n at x, all (N, 3) (what fitting compares)."""
        if not self.has_surface():
            raise InputError("DipoleBSSRDF: no surface quadrature yet; call set_surface (points of the object)")
        textured = self.textured
        sigma_a, sigma_s = self.coefficients(x if textured else None)  # at the exit points (module docstring)
        eta = float(self.cfg.ior)
        if cpu_kernels.usable(wi, x, wo, n, sigma_a, sigma_s, self.points):  # the same within float32 rounding
            return cpu_kernels.dipole_eval(self, wi, x, wo, n, sigma_a, sigma_s, diffuse_fresnel_reflectance(eta))
        cos_o = (n * wo).sum(-1)
        out_factor = (1 - fresnel_dielectric(cos_o.clamp(min=0), eta)) * (cos_o > 0) / math.pi
        chunks = []
        batch = rows_per_slice(self.cfg.batch, x.device)
        for s in range(0, x.shape[0], batch):
            sl = slice(s, s + batch)
            cos_k = wi[sl] @ self.normals.T  # (B, K)
            lit = cos_k.clamp(min=0)
            ft = 1 - fresnel_dielectric(lit.reshape(-1), eta).reshape(lit.shape)
            weight = ft * lit * self.areas  # (B, K)
            r = torch.cdist(x[sl], self.points)
            a, s_ = (sigma_a[sl, None], sigma_s[sl, None]) if textured else (sigma_a, sigma_s)  # (B, 1, 3) or (3,)
            profile = dipole_profile(r, a, s_, eta)  # (B, K, 3)
            chunks.append(torch.einsum("bk,bkc->bc", weight, profile))
        return torch.cat(chunks, 0) * out_factor[:, None]

    def eval(self, q: Query) -> torch.Tensor:
        q.require("x", "wo", "n", who="DipoleBSSRDF.eval")
        dtype = self.points.dtype
        return self.raw(q.wi.to(dtype), q.x.to(dtype), q.wo.to(dtype), q.n.to(dtype)).to(q.dtype)

    def forward(self, q: Query) -> torch.Tensor:
        return self.eval(q)

    def size_bytes(self, precision: str = "fp16") -> int:
        """The six base coefficients, and the texture (6 R^3 values) with its box (6 float32) when textured (the
        quadrature is geometry, not material)."""
        if not self.textured:
            return storage_bytes(6 * float_bits(precision))
        return storage_bytes((6 + self.texture.numel()) * float_bits(precision) + 6 * 32)

    def flops(self) -> int:
        """Per query: a distance, the profile (~40 operations) and the weight for each surface point, plus the
        trilinear texture lookup (8 corners x 6 values, 2 operations each) when textured."""
        return 60 * self.cfg.samples + (96 if self.textured else 0)
