"""Lights in world space (y-up): point, directional, constant environment, importance-sampled environment map.

Spec strings (grammar in `neumat.render.spec`):
  point[:x/y/z][,intensity=I]       point light at (x, y, z) (default 2/2/2); intensity in W/sr, a number or
                                    r/g/b (default pi |position|^2: irradiance pi at the origin)
  dir[:x/y/z][,irradiance=E]        directional light arriving from direction (x, y, z) (normalised; default
                                    1/1/1); irradiance at normal incidence (default pi)
  const[:VALUE]                     constant environment of radiance VALUE (number or r/g/b, default 1)
  env:PATH[,scale=s,rotation=deg]   equirectangular .hdr / .exr map, radiance times scale, rotated about +y
  env:sky[,sun_elevation=deg,sun_azimuth=deg,sun_irradiance=E,sky_irradiance=E,width=W,scale=s,rotation=deg]
                                    procedural sky and sun (see `envmaps.sky_envmap`)
A white Lambert surface of albedo a facing a "dir" or "point" light at the default irradiance pi renders
to a * cos(theta).
"""
from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass

import torch

from ..core.errors import InputError
from ..color.tonemap import LUMINANCE
from ..warp.sphere import sample_uniform_sphere
from ..warp.alias import AliasTable
from .envmaps import downsample_envmap, read_envmap, sky_envmap
from .spec import as_float, as_vector, check_options, parse_option_value, parse_spec, unknown_name

LIGHT_FORMS = ["point[:x/y/z]", "dir[:x/y/z]", "const:VALUE", "env:PATH", "env:sky"]


@dataclass
class LightSample:
    """N light samples for N shading points.

    wi: (N, 3) unit world direction towards the light; radiance: (N, 3) incident radiance along wi (for
    delta lights the irradiance it delivers at normal incidence); pdf: (N,) solid-angle density (1 for
    delta lights, 0 where sampling failed); distance: (N,) to the light (inf for distant lights).
    """

    wi: torch.Tensor
    radiance: torch.Tensor
    pdf: torch.Tensor
    distance: torch.Tensor


