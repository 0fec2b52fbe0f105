"""Ground truth for translucent objects: a heterogeneous scattering volume behind a rough dielectric
surface, path traced by Mitsuba 3 (`volpath`, llvm_ad_rgb), under distant light.

The quantity is NeuPreSS's subsurface-scattering function for distant light (TG et al., Eq. 4):
S_hat(wi; x, wo) = radiance leaving the surface point x towards wo when a directional light of unit
irradiance arrives from wi (wi points towards the light), external surface reflection excluded. Its unit
is 1/sr; the radiance under a distant environment is L(x, wo) = integral of L_env(wi) S_hat dwi over the
sphere (Eq. 5). All positions and directions are in object space.

Details: docs/notes/reflectance.md, section `neumat.reflectance.translucent`.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ..core.checks import check_directions, check_finite, check_int, check_number, check_shape
from ..core.config import config_from_dict
from ..core.errors import InputError
from ..core.material import Material
from ..core.mitsuba import import_mitsuba
from ..core.query import Query
from ..io.images import read_image
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
#: Mitsuba samplers `TranslucentConfig.sampler` accepts
SAMPLERS = ("independent", "orthogonal")
#: what `TranslucentObject.trace_environment` returns: subsurface only, everything, the surface reflection only
TRACE_PARTS = ("subsurface", "full", "reflection")


@dataclass
class InnerShape:
    """A shape inside the translucent volume (object units): a sphere of radius `scale` at `center`, or a closed
    PLY mesh placed by x -> scale * x + center. It holds its own `medium` behind an `ior` interface, or, with
    no medium, is an opaque diffuse surface with `albedo` (a constant or an image texture)."""

    #: "sphere", "cube" (Mitsuba's [-1, 1]^3) or the path of a closed PLY triangle mesh (outward normals)
    shape: str = "sphere"
    #: the sphere's centre / the cube's / the mesh's translation
    center: tuple[float, float, float] = (0.0, 0.0, 0.0)
    #: the sphere's radius / the cube's half side / the mesh's uniform scale
    scale: float = 0.3
    #: None: opaque diffuse surface; a JENSEN_MEDIA name (homogeneous, at the object's size_mm scale); or
    #: "noise": the noise mix of the object's `media` (albedo texture included; the outer medium itself unless
    #: the object's `outer_medium` names another)
    medium: str | None = None
    #: with a medium: None for an index-matched interface (Mitsuba `null` BSDF), else a smooth `dielectric`
    #: with this index inside and the outer `ior` outside
    ior: float | None = None
    #: without a medium: the diffuse reflectance, linear RGB in [0, 1]
    albedo: tuple[float, float, float] = (0.5, 0.5, 0.5)
    #: without a medium: an image (sRGB-decoded) replacing `albedo`, on the shape's Mitsuba uv (the sphere's
    #: latitude-longitude uv; a mesh must carry uv in its PLY file)
    albedo_texture: str | None = None


@dataclass
class TranslucentConfig:
    """A translucent object. Defaults: a small marble-and-ketchup sphere, moderately translucent."""

    #: "sphere" (unit sphere at the origin), "cube" (Mitsuba's cube, [-1, 1]^3) or the path of a closed PLY
    #: triangle mesh (outward normals)
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
    #: longest path, in scattering events and surface interactions (the paper's 5000)
    max_depth: int = 5000
    #: depth from which volpath plays Russian roulette (survival min(max throughput x eta^2, 0.95)); unbiased at
    #: any value. 20 (the default) against Mitsuba's 5: 0.83x the variance at the same CPU time
    #: (benchmarks/studies/neupress/results/neupress_variance.md); traces made before this field existed used 5
    rr_depth: int = 20
    #: shapes inside the volume (seeds in a grape, a bunny in a cube, ice in a drink); dicts are read as InnerShape
    inner: tuple[InnerShape, ...] = ()
    #: an image whose first channel (0..1, read without sRGB decoding) sets the surface's GGX alpha through
    #: `roughness_range`, in the `latlong_uv` projection; None: the constant `roughness`
    roughness_texture: str | None = None
    #: alpha at texture values 0 and 1
    roughness_range: tuple[float, float] = (0.05, 0.5)
    #: an RGB image (sRGB-decoded) multiplying the medium grid's single-scattering albedo, looked up in the
    #: `latlong_uv` projection of each voxel's direction from the box centre (the product is clipped to [0, 1])
    albedo_texture: str | None = None
    #: None: the outer volume is the noise mix of `media` (the default); a JENSEN_MEDIA name: the outer volume is
    #: that medium, homogeneous, and the noise mix fills only the inner shapes whose medium is "noise" (the
    #: paperweight: a weakly scattering block around a marble bunny)
    outer_medium: str | None = None
    #: multiplies the outer homogeneous medium's sigma_s and sigma_a (its albedo unchanged; < 1: thinner, more
    #: transparent); only with `outer_medium`
    outer_density: float = 1.0
    #: next-event estimation (a shadow ray towards the light) at scattering events inside the object: Mitsuba's
    #: `sample_emitters` of the interior media. The rough dielectric surface blocks every such shadow ray (volpath's
    #: shadow rays pass only null interfaces), so it adds exactly 0 and only costs the tracking to the surface; False
    #: (the default) keeps the mean (light enters through the surface's own emitter sampling) at 15-19 % less CPU on
    #: the bunny (benchmarks/studies/neupress/results/neupress_variance.md). True: Mitsuba's default, what traces
    #: made before this field existed used (their recorded objects now load with False: same mean)
    interior_emitter_sampling: bool = False
    #: Mitsuba's sampler of `trace`'s `spp` paths per ray, one pixel's samples: "independent", or "orthogonal"
    #: (Mitsuba's jittered orthogonal arrays, strength 2; needs `spp` to be the square of a prime: 4, 9, 25, 49, 121,
    #: 169, ...; `trace_environment`'s single paths stay independent). Both are unbiased
    sampler: str = "independent"

    def __post_init__(self) -> None:
        if not isinstance(self.inner, (list, tuple)):
            raise InputError(f"translucent inner: expected a list of inner shapes, got {self.inner!r}")
        self.inner = tuple(config_from_dict(InnerShape, s) if isinstance(s, dict) else s for s in self.inner)


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
        _check_spp(config, spp)
        self.spp, self.seed = spp, int(seed)
        #: trace calls so far: each draws fresh random numbers seeded by (seed, this count); a resumed trace sets it
        self.trace_calls = 0
        #: CPU seconds of this process (all its threads, Mitsuba's included) spent in `trace` so far: what traced
        #: observations cost; a resumed trace restores it (NaN where its checkpoint did not record it)
        self.trace_cpu_seconds = 0.0
        self.mi = mi = import_mitsuba()
        shape = outer_shape_dict(config)
        probe = mi.load_dict({"type": "scene", "shape": shape})
        box = probe.bbox()
        self.bbox_min = np.array(box.min, dtype=np.float64)
        self.bbox_max = np.array(box.max, dtype=np.float64)
        self.diagonal = float(np.linalg.norm(self.bbox_max - self.bbox_min))
        _check_inner(config, self.bbox_min, self.bbox_max)
        sigma_t, albedo = medium_grids(config, self.bbox_min, self.bbox_max)
        self._grids = (sigma_t, albedo, self.bbox_min, self.bbox_max)
        self.scenes = {interior: mi.load_dict(_scene_dict(config, shape, interior, *self._grids))
                       for interior in ("medium", "black")}
        self._params = {k: mi.traverse(s) for k, s in self.scenes.items()}
        self._light_key = next(k for k in self._params["medium"].keys() if k.startswith("light.") and "to_world" in k)

    def describe(self) -> str:
        c = self.config
        outer = "" if c.outer_medium is None else f" in {c.outer_medium} x{c.outer_density:g}"
        return f"translucent {Path(c.shape).name} {'+'.join(c.media)}{outer} {c.size_mm} mm, {self.spp} spp"

    # ---- queries on the surface -------------------------------------------------------------------------
    def surface_roughness(self, x: torch.Tensor) -> torch.Tensor:
        """GGX alpha (N,) float64 of the outer surface at surface points x (N, 3): `config.roughness`, or the
        roughness texture's value there (on a mesh, Mitsuba interpolates the vertices' values linearly over
        each triangle, so inside a triangle the two differ by the texture's variation across it)."""
        check_shape(x, "x", (x.shape[0], 3))
        c = self.config
        if c.roughness_texture is None:
            return torch.full((x.shape[0],), float(c.roughness), dtype=torch.float64, device=x.device)
        centre = (self.bbox_min + self.bbox_max) / 2
        alpha = _roughness_at(c, x.detach().double().cpu().numpy() - centre)
        return torch.from_numpy(alpha).to(x.device)

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
    def trace(self, o: torch.Tensor, d: torch.Tensor, light: torch.Tensor, spp: int | None = None,
              seed: int | None = None) -> torch.Tensor:
        """Subsurface radiance (N, 3) float64 along rays o + t d (N, 3) under a unit-irradiance directional light
        arriving from `light` (3,) (towards the light); rays that miss the object give 0.

        seed: None draws fresh paths (from the object's seed and a call counter); an integer >= 0 makes the paths
        a function of (seed, rays) alone, so that a resumed online fit re-traces the same batches."""
        check_shape(o, "o", (o.shape[0], 3))
        check_shape(d, "d", (o.shape[0], 3))
        check_directions(d, "d")
        check_finite(o, "o")
        light = torch.as_tensor(light, dtype=torch.float64).reshape(3)
        check_directions(light[None], "light")
        spp = self.spp if spp is None else spp
        _check_spp(self.config, spp)
        if seed is not None:
            check_int(seed, "trace seed", 0)
        started = time.process_time()
        self._set_light(light)
        n = o.shape[0]
        rays_per_call = max(1, WAVEFRONT // spp)
        out = torch.zeros(n, 3, dtype=torch.float64)
        for start in range(0, n, rays_per_call):
            sl = slice(start, min(n, start + rays_per_call))
            oo = o[sl].repeat_interleave(spp, 0)
            dd = d[sl].repeat_interleave(spp, 0)
            call = self._next_seed() if seed is None else call_seed(seed, start)
            diff = self._radiance("medium", oo, dd, call, spp=spp) - self._radiance("black", oo, dd, call, spp=spp)
            out[sl] = diff.reshape(-1, spp, 3).mean(1)
        self.trace_cpu_seconds += time.process_time() - started
        # not clamped: the difference is unbiased but one ray's mean can be negative (on a concave object a path
        # that reflects off the surface and meets it again diverges between the two traces); clamping would bias it
        return out

    def noise_variance(self, q: Query) -> torch.Tensor:
        """Variance (N, 3) float64 of `eval(q)`'s Monte Carlo estimate (`spp` paths), unbiased: each query is
        evaluated twice with independent paths, a and b, giving (a - b)^2 / 2. Costs two `eval` calls."""
        a, b = self.eval(q).double(), self.eval(q).double()
        return (a - b) ** 2 / 2

    def trace_environment(self, o: torch.Tensor, d: torch.Tensor, image: np.ndarray, seed: int = 0,
                          part: str = "subsurface") -> torch.Tensor:
        """Radiance (N, 3) float64 (its `part`, below) along rays o + t d (N, 3), one path each, under the
        equirectangular environment `image` (H, W, 3) (the mapping of `neumat.render.envmaps`, nearest-texel radiance as
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
            desc = _scene_dict(self.config, outer_shape_dict(self.config), interior, *self._grids)
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

    def _radiance(self, interior: str, o: torch.Tensor, d: torch.Tensor, seed: int, scenes=None,
                  spp: int = 1) -> torch.Tensor:
        """One path per ray; with `spp` > 1 the rays come in runs of `spp` equal rays (`repeat_interleave`), each run
        one pixel's samples of the config's sampler (Mitsuba numbers lanes k spp .. k spp + spp - 1 as pixel k)."""
        mi = self.mi
        scene = (scenes or self.scenes)[interior]
        if spp > 1 and self.config.sampler != "independent":
            sampler = mi.load_dict({"type": self.config.sampler, "sample_count": spp})
            sampler.set_samples_per_wavefront(spp)
        else:
            sampler = mi.load_dict({"type": "independent"})
        sampler.seed(seed, o.shape[0])
        value, _, _ = scene.integrator().sample(scene, sampler, self._ray(o, d))
        return torch.from_numpy(np.array(value, dtype=np.float64).T.copy())

    def _next_seed(self) -> int:
        """A seed for Mitsuba's sampler not used by an earlier call (paths of different calls independent)."""
        self.trace_calls += 1
        return (self.seed * 1_000_003 + self.trace_calls) % (1 << 31)

    def _set_light(self, light: torch.Tensor) -> None:
        """Point the directional emitter of both scenes so that light arrives from `light`."""
        to_world = self.mi.ScalarTransform4f().look_at(origin=[0, 0, 0], target=(-light).tolist(), up=_up(light))
        for params in self._params.values():
            params[self._light_key] = to_world
            params.update()

    def _ray(self, o: torch.Tensor, d: torch.Tensor):
        mi = self.mi
        return mi.Ray3f(mi.Point3f(_np3(o)), mi.Vector3f(_np3(d)))


def _check_spp(c: TranslucentConfig, spp) -> None:
    """spp is a positive integer, and the square of a prime with the orthogonal sampler (InputError otherwise)."""
    check_int(spp, "translucent spp")
    r = math.isqrt(spp)
    if c.sampler == "orthogonal" and not (r * r == spp and r >= 2 and all(r % k for k in range(2, math.isqrt(r) + 1))):
        raise InputError(f"translucent sampler 'orthogonal': spp must be the square of a prime (4, 9, 25, 49, 121, "
                         f"169, ...), got {spp}")


def call_seed(*keys: int) -> int:
    """A 31-bit seed for Mitsuba's sampler that is a hash of the integers `keys` (e.g. a fit's seed, its step and a
    view): reproducible, and unrelated to the call-counter seeds of `TranslucentObject._next_seed` in practice."""
    return int(np.random.SeedSequence([int(k) for k in keys]).generate_state(1)[0]) & 0x7FFFFFFF


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
    albedo = sigma_s / (sigma_s + sigma_a)
    if config.albedo_texture is not None:  # each voxel looks the texture up in its direction from the centre
        d = np.stack([x, y, z], -1).reshape(-1, 3) - (lo + hi) / 2
        texture = lookup_texture(read_image(config.albedo_texture), latlong_uv(d))
        albedo = np.clip(albedo * texture.reshape(albedo.shape), 0, 1)
    return sigma_t.astype(np.float32), albedo.astype(np.float32)


def latlong_uv(d: np.ndarray) -> np.ndarray:
    """Texture coordinates (N, 2) in [0, 1) x [0, 1] of directions d (N, 3) (any length > 0): u = atan2(y, x) / 2 pi
    (mod 1), v = acos(z) / pi; Mitsuba's uv of the unit sphere."""
    d = d / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-30)
    u = np.mod(np.arctan2(d[..., 1], d[..., 0]) / (2 * math.pi), 1.0)
    return np.stack([u, np.arccos(np.clip(d[..., 2], -1, 1)) / math.pi], -1)


