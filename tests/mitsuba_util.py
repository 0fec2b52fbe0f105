"""Detect a usable Mitsuba 3 (LLVM backend) without risking the test process, and import it.

A broken LLVM can abort the interpreter at its first kernel, so `neumat.core.llvm` probes each
candidate library in a subprocess, once per process. Use `mitsuba_or_skip()` inside a test (it skips with the
reason, which names the fix) and mark the test `@pytest.mark.mitsuba`.
"""
from __future__ import annotations

import pytest

from neumat.core.errors import InputError
from neumat.core.mitsuba import import_mitsuba


def mitsuba_or_skip():
    """The `mitsuba` module with variant llvm_ad_rgb set, or skip the calling test with the reason."""
    try:
        return import_mitsuba()
    except InputError as e:
        pytest.skip(str(e))


def mi_vector(mi, w):
    """A torch (N, 3) tensor as Mitsuba's Vector3f."""
    return mi.Vector3f(*(mi.Float(c.contiguous()) for c in w.T))


def to_torch(x):
    """A Mitsuba / Dr.Jit array as a float64 torch tensor ((3, N) arrays transposed to (N, 3))."""
    import numpy as np
    import torch

    a = np.array(x, dtype=np.float64)
    return torch.from_numpy(a.T.copy() if a.ndim == 2 else a)


def bsdf_chi2_test(mi, bsdf, theta: float, uv=None, sample_count: int = 200_000, res: int = 32):
    """Mitsuba's chi-square test of `bsdf.sample` against `bsdf.pdf` at incident elevation `theta` (radians; at
    `uv`, a pair, where given), failed samples carrying no weight as in mi.chi2.BSDFAdapter; the caller runs it."""
    import drjit as dr
    import numpy as np

    wi = mi.ScalarVector3f(np.sin(theta), 0.0, np.cos(theta))
    ctx = mi.BSDFContext()

    def interaction(n):
        si = dr.zeros(mi.SurfaceInteraction3f, n)
        si.wi = mi.Vector3f(wi)
        if uv is not None:
            si.uv = mi.Point2f(*uv)
        return si

    def sample(s):
        bs, _ = bsdf.sample(ctx, interaction(dr.width(s)), s.x, mi.Point2f(s.y, s.z))
        return bs.wo, dr.select(bs.pdf > 0, 1.0, 0.0)

    def pdf(wo):
        return bsdf.pdf(ctx, interaction(dr.width(wo)), wo)

    # ires=8: at Mitsuba's default 4 its quadrature of the pdf is too coarse near grazing angles, where it rejects
    # Mitsuba's own roughconductor at low alphas as well (p = 1e-6 at theta 1.2)
    return mi.chi2.ChiSquareTest(domain=mi.chi2.SphericalDomain(), sample_func=sample, pdf_func=pdf,
                                 sample_dim=3, sample_count=sample_count, res=res, ires=8)


#: sphere_scene's default lights: a sun and a constant sky
SUN_AND_SKY = {"sun": {"type": "directional", "direction": [0.3, -1, -0.4], "irradiance": 3.0},
               "sky": {"type": "constant", "radiance": {"type": "rgb", "value": [0.6, 0.7, 0.9]}}}


def sphere_scene(mi, bsdf, spp: int = 16, size: int = 32, depth: int = 4, lights: dict | None = None):
    """A sphere with `bsdf` on a diffuse floor under `lights` (default SUN_AND_SKY), path traced to `depth`: the
    scene the plugin tests render natively, through the bridge and with Mitsuba's own BSDFs."""
    return mi.load_dict({
        "type": "scene", "integrator": {"type": "path", "max_depth": depth},
        "sensor": {"type": "perspective", "fov": 30,
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 1.5, 3.5], target=[0, 0, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": size, "height": size, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent", "sample_count": spp}},
        "sphere": {"type": "sphere", "bsdf": bsdf},
        "floor": {"type": "rectangle", "to_world": mi.ScalarTransform4f().translate([0, -1, 0]).rotate([1, 0, 0], -90)
                  .scale(3), "bsdf": {"type": "diffuse"}},
        **(SUN_AND_SKY if lights is None else lights)})
