"""`neumat_translucent_shade` of the NeuPreSS GLSL export on headless OpenGL: the same sum as a torch computation of
its estimator (GGX-sampled rough-dielectric reflection plus lobe-sampled S_hat, over one Hammersley set), and its
surface term against Mitsuba's `roughdielectric` reflection."""
import math

import numpy as np
import pytest
import torch

from neumat.core.query import Query
from neumat.export.glsl_common import GLSLExport
from neumat.methods.neupress.glsl import export_neupress
from neumat.methods.neupress.model import NeuPreSS
from neumat.render.lights import EnvironmentMap
from neumat.testing.parity import glsl_run, opengl_available
from neumat.warp import sample_uniform_sphere

needs_gl = pytest.mark.skipif(not opengl_available(), reason="no moderngl or no headless OpenGL 3.3 context (EGL)")


def _hammersley(count: int) -> torch.Tensor:
    """(count, 2) float32: ((k + 0.5) / count, the base-2 radical inverse of k to 24 bits), as the shader."""
    k = torch.arange(count)
    rev = torch.tensor([int(f"{i:032b}"[::-1], 2) >> 8 for i in range(count)], dtype=torch.float32)
    return torch.stack([(k.float() + 0.5) / count, rev * 2.0 ** -24], -1)


def _basis(n: torch.Tensor):
    """neumat's nm_basis (Duff et al. 2017), as the GLSL common code builds it."""
    sign = torch.where(n[:, 2] >= 0, 1.0, -1.0)
    a = -1.0 / (sign + n[:, 2])
    b = n[:, 0] * n[:, 1] * a
    t = torch.stack([1 + sign * n[:, 0] ** 2 * a, sign * b, -sign * n[:, 0]], -1)
    s = torch.stack([b, sign + n[:, 1] ** 2 * a, -n[:, 1]], -1)
    return t, s


def _fresnel(c, eta):
    sin2 = (1 - c * c) / eta ** 2
    ct = (1 - sin2).clamp(min=0).sqrt()
    rs = (c - eta * ct) / (c + eta * ct)
    rp = (eta * c - ct) / (eta * c + ct)
    return torch.where(sin2 >= 1, torch.ones_like(c), 0.5 * (rs * rs + rp * rp))


def _g1(v, h, n, alpha):
    c = (v * n).sum(-1)
    tan2 = (1 - c * c).clamp(min=0) / (c * c)
    return torch.where((v * h).sum(-1) * c > 0, 2 / (1 + (1 + alpha ** 2 * tan2).sqrt()), torch.zeros_like(c))


def _reference(model, env, x, n, wo, alpha, ior, samples):
    """The shader's estimator in torch: (N, 3)."""
    u_all = _hammersley(samples)
    t, b = _basis(n)
    co = (n * wo).sum(-1)
    total = torch.zeros(x.shape[0], 3)
    for k in range(samples):
        u = u_all[k].expand(x.shape[0], 2)
        cos2 = 1 / (1 + alpha ** 2 * u[:, 0] / (1 - u[:, 0]))
        cos_h, sin_h, phi = cos2.sqrt(), (1 - cos2).clamp(min=0).sqrt(), 2 * math.pi * u[:, 1]
        h = (sin_h * phi.cos())[:, None] * t + (sin_h * phi.sin())[:, None] * b + cos_h[:, None] * n
        oh = (wo * h).sum(-1)
        wr = 2 * oh[:, None] * h - wo
        ok = (co > 0) & ((n * wr).sum(-1) > 0) & (oh > 0)
        w = _fresnel(oh, ior) * _g1(wo, h, n, alpha) * _g1(wr, h, n, alpha) * oh / (co * cos_h)
        total += torch.where(ok[:, None], w[:, None] * env.eval(wr), torch.zeros(1))
        with torch.no_grad():
            wi, pdf = model.sample_incident(Query(wi=n, wo=wo, x=x, n=n), u)
            f = model.eval(Query(wi=wi, wo=wo, x=x))
        total += torch.where((pdf > 0)[:, None], f * env.eval(wi) / pdf[:, None], torch.zeros(1))
    return total / samples


