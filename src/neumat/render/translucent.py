"""Images of a translucent object under a distant environment, from a learned S_hat (Eq. 5 of NeuPreSS, Monte
Carlo) or from the path-traced reference (Mitsuba 3, same camera rays).

Two appearances: "subsurface" (the learned term alone, background black: what S_hat holds) and "full" (Eq. 3:
the surface reflection f_r of the environment off the rough dielectric, plus the subsurface term, over the
environment seen by rays that miss the object).

Eq. 5: L(x, wo) = integral over the sphere of L_env(wi) S_hat(wi; x, wo) dwi, estimated with wi drawn from
the environment ("light": luminance importance sampling), from the model's Gaussian lobe ("model"), or from
their even mixture ("mis": one sample, weighted by the balance heuristic, 1 / (p_env + p_model) / 2; the same
number of network evaluations as the others). The surface reflection takes one environment sample and one
GGX visible-normal sample per camera sample, combined by the balance heuristic; directions the object itself
blocks give 0 (on a convex object nothing else differs from the reference; light reflected between parts of a
concave object is not included).
"""
from __future__ import annotations

import math

import numpy as np
import torch

from ..core.checks import check_int
from ..core.errors import InputError
from ..core.material import material_device
from ..core.query import Query
from ..reflectance.rough_dielectric import (rough_dielectric_reflection, rough_dielectric_reflection_pdf,
                                            sample_rough_dielectric_reflection)
from ..reflectance.translucent import TRACE_PARTS, TranslucentObject
from .camera import Camera, make_camera
from .lights import EnvironmentMap

STRATEGIES = ("light", "model", "mis")
APPEARANCES = ("full", "subsurface")
#: origins of visibility rays sit this many bounding-box diagonals above the surface
RAY_OFFSET = 1e-4


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