def lookup_texture(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear lookup (N, C) float64 of an image (H, W, C) at uv (N, 2) (u along the width, v down the height,
    texel centres at (i + 0.5) / size), wrapping around both edges, as Mitsuba's bilinear `bitmap`."""
    h, w = image.shape[:2]
    px, py = uv[:, 0] * w - 0.5, uv[:, 1] * h - 0.5
    x0, y0 = np.floor(px), np.floor(py)
    fx, fy = (px - x0)[:, None], (py - y0)[:, None]
    x0, y0 = x0.astype(np.int64), y0.astype(np.int64)
    img = image.astype(np.float64)

    def at(yy, xx):
        return img[np.mod(yy, h), np.mod(xx, w)]
    return ((1 - fy) * ((1 - fx) * at(y0, x0) + fx * at(y0, x0 + 1))
            + fy * ((1 - fx) * at(y0 + 1, x0) + fx * at(y0 + 1, x0 + 1)))


def _alpha_image(c: TranslucentConfig) -> np.ndarray:
    """The roughness texture as GGX alpha, float32 (H, W, 1)."""
    lo, hi = c.roughness_range
    return (lo + (hi - lo) * read_image(c.roughness_texture, srgb=False)[..., :1]).astype(np.float32)


def _roughness_at(c: TranslucentConfig, d: np.ndarray) -> np.ndarray:
    """Textured alpha (N,) float64 in the directions d (N, 3) from the bounding-box centre."""
    return lookup_texture(_alpha_image(c), latlong_uv(d))[:, 0]


def _check_inner(c: TranslucentConfig, lo: np.ndarray, hi: np.ndarray) -> None:
    """Inner shapes lie inside the outer bounding box and their boxes do not overlap."""
    boxes = []
    for k, s in enumerate(c.inner):
        who = f"translucent inner[{k}]"
        if s.shape in ("sphere", "cube"):
            box = (np.array(s.center) - s.scale, np.array(s.center) + s.scale)
        else:
            mesh = import_mitsuba().load_dict(_inner_shape_dict(s))
            if s.albedo_texture is not None and not mesh.has_vertex_texcoords():
                raise InputError(f"{who}: albedo_texture needs uv coordinates in {s.shape} (it has none)")
            b = mesh.bbox()
            box = (np.array(b.min, dtype=np.float64), np.array(b.max, dtype=np.float64))
        if np.any(box[0] < lo) or np.any(box[1] > hi):
            raise InputError(f"{who}: its bounding box {np.round(box[0], 4).tolist()}..{np.round(box[1], 4).tolist()} "
                             f"is not inside the object's {np.round(lo, 4).tolist()}..{np.round(hi, 4).tolist()}")
        for j, other in enumerate(boxes):
            if np.all(box[0] < other[1]) and np.all(other[0] < box[1]):
                raise InputError(f"{who}: its bounding box overlaps inner[{j}]'s (nested media must not overlap)")
        boxes.append(box)


#: the analytic / built-in shapes `shape` may name besides a PLY file
BUILTIN_SHAPES = ("sphere", "cube")


def _check_shape(shape: str, who: str) -> None:
    """InputError naming `who` unless `shape` is "sphere", "cube" or an existing, readable .ply file."""
    if shape not in BUILTIN_SHAPES:
        path = Path(shape)
        if not path.is_file() or path.suffix.lower() != ".ply":
            raise InputError(f"{who}: expected 'sphere', 'cube' or an existing .ply file, got {shape!r}")
        check_ply(path)


def _check_inner_fields(k: int, s) -> None:
    who = f"translucent inner[{k}]"
    if not isinstance(s, InnerShape):
        raise InputError(f"{who}: expected an InnerShape or a dict of its fields, got {s!r}")
    _check_shape(s.shape, f"{who} shape")
    check_number(s.scale, f"{who} scale", 0.0, strict=True)
    if len(s.center) != 3:
        raise InputError(f"{who} center: expected 3 numbers, got {s.center!r}")
    for v in s.center:
        check_number(v, f"{who} center")
    if s.medium is None:
        if s.ior is not None:
            raise InputError(f"{who} ior: an opaque inner shape (no medium) has no interface ior, got {s.ior!r}")
        if len(s.albedo) != 3 or not all(isinstance(v, (int, float)) and 0 <= v <= 1 for v in s.albedo):
            raise InputError(f"{who} albedo: expected 3 numbers in [0, 1], got {s.albedo!r}")
        if s.albedo_texture is not None:
            read_image(s.albedo_texture)  # raises on a missing or unreadable image
    else:
        if s.medium != "noise" and s.medium not in JENSEN_MEDIA:
            raise InputError(f"{who} medium: expected 'noise' or one of {sorted(JENSEN_MEDIA)}, got {s.medium!r}")
        if s.ior is not None:
            check_number(s.ior, f"{who} ior", 0.0, strict=True)
        if s.albedo_texture is not None:
            raise InputError(f"{who} albedo_texture: only an opaque inner shape (no medium) has one")


def _check_config(c: TranslucentConfig) -> None:
    for name in c.media:
        if name not in JENSEN_MEDIA:
            raise InputError(f"translucent media: unknown medium {name!r}; known: {sorted(JENSEN_MEDIA)}")
    if len(c.media) != 2:
        raise InputError(f"translucent media: expected two medium names, got {c.media!r}")
    _check_shape(c.shape, "translucent shape")
    for key in ("size_mm", "roughness", "noise_frequency"):
        check_number(getattr(c, key), f"translucent {key}", 0.0, strict=True)
    if not (isinstance(c.ior, (int, float)) and c.ior > 1):
        raise InputError(f"translucent ior: expected a number > 1, got {c.ior!r}")
    for key in ("grid_resolution", "max_depth"):
        check_int(getattr(c, key), f"translucent {key}", 2)
    check_int(c.rr_depth, "translucent rr_depth", 1)
    for k, s in enumerate(c.inner):
        _check_inner_fields(k, s)
    lo, hi = c.roughness_range
    check_number(lo, "translucent roughness_range[0]", 0.0, strict=True)
    check_number(hi, "translucent roughness_range[1]", 0.0, strict=True)
    for key in ("roughness_texture", "albedo_texture"):
        if getattr(c, key) is not None:
            read_image(getattr(c, key))  # raises on a missing or unreadable image
    if c.outer_medium is not None and c.outer_medium not in JENSEN_MEDIA:
        raise InputError(f"translucent outer_medium: expected None (the noise mix) or one of {sorted(JENSEN_MEDIA)}, "
                         f"got {c.outer_medium!r}")
    check_number(c.outer_density, "translucent outer_density", 0.0, strict=True)
    if c.outer_medium is None and c.outer_density != 1.0:
        raise InputError(f"translucent outer_density: scales a homogeneous outer_medium, but outer_medium is None "
                         f"(got outer_density {c.outer_density!r})")
    if c.sampler not in SAMPLERS:
        raise InputError(f"translucent sampler: expected one of {SAMPLERS}, got {c.sampler!r}")
    if not isinstance(c.interior_emitter_sampling, bool):
        raise InputError(f"translucent interior_emitter_sampling: expected true or false, got "
                         f"{c.interior_emitter_sampling!r}")


def outer_shape_dict(c: TranslucentConfig) -> dict:
    """The `mi.load_dict` entry of the object's outer surface in object space (sphere, cube or PLY mesh), without its
    BSDF and media: the tracer and the Mitsuba integrator (`integrations.mitsuba_translucent`) build on it."""
    if c.shape == "sphere":
        return {"type": "sphere", "radius": 1.0}
    if c.shape == "cube":
        return {"type": "cube"}
    return {"type": "ply", "filename": str(c.shape)}


def _scene_dict(c, shape, interior, sigma_t, albedo, lo, hi) -> dict:
    """The Mitsuba scene of config c with the `interior` "medium" (the grids sigma_t and albedo over [lo, hi] and
    the inner shapes) or "black" (fully absorbing; nothing reaches inner shapes there, so they are left out)."""
    mi = import_mitsuba()
    mm_per_unit = c.size_mm / max(np.linalg.norm(hi - lo), 1e-12)
    nee = bool(c.interior_emitter_sampling)
    if interior == "black":
        medium = noise = {"type": "homogeneous", "albedo": 0.0, "sigma_t": 1e6, "sample_emitters": nee}
    else:
        to_world = mi.ScalarTransform4f().translate(lo.tolist()).scale((hi - lo).tolist())
        noise = mi.load_dict({"type": "heterogeneous",  # one object: the inner shapes' exterior too
                              "sigma_t": {"type": "gridvolume", "grid": mi.VolumeGrid(sigma_t), "to_world": to_world},
                              "albedo": {"type": "gridvolume", "grid": mi.VolumeGrid(albedo), "to_world": to_world},
                              "sample_emitters": nee})
        medium = noise if c.outer_medium is None else mi.load_dict(
            homogeneous_medium(c.outer_medium, mm_per_unit * c.outer_density, nee))
    desc = {"type": "scene",
            "integrator": {"type": "volpath", "max_depth": c.max_depth, "rr_depth": c.rr_depth},
            "object": _outer_shape(c, shape, medium, lo, hi),
            "light": {"type": "directional", "direction": [0, 0, -1], "irradiance": 1.0}}
    if interior != "black":
        for k, s in enumerate(c.inner):
            desc[f"inner_{k}"] = _inner_dict(c, s, medium, noise, mm_per_unit)
    return desc


def _outer_shape(c, shape: dict, medium, lo, hi):
    """The outer surface (a dict, or a loaded mesh carrying the per-vertex alpha of a roughness texture)."""
    mi = import_mitsuba()
    bsdf = {"type": "roughdielectric", "distribution": "ggx", "alpha": c.roughness, "int_ior": c.ior, "ext_ior": 1.0}
    if c.roughness_texture is None:
        return {**shape, "interior": medium, "bsdf": bsdf}
    if shape["type"] == "sphere":  # Mitsuba's sphere uv is latlong_uv of the direction from its centre
        bsdf["alpha"] = {"type": "bitmap", "bitmap": mi.Bitmap(_alpha_image(c)), "raw": True,
                         "filter_type": "bilinear", "wrap_mode": "repeat"}
        return {**shape, "interior": medium, "bsdf": bsdf}
    bsdf["alpha"] = {"type": "mesh_attribute", "name": "vertex_alpha"}
    mesh = mi.load_dict({**shape, "interior": medium, "bsdf": bsdf})
    vertices = np.array(mesh.vertex_positions_buffer(), dtype=np.float64).reshape(-1, 3)
    mesh.add_attribute("vertex_alpha", 1, _roughness_at(c, vertices - (lo + hi) / 2).astype(np.float32))
    return mesh


def _inner_shape_dict(s: InnerShape) -> dict:
    if s.shape == "sphere":
        return {"type": "sphere", "center": list(s.center), "radius": float(s.scale)}
    if s.shape == "cube":
        return {"type": "cube", "to_world": import_mitsuba().ScalarTransform4f().translate(list(s.center))
                .scale(float(s.scale))}
    to_world = import_mitsuba().ScalarTransform4f().translate(list(s.center)).scale(float(s.scale))
    return {"type": "ply", "filename": str(s.shape), "to_world": to_world}


def homogeneous_medium(name: str, mm_per_unit: float, sample_emitters: bool = False) -> dict:
    """Mitsuba `homogeneous` medium of the JENSEN_MEDIA entry `name` with lengths in object units (`mm_per_unit`
    millimetres each), `sample_emitters` as `TranslucentConfig.interior_emitter_sampling`. Mitsuba's rgb values lie
    in [0, 1], so sigma_t is a colour times its largest component."""
    sigma_s, sigma_a = (np.array(v) for v in JENSEN_MEDIA[name])
    sigma_t = (sigma_s + sigma_a) * mm_per_unit
    return {"type": "homogeneous", "scale": float(sigma_t.max()), "sample_emitters": sample_emitters,
            "sigma_t": {"type": "rgb", "value": (sigma_t / sigma_t.max()).tolist()},
            "albedo": {"type": "rgb", "value": (sigma_s / (sigma_s + sigma_a)).tolist()}}


def _inner_dict(c: TranslucentConfig, s: InnerShape, outer_medium, noise_medium, mm_per_unit: float) -> dict:
    """An inner shape in the outer medium: an opaque diffuse surface, or its own medium (`noise_medium` for
    "noise") behind a null (index-matched) or smooth dielectric interface."""
    mi = import_mitsuba()
    desc = {**_inner_shape_dict(s), "exterior": outer_medium}
    if s.medium is None:
        reflectance = ({"type": "rgb", "value": list(s.albedo)} if s.albedo_texture is None else
                       {"type": "bitmap", "bitmap": mi.Bitmap(read_image(s.albedo_texture)), "raw": True})
        desc["bsdf"] = {"type": "diffuse", "reflectance": reflectance}
        return desc
    if s.medium == "noise":
        desc["interior"] = noise_medium
    else:
        desc["interior"] = homogeneous_medium(s.medium, mm_per_unit, bool(c.interior_emitter_sampling))
    desc["bsdf"] = ({"type": "null"} if s.ior is None else
                    {"type": "dielectric", "int_ior": float(s.ior), "ext_ior": float(c.ior)})
    return desc


def _up(w: torch.Tensor) -> list[float]:
    return [0.0, 1.0, 0.0] if abs(float(w[1])) < 0.9 else [1.0, 0.0, 0.0]


def _np3(t: torch.Tensor) -> np.ndarray:
    return np.ascontiguousarray(t.detach().cpu().numpy().astype(np.float32).T)



#: the Stanford bunny of the reference data (`neumat.io.shared_data`), the paperweight's inner shape
PAPERWEIGHT_MESH = "mesh/stanford_bunny_35k.ply"


def paperweight_config(mesh: str | Path | None = None, fill: float = 0.7) -> TranslucentConfig:
    """NeuPreSS's "Paperweight" (TG et al., Table 1): a cube of a weakly scattering medium holding the Stanford
    bunny made of marble with a solid-texture variation of its optical properties. Built from what exists here: the
    cube [-1, 1]^3 is skim milk (Jensen et al.) at 5% density (optical depth 0.1-0.3 across); the bunny (`mesh`,
    default the 35k-vertex one of the reference data) is centred, its largest side `fill` of the cube's, behind an
    index-matched interface, filled with the noise mix of marble and skin1 (darker, warmer veins) at 6 cycles per
    cube diagonal; 6 mm across the cube's diagonal; the surface is the default rough dielectric (GGX alpha 0.3,
    ior 1.5). The paper does not give these numbers; they are choices."""
    from ..io.shared_data import resolve_data_path, shared_data_candidates
    path = resolve_data_path(PAPERWEIGHT_MESH) if mesh is None else Path(mesh)
    if not path.is_file():
        where = "" if mesh is not None else f" (looked in {', '.join(map(str, shared_data_candidates()))}; set " \
                                            "NEUMAT_SHARED_DATA)"
        raise InputError(f"paperweight: the bunny mesh {str(path)!r} does not exist{where}")
    _check_shape(str(path), "paperweight mesh")
    check_number(fill, "paperweight fill", 0.0, strict=True)
    if fill >= 1:
        raise InputError("paperweight fill: expected a number in (0, 1) (the mesh must fit inside the cube), "
                         f"got {fill!r}")
    box = import_mitsuba().load_dict({"type": "ply", "filename": str(path)}).bbox()
    lo, hi = np.array(box.min, dtype=np.float64), np.array(box.max, dtype=np.float64)
    scale = 2 * fill / float((hi - lo).max())
    center = tuple(round(float(v), 6) for v in -scale * (lo + hi) / 2)
    bunny = InnerShape(shape=str(path), center=center, scale=round(scale, 6), medium="noise")
    return TranslucentConfig(shape="cube", media=("marble", "skin1"), size_mm=6.0, noise_frequency=6.0,
                             grid_resolution=48, outer_medium="skimmilk", outer_density=0.05, inner=(bunny,))