def _model():
    torch.manual_seed(0)
    m = NeuPreSS(features=7, width=12, layers=4, sampler_hidden=(10, 6), direction_encoding="cartesian")
    m.set_bounds(torch.full((3,), -1.0), torch.full((3,), 1.0))
    with torch.no_grad():
        m.appearance.out.bias.add_(0.2)
    return m


def _env() -> np.ndarray:
    g = torch.Generator().manual_seed(5)
    return (0.2 + torch.rand(8, 16, 3, generator=g) * torch.linspace(2, 0.3, 8)[:, None, None]).numpy()


@needs_gl
def test_shade_is_the_torch_estimator():
    model, env = _model(), _env()
    g = torch.Generator().manual_seed(3)
    x = sample_uniform_sphere(torch.rand(200, 2, generator=g))
    n = x.clone()
    wo = sample_uniform_sphere(torch.rand(200, 2, generator=g))
    wo = torch.where(((wo * n).sum(-1) < 0)[:, None], -wo, wo)  # the visible side
    base = export_neupress(model)
    image = np.concatenate([env, np.ones(env.shape[:2] + (1,))], -1)[None].astype(np.float32)
    export = GLSLExport(base.source, {**base.textures, "neumat_env": image}, spatially_varying=False)
    alpha, ior, samples = 0.3, 1.5, 16
    shaded = glsl_run(export, {"x": x, "n": n, "wo": wo},
                      f"colour = vec4(neumat_translucent_shade(x.xyz, n.xyz, wo.xyz, {alpha}, {ior}, {samples}), 1.0);")
    expected = _reference(model, EnvironmentMap(env), x, n, wo, alpha, ior, samples)
    err = (shaded[:, :3] - expected).abs()
    assert float(expected.min()) > 0
    assert float((err / expected).median()) < 1e-4, float((err / expected).median())
    assert float((err > 1e-3 * expected).float().mean()) < 0.02  # a rare texel edge / lobe sample may differ


@needs_gl
def test_surface_term_is_mitsubas_rough_dielectric_reflection():
    from mitsuba_util import mitsuba_or_skip
    mitsuba_or_skip()
    from neumat.core.mitsuba import import_mitsuba
    mi = import_mitsuba()
    import drjit as dr
    g = torch.Generator().manual_seed(7)
    wo, wi = (sample_uniform_sphere(torch.rand(300, 2, generator=g)) for _ in range(2))
    wo[:, 2], wi[:, 2] = wo[:, 2].abs(), wi[:, 2].abs()
    n = torch.tensor([[0.0, 0.0, 1.0]]).expand(300, 3)
    alpha, ior = 0.3, 1.5
    export = export_neupress(_model())
    ours = glsl_run(export, {"n": n, "wo": wo, "wi": wi}, f"colour = vec4(neumat_rough_dielectric_reflection("
                    f"n.xyz, wo.xyz, wi.xyz, {alpha}, {ior}));")[:, 0]
    bsdf = mi.load_dict({"type": "roughdielectric", "distribution": "ggx", "alpha": alpha, "int_ior": ior,
                         "ext_ior": 1.0})
    si = dr.zeros(mi.SurfaceInteraction3f, 300)
    si.wi = mi.Vector3f(*(mi.Float(c.contiguous()) for c in wo.T))
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    value = bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(*(mi.Float(c.contiguous()) for c in wi.T)))
    theirs = torch.from_numpy(np.array(value, dtype=np.float32)[0].copy())
    assert float(theirs.max()) > 0.1  # a glossy peak (Fresnel ~0.04 times D) is among the directions
    assert torch.allclose(ours, theirs, rtol=1e-4, atol=1e-6), float((ours - theirs).abs().max())