def object_mask(obj: TranslucentObject, camera: Camera, resolution: int) -> torch.Tensor:
    """(resolution, resolution) bool: the pixels whose centre ray hits the object."""
    pix = torch.arange(resolution * resolution)
    rays = camera.rays(torch.stack([pix % resolution, pix // resolution], -1).float() + 0.5)
    return obj.first_hits(rays.o.double(), rays.d.double())[0].reshape(resolution, resolution)


def _pixel_rays(camera: Camera, resolution: int, spp: int, gen: torch.Generator):
    pix = torch.arange(resolution * resolution)
    xy = torch.stack([pix % resolution, pix // resolution], -1).repeat_interleave(spp, 0).float()
    rays = camera.rays(xy + torch.rand(xy.shape, generator=gen))
    return rays.o.double(), rays.d.double()


def default_strategy(model) -> str:
    """"mis" for a model that samples its lobe and gives its pdf (sample_incident, incident_pdf), else "light"."""
    return "mis" if hasattr(model, "sample_incident") and hasattr(model, "incident_pdf") else "light"


def image_scores(reference: torch.Tensor, test: torch.Tensor, mask: np.ndarray) -> dict[str, float]:
    """The translucent image table's scores of `test` against `reference` under the ACES tone map: the image
    metrics (FLIP, SSIM, ...), MSE of the radiance, and FLIP over the object's pixels (`mask`), where the learned
    term is (the background is the same in both)."""
    from ..metrics.image import image_metrics, masked_flip

    scores = image_metrics(reference.numpy(), test.numpy(), tonemap="aces")
    scores["mse"] = float(((test - reference) ** 2).mean())
    scores["object_flip"] = masked_flip(reference.numpy(), test.numpy(), mask, tonemap="aces")
    return scores


def render_translucent(model, obj: TranslucentObject, env: EnvironmentMap, camera: Camera, resolution: int,
                       spp: int = 16, strategy: str | None = None, seed: int = 0, batch: int = 1 << 15,
                       appearance: str = "subsurface") -> torch.Tensor:
    """(resolution, resolution, 3) float32 radiance of `model` (a Material with full_sphere, queried with x, wo,
    wi and the normal n; strategy "model" needs `sample_incident`, "mis" also `incident_pdf` (and uses
    `incident_lobe(q)`, a lobe with sample(u) / pdf(w), when the model has one: its sampler runs once); default
    `default_strategy(model)`) on the geometry of `obj`, lit by `env`, `spp` samples per pixel (jittered over the
    pixel). appearance "subsurface": the learned term on black; "full": plus the surface reflection and the
    background (see the module docstring). The model is queried on its own device; the image is on the CPU."""
    strategy = default_strategy(model) if strategy is None else strategy
    if strategy not in STRATEGIES:
        raise InputError(f"strategy: expected one of {STRATEGIES}, got {strategy!r}")
    for name in {"model": ("sample_incident",), "mis": ("sample_incident", "incident_pdf")}.get(strategy, ()):
        if not hasattr(model, name):
            raise InputError(f"strategy {strategy!r}: {type(model).__name__} has no {name}")
    if appearance not in APPEARANCES:
        raise InputError(f"appearance: expected one of {APPEARANCES}, got {appearance!r}")
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
            elif strategy == "model":
                q = Query(wi=n[sl], wo=wo[sl], x=x[sl], n=n[sl]).to(dev)
                wi, pdf = (t.cpu() for t in model.sample_incident(q, u.float().to(dev)))
                radiance = env.eval(wi)
            else:
                wi, pdf, radiance = _mixture_sample(model, env, x[sl], n[sl], wo[sl], u, gen, dev)
            f = model.eval(Query(wi=wi, wo=wo[sl], x=x[sl], n=n[sl]).to(dev)).cpu()
            ok = (pdf > 0).unsqueeze(-1)
            values[sl] = torch.where(ok, f * radiance / pdf.clamp(min=1e-30).unsqueeze(-1), torch.zeros_like(f))
    image = torch.zeros(o.shape[0], 3)
    image[hit] = values
    if appearance == "full":
        image[~hit] = env.eval(d[~hit]).float()
        rows = hit.nonzero().squeeze(1)
        for s in range(0, rows.shape[0], batch):
            r = rows[s:s + batch]
            image[r] += surface_reflection(obj, env, o[r], d[r], gen).float()
    return image.reshape(resolution * resolution, spp, 3).mean(1).reshape(resolution, resolution, 3)


def _mixture_sample(model, env: EnvironmentMap, x, n, wo, u, gen: torch.Generator, dev):
    """Light directions (M, 3) from the even mixture of environment and model sampling (one uniform number more
    picks the technique), their mixture pdf (M,) and the radiance (M, 3) along them."""
    pick_env = torch.rand(x.shape[0], generator=gen) < 0.5
    q = Query(wi=n, wo=wo, x=x, n=n).to(dev)
    lobe = model.incident_lobe(q) if hasattr(model, "incident_lobe") else None  # its network once, for both
    um = u.float().to(dev)
    from_model = (lobe.sample(um.to(q.dtype)) if lobe is not None else model.sample_incident(q, um))[0]
    wi = torch.where(pick_env.unsqueeze(-1), env.sample(x, u).wi, from_model.cpu().to(x.dtype))
    radiance, env_pdf = env.eval_pdf(wi)
    model_pdf = (lobe.pdf(wi.to(dev, q.dtype)) if lobe is not None
                 else model.incident_pdf(Query(wi=wi, wo=wo, x=x, n=n).to(dev))).cpu().to(x.dtype)
    return wi, 0.5 * (env_pdf + model_pdf), radiance


def surface_reflection(obj: TranslucentObject, env: EnvironmentMap, o: torch.Tensor, d: torch.Tensor,
                       gen: torch.Generator) -> torch.Tensor:
    """Radiance (M, 3) float64 reflected towards the camera by the rough dielectric surface of `obj` where the
    camera rays o + t d (M, 3) first hit it (every ray must hit): the environment's light, one environment sample
    and one GGX sample per ray combined by the balance heuristic, 0 along directions the object blocks."""
    o, d = o.double(), d.double()
    hit, x, geometric = obj.first_hits(o, d)
    if not bool(hit.all()):
        raise InputError(f"surface_reflection: {int((~hit).sum())} of the camera rays miss the object")
    n = obj.shading_normals(o, d)
    wo = -d
    alpha = obj.surface_roughness(x)
    eta = float(obj.config.ior)
    u_env = torch.rand(x.shape[0], 2, generator=gen, dtype=torch.float64)
    u_ggx = torch.rand(x.shape[0], 2, generator=gen, dtype=torch.float64)
    origin = x + RAY_OFFSET * obj.diagonal * geometric
    out = torch.zeros(x.shape[0], 3, dtype=torch.float64)
    for wi in (env.sample(x, u_env).wi, sample_rough_dielectric_reflection(wo, u_ggx, alpha, n=n)[0]):
        f = rough_dielectric_reflection(wi, wo, alpha, eta, n=n) * (wi * n).sum(-1)
        live = (f > 0).nonzero().squeeze(1)
        radiance, env_pdf = env.eval_pdf(wi[live])
        pdf = env_pdf + rough_dielectric_reflection_pdf(wi[live], wo[live], alpha[live], n=n[live])
        visible = ~obj.occluded(origin[live], wi[live])
        weight = torch.where(visible, f[live] / pdf, torch.zeros_like(pdf))
        out[live] += weight.unsqueeze(-1) * radiance
    return out


def render_translucent_reference(obj: TranslucentObject, env: EnvironmentMap, camera: Camera, resolution: int,
                                 spp: int = 256, seed: int = 0, appearance: str = "subsurface") -> torch.Tensor:
    """(resolution, resolution, 3) float32 path-traced radiance of `obj` lit by `env` (Mitsuba 3, the same pixel
    jitter as `render_translucent`). appearance "subsurface": real minus black interior; "full": the real
    interior alone, with the background; "reflection": the black interior alone (surface reflection and
    background)."""
    if appearance not in TRACE_PARTS:
        raise InputError(f"appearance: expected one of {TRACE_PARTS}, got {appearance!r}")
    if env.rotation_rad != 0:
        raise InputError("render_translucent_reference: rotated environment maps are not supported")
    gen = torch.Generator().manual_seed(seed)
    o, d = _pixel_rays(camera, resolution, spp, gen)
    values = obj.trace_environment(o, d, env.image.cpu().numpy(), seed=seed, part=appearance)
    return values.reshape(resolution * resolution, spp, 3).mean(1).reshape(resolution, resolution, 3).float()
