"""Images of a translucent object under a distant environment: subsurface radiance only (external surface
reflection excluded, background black), from a learned S_hat (Eq. 5 of NeuPreSS, Monte Carlo) or from
the path-traced reference (Mitsuba 3, same camera rays).

Eq. 5: L(x, wo) = integral over the sphere of L_env(wi) S_hat(wi; x, wo) dwi, estimated with wi drawn from
the environment ("light": luminance importance sampling) or from the model's Gaussian lobe ("model").
"""
from __future__ import annotations

import math

import numpy as np
import torch

from ..core.checks import check_int
from ..core.errors import InputError
from ..core.material import material_device
from ..core.query import Query
from ..reflectance.translucent import TranslucentObject
from .camera import Camera, make_camera
from .lights import EnvironmentMap

STRATEGIES = ("light", "model")


def orbit_camera(obj: TranslucentObject, resolution: int, azimuth: float = 30.0, elevation: float = 20.0,
                 fov: float = 30.0) -> Camera:
    """A pinhole camera framing the object's bounding sphere from (azimuth, elevation) degrees (y up,
    azimuth 0 looks from +z)."""
    centre = (obj.bbox_min + obj.bbox_max) / 2
    a, e = math.radians(azimuth), math.radians(elevation)
    direction = np.array([math.cos(e) * math.sin(a), math.sin(e), math.cos(e) * math.cos(a)])
    distance = obj.diagonal / 2 / math.sin(math.radians(fov) / 2)
    return make_camera("pinhole", resolution, resolution, tuple(centre + distance * direction), tuple(centre),
                       (0.0, 1.0, 0.0), fov=fov)


def _pixel_rays(camera: Camera, resolution: int, spp: int, gen: torch.Generator):
    pix = torch.arange(resolution * resolution)
    xy = torch.stack([pix % resolution, pix // resolution], -1).repeat_interleave(spp, 0).float()
    rays = camera.rays(xy + torch.rand(xy.shape, generator=gen))
    return rays.o.double(), rays.d.double()


def render_translucent(model, obj: TranslucentObject, env: EnvironmentMap, camera: Camera, resolution: int,
                       spp: int = 16, strategy: str = "light", seed: int = 0, batch: int = 1 << 15) -> torch.Tensor:
    """(resolution, resolution, 3) float32 subsurface radiance of `model` (a Material with full_sphere,
    queried with x, wo, wi and the normal n; with strategy "model" it must have `sample_incident`) on the geometry of
    `obj`, lit by `env`, `spp` samples per pixel (jittered over the pixel). The model is queried on its own
    device; the image is on the CPU."""
    if strategy not in STRATEGIES:
        raise InputError(f"strategy: expected one of {STRATEGIES}, got {strategy!r}")
    if strategy == "model" and not hasattr(model, "sample_incident"):
        raise InputError(f"strategy 'model': {type(model).__name__} has no sample_incident")
    check_int(spp, "spp")
    dev = material_device(model)
    gen = torch.Generator().manual_seed(seed)
    o, d = _pixel_rays(camera, resolution, spp, gen)
    hit, x, n = obj.first_hits(o, d)
    x, n, wo = x.float(), n.float(), -d[hit].float()
    values = torch.zeros(x.shape[0], 3)
    with torch.no_grad():
        for s in range(0, x.shape[0], batch):
            sl = slice(s, s + batch)
            u = torch.rand(x[sl].shape[0], 2, generator=gen, dtype=torch.float64)
            if strategy == "light":
                ls = env.sample(x[sl], u)
                wi, pdf, radiance = ls.wi, ls.pdf, ls.radiance
            else:
                q = Query(wi=n[sl], wo=wo[sl], x=x[sl], n=n[sl]).to(dev)
                wi, pdf = (t.cpu() for t in model.sample_incident(q, u.float().to(dev)))
                radiance = env.eval(wi)
            f = model.eval(Query(wi=wi, wo=wo[sl], x=x[sl], n=n[sl]).to(dev)).cpu()
            ok = (pdf > 0).unsqueeze(-1)
            values[sl] = torch.where(ok, f * radiance / pdf.clamp(min=1e-30).unsqueeze(-1), torch.zeros_like(f))
    image = torch.zeros(o.shape[0], 3)
    image[hit] = values
    return image.reshape(resolution * resolution, spp, 3).mean(1).reshape(resolution, resolution, 3)


def render_translucent_reference(obj: TranslucentObject, env: EnvironmentMap, camera: Camera, resolution: int,
                                 spp: int = 256, seed: int = 0) -> torch.Tensor:
    """(resolution, resolution, 3) float32 path-traced subsurface radiance of `obj` lit by `env` (Mitsuba 3,
    the same pixel jitter as `render_translucent`)."""
    if env.rotation_rad != 0:
        raise InputError("render_translucent_reference: rotated environment maps are not supported")
    gen = torch.Generator().manual_seed(seed)
    o, d = _pixel_rays(camera, resolution, spp, gen)
    values = obj.trace_environment(o, d, env.image.cpu().numpy(), seed=seed)
    return values.reshape(resolution * resolution, spp, 3).mean(1).reshape(resolution, resolution, 3).float()
