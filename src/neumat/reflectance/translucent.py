"""Ground truth for translucent objects: a heterogeneous scattering volume behind a rough dielectric
surface, path traced by Mitsuba 3 (`volpath`, llvm_ad_rgb), under distant light.

The quantity is NeuPreSS's subsurface-scattering function for distant light (TG et al., Eq. 4):
S_hat(wi; x, wo) = radiance leaving the surface point x towards wo when a directional light of unit
irradiance arrives from wi (wi points towards the light), external surface reflection excluded. Its unit
is 1/sr; the radiance under a distant environment is L(x, wo) = integral of L_env(wi) S_hat dwi over the
sphere (Eq. 5). All positions and directions are in object space.

External reflection is removed sample by sample: every path is traced twice with the same random
numbers, once with the real interior and once with a black (fully absorbing) interior, and the two are
subtracted. The first vertex (where external reflection happens) is identical in both, so the difference
is the subsurface part alone, unbiased.

The medium mixes two materials of Jensen et al. 2001 (reduced scattering and absorption in 1/mm, isotropic
phase function) by a smooth procedural noise, like the paper's dragon and Lucy; `size_mm` sets how many
millimetres the object's bounding-box diagonal spans and so how translucent it is.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ..core.checks import check_directions, check_finite, check_int, check_number, check_shape
from ..core.errors import InputError
from ..core.material import Material
from ..core.mitsuba import import_mitsuba
from ..core.query import Query
from ..io.ply import check_ply

#: reduced scattering sigma_s' and absorption sigma_a in 1/mm (RGB), Jensen et al. 2001, Table 1
JENSEN_MEDIA = {
    "marble": ((2.19, 2.62, 3.00), (0.0021, 0.0041, 0.0071)),
    "ketchup": ((0.18, 0.07, 0.03), (0.061, 0.97, 1.45)),
    "skimmilk": ((0.70, 1.22, 1.90), (0.0014, 0.0025, 0.0142)),
    "wholemilk": ((2.55, 3.21, 3.77), (0.0011, 0.0024, 0.014)),
    "skin1": ((0.74, 0.88, 1.01), (0.032, 0.17, 0.48)),
    "apple": ((2.29, 2.39, 1.97), (0.0030, 0.0034, 0.046)),
}
#: paths traced per Mitsuba call (bounds memory)
WAVEFRONT = 1 << 20
#: what `TranslucentObject.trace_environment` returns: subsurface only, everything, the surface reflection only
TRACE_PARTS = ("subsurface", "full", "reflection")


@dataclass
class TranslucentConfig:
    """A translucent object. Defaults: a small marble-and-ketchup sphere, moderately translucent."""

    #: "sphere" (unit sphere at the origin) or the path of a closed PLY triangle mesh (outward normals)
    shape: str = "sphere"
    #: the two Jensen et al. media mixed by the noise (keys of JENSEN_MEDIA)
    media: tuple[str, str] = ("marble", "ketchup")
    #: millimetres spanned by the bounding-box diagonal (smaller = more translucent)
    size_mm: float = 4.0
    #: spatial frequency of the mixing noise, in cycles per bounding-box diagonal
    noise_frequency: float = 3.0
    #: seed of the mixing noise
    noise_seed: int = 0
    #: resolution of the voxel grid that holds the medium over the bounding box
    grid_resolution: int = 32
    #: GGX roughness alpha of the dielectric surface (Walter et al. 2007)
    roughness: float = 0.3
    #: index of refraction inside (outside is 1)
    ior: float = 1.5
    #: longest path (the paper uses 5000)
    max_depth: int = 1000


class TranslucentObject(Material):
    """Path-traced S_hat(wi; x, wo) of a translucent object (see the module docstring).

    `eval(q)` needs q.x (points on the surface) and q.wo; it returns a Monte Carlo estimate with `spp`
    paths per query, 0 where wo looks at the back of the surface (wo . n <= 0) and raises InputError for
    points that are not on the surface. `trace` gives radiance along arbitrary rays (for images).
    """

    name = "translucent"
    full_sphere = True

    def __init__(self, config: TranslucentConfig | None = None, spp: int = 64, seed: int = 0) -> None:
        self.config = config = config or TranslucentConfig()
        _check_config(config)
        check_int(spp, "spp")
        self.spp, self.seed = spp, int(seed)
        self._calls = 0  # each trace call draws fresh random numbers (seeded by seed and this count)
        self.mi = mi = import_mitsuba()
        shape = _shape_dict(config)
        probe = mi.load_dict({"type": "scene", "shape": shape})
        box = probe.bbox()
        self.bbox_min = np.array(box.min, dtype=np.float64)
        self.bbox_max = np.array(box.max, dtype=np.float64)
        self.diagonal = float(np.linalg.norm(self.bbox_max - self.bbox_min))
        sigma_t, albedo = medium_grids(config, self.bbox_min, self.bbox_max)
        self._grids = (sigma_t, albedo, self.bbox_min, self.bbox_max)
        self.scenes = {interior: mi.load_dict(_scene_dict(config, shape, interior, *self._grids))
                       for interior in ("medium", "black")}
        self._params = {k: mi.traverse(s) for k, s in self.scenes.items()}
        self._light_key = next(k for k in self._params["medium"].keys() if k.startswith("light.") and "to_world" in k)

    def describe(self) -> str:
        c = self.config
        return f"translucent {Path(c.shape).name} {'+'.join(c.media)} {c.size_mm} mm, {self.spp} spp"

    # ---- queries on the surface -------------------------------------------------------------------------
    def first_hits(self, o: torch.Tensor, d: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """For rays o + t d (N, 3): (hit (N,) bool, x (M, 3), n (M, 3)) float64, the first surface points
        of the M rays that hit and the outward normals there."""
        si = self.scenes["black"].ray_intersect(self._ray(o, d))
        hit = torch.from_numpy(np.array(si.is_valid(), dtype=bool))
        x = torch.from_numpy(np.array(si.p, dtype=np.float64).T.copy())[hit]
        n = torch.from_numpy(np.array(si.n, dtype=np.float64).T.copy())[hit]
        return hit, x, n / n.norm(dim=-1, keepdim=True)

    def shading_normals(self, o: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
        """Outward unit shading normals (M, 3) float64 at the first surface points of the rays o + t d (N, 3) that
        hit (those of `first_hits`): the normals Mitsuba's BSDF uses (interpolated vertex normals on meshes)."""
        si = self.scenes["black"].ray_intersect(self._ray(o, d))
        hit = torch.from_numpy(np.array(si.is_valid(), dtype=bool))
        n = torch.from_numpy(np.array(si.sh_frame.n, dtype=np.float64).T.copy())[hit]
        return n / n.norm(dim=-1, keepdim=True)

    def occluded(self, o: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
        """(N,) bool: whether the rays o + t d (N, 3), t > 0, hit the object (Mitsuba's ray_test)."""
        return torch.from_numpy(np.array(self.scenes["black"].ray_test(self._ray(o, d)), dtype=bool))

    def surface(self, x: torch.Tensor, wo: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(visible (N,) bool, n (N, 3) outward normal) at surface points x (N, 3) seen from directions wo.

        Raises InputError when a point is farther than 1e-3 diagonals from the surface along wo."""
        eps = 1e-3 * self.diagonal
        o = x.detach().double().cpu() + eps * wo.detach().double().cpu()
        si = self.scenes["black"].ray_intersect(self._ray(o, -wo.detach().double().cpu()))
        hit = torch.from_numpy(np.array(si.is_valid(), dtype=bool))
        t = torch.from_numpy(np.array(si.t, dtype=np.float64))
        n = torch.from_numpy(np.array(si.n, dtype=np.float64).T.copy())
        on_surface = hit & ((t - eps).abs() <= 0.5 * eps)
        if not bool(on_surface.all()):
            bad = int((~on_surface).nonzero()[0])
            raise InputError(f"Query.x[{bad}] = {x[bad].tolist()} is not on the surface of {self.config.shape} "
                             "(no surface within 1e-3 diagonals along wo)")
        visible = (n * wo.double().cpu()).sum(-1) > 0
        return visible.to(x.device), (n / n.norm(dim=-1, keepdim=True)).to(x.device, x.dtype)

    def surface_samples(self, n: int, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """n points uniform over the object's surface area: positions (n, 3), outward unit normals (n, 3) and the
        area each stands for (n,) (the total area / n), float64; a quadrature over the surface."""
        check_int(n, "surface_samples n")
        mi = self.mi
        u = torch.rand(n, 2, generator=torch.Generator().manual_seed(int(seed)), dtype=torch.float64).numpy()
        shape = self.scenes["black"].shapes()[0]
        ps = shape.sample_position(0.0, mi.Point2f(u[:, 0].astype(np.float32), u[:, 1].astype(np.float32)))
        x = torch.from_numpy(np.array(ps.p, dtype=np.float64).T.copy())
        normal = torch.from_numpy(np.array(ps.n, dtype=np.float64).T.copy())
        pdf = np.broadcast_to(np.array(ps.pdf, dtype=np.float64).reshape(-1), (n,))  # uniform shapes give one value
        area = torch.from_numpy(1.0 / pdf / n)
        return x, normal / normal.norm(dim=-1, keepdim=True), area

    def surface_roughness(self, x: torch.Tensor) -> torch.Tensor:
        """GGX alpha (N,) float64 of the dielectric surface at surface points x (N, 3): config.roughness."""
        check_shape(x, "x", (x.shape[0], 3))
        return torch.full((x.shape[0],), float(self.config.roughness), dtype=torch.float64)

    def eval(self, q: Query) -> torch.Tensor:
        """S_hat(q.wi; q.x, q.wo), (N, 3) linear RGB per steradian (Monte Carlo, `spp` paths each)."""
        q.require("x", "wo", who="translucent object")
        visible, _ = self.surface(q.x, q.wo)
        out = torch.zeros(len(q), 3, dtype=torch.float64)
        lights, group = torch.unique(q.wi.double(), dim=0, return_inverse=True)
        for k in range(lights.shape[0]):
            idx = ((group == k) & visible.cpu()).nonzero().squeeze(1)
            if idx.numel():
                eps = 1e-3 * self.diagonal
                o = q.x[idx].double().cpu() + eps * q.wo[idx].double().cpu()
                out[idx] = self.trace(o, -q.wo[idx].double().cpu(), lights[k])
        return out.to(q.device, q.dtype)

    # ---- rays ---------------------------------------------------------------------------------------------
    def trace(self, o: torch.Tensor, d: torch.Tensor, light: torch.Tensor, spp: int | None = None) -> torch.Tensor:
        """Subsurface radiance (N, 3) float64 along rays o + t d (N, 3) under a unit-irradiance directional light
        arriving from `light` (3,) (towards the light); rays that miss the object give 0."""
        check_shape(o, "o", (o.shape[0], 3))
        check_shape(d, "d", (o.shape[0], 3))
        check_directions(d, "d")
        check_finite(o, "o")
        light = torch.as_tensor(light, dtype=torch.float64).reshape(3)
        check_directions(light[None], "light")
        spp = self.spp if spp is None else spp
        self._set_light(light)
        n = o.shape[0]
        rays_per_call = max(1, WAVEFRONT // spp)
        out = torch.zeros(n, 3, dtype=torch.float64)
        for start in range(0, n, rays_per_call):
            sl = slice(start, min(n, start + rays_per_call))
            oo = o[sl].repeat_interleave(spp, 0)
            dd = d[sl].repeat_interleave(spp, 0)
            seed = self._next_seed()
            diff = self._radiance("medium", oo, dd, seed) - self._radiance("black", oo, dd, seed)
            out[sl] = diff.reshape(-1, spp, 3).mean(1)
        return out

    def trace_environment(self, o: torch.Tensor, d: torch.Tensor, image: np.ndarray, seed: int = 0,
                          part: str = "subsurface") -> torch.Tensor:
        """Radiance (N, 3) float64 (its `part`, below) along rays o + t d (N, 3), one path each, under the equirectangular
        environment `image` (H, W, 3) (the mapping of `neumat.render.envmaps`, nearest-texel radiance as
        `EnvironmentMap` looks it up: each texel is repeated 4 x 4 before Mitsuba's bilinear lookup).

        part: "subsurface" (real minus black interior), "full" (the real interior alone: surface reflection plus
        subsurface, and the environment along rays that miss) or "reflection" (the black interior alone)."""
        if part not in TRACE_PARTS:
            raise InputError(f"trace_environment part: expected one of {TRACE_PARTS}, got {part!r}")
        image = np.asarray(image, dtype=np.float32)
        if image.ndim != 3 or image.shape[2] != 3 or not np.isfinite(image).all():
            raise InputError(f"environment image: expected a finite (H, W, 3) array, got shape {image.shape}")
        fine = np.repeat(np.repeat(image, 4, 0), 4, 1)
        scenes = {}
        for interior, scene in self.scenes.items():
            desc = _scene_dict(self.config, _shape_dict(self.config), interior, *self._grids)
            desc["light"] = {"type": "envmap", "bitmap": self.mi.Bitmap(fine)}
            scenes[interior] = self.mi.load_dict(desc)
        out = torch.zeros(o.shape[0], 3, dtype=torch.float64)
        for start in range(0, o.shape[0], WAVEFRONT):
            sl = slice(start, start + WAVEFRONT)
            call_seed = self._next_seed() + seed
            if part == "subsurface":
                out[sl] = (self._radiance("medium", o[sl], d[sl], call_seed, scenes)
                           - self._radiance("black", o[sl], d[sl], call_seed, scenes))
            else:
                out[sl] = self._radiance("medium" if part == "full" else "black", o[sl], d[sl], call_seed, scenes)
        return out

    def _radiance(self, interior: str, o: torch.Tensor, d: torch.Tensor, seed: int, scenes=None) -> torch.Tensor:
        mi = self.mi
        scene = (scenes or self.scenes)[interior]
        sampler = mi.load_dict({"type": "independent"})
        sampler.seed(seed, o.shape[0])
        value, _, _ = scene.integrator().sample(scene, sampler, self._ray(o, d))
        return torch.from_numpy(np.array(value, dtype=np.float64).T.copy())

    def _next_seed(self) -> int:
        """A seed for Mitsuba's sampler not used by an earlier call (paths of different calls independent)."""
        self._calls += 1
        return (self.seed * 1_000_003 + self._calls) % (1 << 31)

    def _set_light(self, light: torch.Tensor) -> None:
        """Point the directional emitter of both scenes so that light arrives from `light`."""
        to_world = self.mi.ScalarTransform4f().look_at(origin=[0, 0, 0], target=(-light).tolist(), up=_up(light))
        for params in self._params.values():
            params[self._light_key] = to_world
            params.update()

    def _ray(self, o: torch.Tensor, d: torch.Tensor):
        mi = self.mi
        return mi.Ray3f(mi.Point3f(_np3(o)), mi.Vector3f(_np3(d)))


def medium_grids(config: TranslucentConfig, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """sigma_t (1/object unit) and single-scattering albedo, each float32 (R, R, R, 3) indexed [z, y, x]
    over the box [lo, hi]: the two media mixed by a smoothstepped sum-of-sines noise."""
    r = config.grid_resolution
    axes = [np.linspace(lo[i], hi[i], r) for i in range(3)]
    z, y, x = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")
    p = np.stack([x, y, z], -1) / max(np.linalg.norm(hi - lo), 1e-12)
    rng = np.random.default_rng(config.noise_seed)
    noise = np.zeros(p.shape[:-1])
    for _ in range(6):
        k = rng.normal(size=3)
        k *= 2 * math.pi * config.noise_frequency / np.linalg.norm(k)
        noise += np.sin(p @ k + rng.uniform(0, 2 * math.pi))
    m = np.clip(0.5 + noise / (2 * math.sqrt(6) * 0.5), 0, 1)
    m = (m * m * (3 - 2 * m))[..., None]
    mm_per_unit = config.size_mm / max(np.linalg.norm(hi - lo), 1e-12)
    (s_a, a_a), (s_b, a_b) = (JENSEN_MEDIA[name] for name in config.media)
    sigma_s = (1 - m) * np.array(s_a) + m * np.array(s_b)
    sigma_a = (1 - m) * np.array(a_a) + m * np.array(a_b)
    sigma_t = (sigma_s + sigma_a) * mm_per_unit
    return sigma_t.astype(np.float32), (sigma_s / (sigma_s + sigma_a)).astype(np.float32)


def _check_config(c: TranslucentConfig) -> None:
    for name in c.media:
        if name not in JENSEN_MEDIA:
            raise InputError(f"translucent media: unknown medium {name!r}; known: {sorted(JENSEN_MEDIA)}")
    if len(c.media) != 2:
        raise InputError(f"translucent media: expected two medium names, got {c.media!r}")
    if c.shape != "sphere":
        path = Path(c.shape)
        if not path.is_file() or path.suffix.lower() != ".ply":
            raise InputError(f"translucent shape: expected 'sphere' or an existing .ply file, got {c.shape!r}")
        check_ply(path)
    for key in ("size_mm", "roughness", "noise_frequency"):
        check_number(getattr(c, key), f"translucent {key}", 0.0, strict=True)
    if not (isinstance(c.ior, (int, float)) and c.ior > 1):
        raise InputError(f"translucent ior: expected a number > 1, got {c.ior!r}")
    for key in ("grid_resolution", "max_depth"):
        check_int(getattr(c, key), f"translucent {key}", 2)


def _shape_dict(c: TranslucentConfig) -> dict:
    if c.shape == "sphere":
        return {"type": "sphere", "radius": 1.0}
    return {"type": "ply", "filename": str(c.shape)}


def _scene_dict(c, shape, interior, sigma_t, albedo, lo, hi) -> dict:
    mi = import_mitsuba()
    if interior == "black":
        medium = {"type": "homogeneous", "albedo": 0.0, "sigma_t": 1e6}
    else:
        to_world = mi.ScalarTransform4f().translate(lo.tolist()).scale((hi - lo).tolist())
        medium = {"type": "heterogeneous",
                  "sigma_t": {"type": "gridvolume", "grid": mi.VolumeGrid(sigma_t), "to_world": to_world},
                  "albedo": {"type": "gridvolume", "grid": mi.VolumeGrid(albedo), "to_world": to_world}}
    return {"type": "scene",
            "integrator": {"type": "volpath", "max_depth": c.max_depth},
            "object": {**shape, "interior": medium,
                       "bsdf": {"type": "roughdielectric", "distribution": "ggx", "alpha": c.roughness,
                                "int_ior": c.ior, "ext_ior": 1.0}},
            "light": {"type": "directional", "direction": [0, 0, -1], "irradiance": 1.0}}


def _up(w: torch.Tensor) -> list[float]:
    return [0.0, 1.0, 0.0] if abs(float(w[1])) < 0.9 else [1.0, 0.0, 0.0]


def _np3(t: torch.Tensor) -> np.ndarray:
    return np.ascontiguousarray(t.detach().cpu().numpy().astype(np.float32).T)

