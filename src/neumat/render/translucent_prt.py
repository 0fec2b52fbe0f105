"""Images of a translucent object from an SH PRT table (NeuPreSS Sec. 4.3, Eq. 11): subsurface radiance only,
background black, with the camera rays and pixel jitter of `render_translucent` (same seed, same samples).

Per camera ray: the first triangle of the table's mesh it hits and the barycentric weights of the hit point, the
environment's SH coefficients b_lm (Eq. 9, once per image), and L = sum_k bary_k sum_lm a_lm(x_k, wo) b_lm over
the triangle's vertices k (`SHPRT.radiance_barycentric`, a_lm bilinear over the view bins). No Monte Carlo over
light directions: the samples per pixel only anti-alias.
"""
from __future__ import annotations

import torch

from ..core.checks import check_int
from ..core.errors import InputError
from .camera import Camera
from .lights import EnvironmentMap
from .mesh import MeshIntersector
from .translucent import _pixel_rays


def render_prt(prt, env: EnvironmentMap, camera: Camera, resolution: int, spp: int = 4, seed: int = 0,
               batch: int = 1 << 16) -> torch.Tensor:
    """(resolution, resolution, 3) float32 radiance of the SH PRT table `prt` (a `neumat.methods.neupress.prt.SHPRT`
    that holds its mesh's faces) lit by `env`, seen by `camera` with `spp` jittered samples per pixel."""
    check_int(resolution, "resolution")
    check_int(spp, "spp")
    if getattr(prt, "faces", None) is None:
        raise InputError("render_prt: the SH PRT table has no triangles (faces); precompute it with "
                         "`neumat translucent prt`, which stores the mesh")
    gen = torch.Generator().manual_seed(seed)
    o, d = _pixel_rays(camera, resolution, spp, gen)
    hit, face, bary = MeshIntersector(prt.points, prt.faces).intersect(o, d)
    b = prt.light_coefficients(env)
    wo = -d[hit]
    wo = (wo / wo.norm(dim=-1, keepdim=True)).float()
    tri = prt.faces.cpu()[face]
    values = torch.zeros(wo.shape[0], 3)
    for s in range(0, wo.shape[0], batch):
        sl = slice(s, s + batch)
        values[sl] = prt.radiance_barycentric(tri[sl].to(prt.device), bary[sl].float(), wo[sl].to(prt.device),
                                              b).cpu()
    image = torch.zeros(o.shape[0], 3)
    image[hit] = values
    return image.reshape(resolution * resolution, spp, 3).mean(1).reshape(resolution, resolution, 3)