class Light(ABC):
    """Base class. Delta lights (point, directional) can only be reached by light sampling."""

    is_delta = False

    @abstractmethod
    def sample(self, p: torch.Tensor, u: torch.Tensor) -> LightSample:
        """Sample a direction towards the light from points p (N, 3) with uniform numbers u (N, 2) (float32 or
        float64); outputs take the dtype of p."""

    def eval(self, d: torch.Tensor) -> torch.Tensor:
        """Radiance (N, 3) arriving from unit directions d (N, 3) (0 for delta lights)."""
        return torch.zeros_like(d)

    def pdf(self, d: torch.Tensor) -> torch.Tensor:
        """Solid-angle density (N,) with which `sample` produces d (N, 3) (0 for delta lights)."""
        return torch.zeros_like(d[:, 0])

    def eval_pdf(self, d: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """`eval(d)` and `pdf(d)` together (one lookup where they share work)."""
        return self.eval(d), self.pdf(d)

    def background(self, d: torch.Tensor) -> torch.Tensor:
        """What a camera ray with direction d (N, 3) that hits nothing sees: the environment, or black."""
        return self.eval(d)


class PointLight(Light):
    """Isotropic point light at `position` with radiant intensity `intensity` (RGB, W/sr)."""

    is_delta = True

    def __init__(self, position, intensity, device=None) -> None:
        self.position = torch.tensor(position, dtype=torch.float32, device=device)
        self.intensity = torch.tensor(intensity, dtype=torch.float32, device=device)

    def sample(self, p: torch.Tensor, u: torch.Tensor) -> LightSample:
        vec = self.position.to(p.dtype) - p
        dist = vec.norm(dim=-1)
        safe = dist.clamp(min=1e-12)
        return LightSample(vec / safe[:, None], self.intensity.to(p.dtype) / (safe * safe)[:, None],
                           torch.ones_like(dist), dist)


class DirectionalLight(Light):
    """Distant light arriving from unit direction `direction`, with irradiance `irradiance` (RGB) at normal
    incidence."""

    is_delta = True

    def __init__(self, direction, irradiance, device=None) -> None:
        d = torch.tensor(direction, dtype=torch.float32, device=device)
        if not d.norm() > 0:
            raise InputError(f"dir light: direction must be non-zero, got {direction}")
        self.direction = d / d.norm()
        self.irradiance = torch.tensor(irradiance, dtype=torch.float32, device=device)

    def sample(self, p: torch.Tensor, u: torch.Tensor) -> LightSample:
        n = p.shape[0]
        ones = torch.ones(n, dtype=p.dtype, device=p.device)
        return LightSample(self.direction.to(p.dtype).expand(n, 3), self.irradiance.to(p.dtype).expand(n, 3),
                           ones, torch.full_like(ones, math.inf))


class ConstantEnvironment(Light):
    """Environment of constant radiance `value` (RGB), sampled uniformly over the sphere."""

    def __init__(self, value, device=None) -> None:
        self.value = torch.tensor(value, dtype=torch.float32, device=device)

    def sample(self, p: torch.Tensor, u: torch.Tensor) -> LightSample:
        wi = sample_uniform_sphere(u.to(p.dtype))
        n = p.shape[0]
        return LightSample(wi, self.value.to(p.dtype).expand(n, 3), torch.full_like(wi[:, 0], 1 / (4 * math.pi)),
                           torch.full_like(wi[:, 0], math.inf))

    def eval(self, d: torch.Tensor) -> torch.Tensor:
        return self.value.to(d.dtype).expand(d.shape[0], 3)

    def pdf(self, d: torch.Tensor) -> torch.Tensor:
        return torch.full_like(d[:, 0], 1 / (4 * math.pi))


class EnvironmentMap(Light):
    """Equirectangular environment map (see `envmaps` for the mapping), looked up per texel (nearest).

    image: (H, W, 3) linear RGB radiance; scale multiplies it; rotation (degrees) turns the map about +y.
    Sampling: an `AliasTable` (O(1) per sample) picks a texel with probability proportional to luminance
    times the texel's solid angle (2 pi / W) (cos theta_top - cos theta_bottom), the exact integral of
    sin theta over its row (tables built in float64); inside the texel the direction is uniform in solid
    angle (phi linear, cos theta linear). The solid-angle pdf is thus piecewise constant:
    P(texel) / solid angle(texel), with no singularity at the poles. Sampled positions keep 1e-4 of a texel
    away from texel edges so that float32 directions map back to the texel they were drawn from. The phi
    offset inside the texel comes from the bits of u[:, 0] left after the texel choice: pass float64 u
    (as the renderer does) for full resolution.
    """

    EDGE = 1e-4

    def __init__(self, image, scale: float = 1.0, rotation: float = 0.0, device=None, name: str = "env") -> None:
        img = torch.as_tensor(image, dtype=torch.float32).to(device)
        if img.dim() != 3 or img.shape[2] != 3 or min(img.shape[:2]) < 1:
            raise InputError(f"{name}: expected an (H, W, 3) image, got shape {tuple(img.shape)}")
        if not bool(torch.isfinite(img).all()):
            raise InputError(f"{name}: image holds NaN or infinite values")
        if bool((img < 0).any()):
            raise InputError(f"{name}: {int((img < 0).sum())} negative value(s) (min {float(img.min()):.4g}); "
                             "radiance must be >= 0")
        self.image = img.clamp(min=0) * float(scale)
        self.height, self.width = img.shape[:2]
        edges = torch.cos(torch.arange(self.height + 1, device=img.device, dtype=torch.float64) * math.pi
                          / self.height)
        self.cos_edges = edges.float()  # (H + 1,) cos theta at the row boundaries, decreasing
        solid_angle = (edges[:-1] - edges[1:]) * (2 * math.pi / self.width)  # (H,) per texel
        weights = (self.image.double() @ self.image.new_tensor(LUMINANCE, dtype=torch.float64)) * solid_angle[:, None]
        if not float(weights.sum()) > 0:
            raise InputError(f"{name}: the environment map is black, nothing to light the scene")
        self.table = AliasTable(weights)
        #: (H, W) solid-angle density inside each texel: P(texel) / solid angle(texel)
        self.texel_pdf = (weights / weights.sum() / solid_angle[:, None]).float()
        self._flat_image = self.image.reshape(-1, 3)
        self._flat_pdf = self.texel_pdf.reshape(-1)
        #: turn about +y (radians); it only shifts phi: phi_world = phi_map - rotation
        self.rotation_rad = math.radians(rotation)

    def _texel(self, d: torch.Tensor) -> torch.Tensor:
        """Flat texel index (N,) (row * W + column) of world directions d (N, 3)."""
        x, z = d[:, 0].contiguous(), d[:, 2].contiguous()  # atan2 on strided views misses the vectorised kernel
        u = torch.remainder((torch.atan2(x, -z) + self.rotation_rad) * (1 / (2 * math.pi)), 1.0)
        v = torch.acos(d[:, 1].clamp(-1, 1)) * (1 / math.pi)
        i = (v * self.height).long().clamp(0, self.height - 1)
        j = (u * self.width).long().clamp(0, self.width - 1)
        return i * self.width + j

    def sample(self, p: torch.Tensor, u: torch.Tensor) -> LightSample:
        texel, fx, fy = self.table.sample(u)
        i, j = texel // self.width, texel % self.width
        fx = fx.float().clamp(self.EDGE, 1 - self.EDGE)
        fy = fy.float().clamp(self.EDGE, 1 - self.EDGE)
        top = self.cos_edges[i]
        cos_theta = top + fy * (self.cos_edges[i + 1] - top)
        sin_theta = ((1 - cos_theta) * (1 + cos_theta)).clamp(min=0).sqrt()  # no cancellation near the poles
        phi = (j + fx) * (2 * math.pi / self.width) - self.rotation_rad
        dtype = p.dtype
        wi = torch.stack([sin_theta * torch.sin(phi), cos_theta, -sin_theta * torch.cos(phi)], -1).to(dtype)
        pdf = self._flat_pdf[texel].to(dtype)
        return LightSample(wi, self._flat_image[texel].to(dtype), pdf, torch.full_like(pdf, math.inf))

    def eval(self, d: torch.Tensor) -> torch.Tensor:
        return self._flat_image[self._texel(d)].to(d.dtype)

    def pdf(self, d: torch.Tensor) -> torch.Tensor:
        return self._flat_pdf[self._texel(d)].to(d.dtype)

    def eval_pdf(self, d: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        texel = self._texel(d)
        return self._flat_image[texel].to(d.dtype), self._flat_pdf[texel].to(d.dtype)


_POINT_OPTIONS = {"intensity": "radiant intensity in W/sr, number or r/g/b (default pi |position|^2)",
                  "position": "x/y/z (alternative to point:x/y/z)"}
_DIR_OPTIONS = {"irradiance": "irradiance at normal incidence, number or r/g/b (default pi)",
                "direction": "x/y/z towards the light (alternative to dir:x/y/z)"}
_ENV_OPTIONS = {"scale": "radiance multiplier (default 1)", "rotation": "turn about +y in degrees (default 0)"}
_SKY_OPTIONS = {**_ENV_OPTIONS, "sun_elevation": "degrees (default 35)", "sun_azimuth": "degrees (default 40)",
                "sun_irradiance": "default 3", "sky_irradiance": "default 1", "width": "map width (default 512)"}


def _vector(value, who: str, nonnegative: bool = False) -> tuple[float, ...]:
    """`as_vector(value, who)`, checked finite (and >= 0 when `nonnegative`)."""
    v = as_vector(value, who)
    if not all(math.isfinite(x) and (x >= 0 or not nonnegative) for x in v):
        raise InputError(f"{who}: expected finite{' non-negative' if nonnegative else ''} numbers, got "
                         f"{'/'.join(map(str, v))}")
    return v


def make_light(spec: str, device=None) -> Light:
    """Build a light from a spec string (see the module docstring) on `device`."""
    s = parse_spec(spec, "light")
    opts = dict(s.options)
    arg = None if s.arg is None else parse_option_value(s.arg)
    if s.name == "point":
        check_options(opts, _POINT_OPTIONS, f"light {spec!r}")
        pos = _vector(opts.get("position", (2.0, 2.0, 2.0) if arg is None else arg), f"light {spec!r}: position")
        default = math.pi * sum(x * x for x in pos)
        return PointLight(pos, _vector(opts.get("intensity", default), f"light {spec!r}: intensity", True), device)
    if s.name == "dir":
        check_options(opts, _DIR_OPTIONS, f"light {spec!r}")
        d = _vector(opts.get("direction", (1.0, 1.0, 1.0) if arg is None else arg), f"light {spec!r}: direction")
        return DirectionalLight(d, _vector(opts.get("irradiance", math.pi), f"light {spec!r}: irradiance", True),
                                device)
    if s.name == "const":
        check_options(opts, {}, f"light {spec!r}")
        return ConstantEnvironment(_vector(1.0 if arg is None else arg, f"light {spec!r}: value", True), device)
    if s.name == "env":
        if not s.arg:
            raise InputError(f"light {spec!r}: expected env:PATH (a .hdr or .exr map) or env:sky")
        scale = _vector(as_float(opts.pop("scale", 1.0), f"light {spec!r}: scale"), f"light {spec!r}: scale",
                        True)[0]
        rotation = as_float(opts.pop("rotation", 0.0), f"light {spec!r}: rotation")
        if not math.isfinite(rotation):
            raise InputError(f"light {spec!r}: rotation: expected a finite number of degrees, got {rotation}")
        if s.arg.lower() == "sky":
            check_options(opts, _SKY_OPTIONS, f"light {spec!r}")
            sky = {k: (v if k == "width" else as_float(v, f"light {spec!r}: {k}")) for k, v in opts.items()}
            return EnvironmentMap(sky_envmap(**sky), scale, rotation, device, name="env:sky")
        check_options(opts, _ENV_OPTIONS, f"light {spec!r}")
        return EnvironmentMap(read_envmap(s.arg), scale, rotation, device, name=f"environment map {s.arg}")
    raise unknown_name("light", s.name, LIGHT_FORMS)


def environment_by_name(name: str, width: int) -> EnvironmentMap:
    """The EnvironmentMap of "sky" or an equirectangular map's path, box-filtered to `width` texels across (how the
    translucent renders light an object: `neumat translucent render`, the neupress benchmark)."""
    return EnvironmentMap(downsample_envmap(sky_envmap(width=width) if name == "sky" else read_envmap(name), width))
