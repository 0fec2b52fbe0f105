"""The reflection lobe of the rough dielectric: Mitsuba 3's `roughdielectric` eval and pdf, chi-square of the
sampler, the albedo at normal incidence against closed-form Fresnel, world frames, and the zero cases."""
import math

import numpy as np
import pytest
import torch

from neumat import InputError
from neumat.core.frames import frame_from_normal, to_world
from neumat.reflectance.microfacet import fresnel_dielectric
from neumat.reflectance.rough_dielectric import (rough_dielectric_reflection, rough_dielectric_reflection_pdf,
                                                 sample_rough_dielectric_reflection)
from neumat.testing.chi2 import chi2_directions
from tests.mitsuba_util import mitsuba_or_skip


def _upper(n: int, gen: torch.Generator) -> torch.Tensor:
    v = torch.randn(n, 3, generator=gen, dtype=torch.float64)
    v[:, 2] = v[:, 2].abs() + 0.02  # nothing exactly grazing
    return v / v.norm(dim=-1, keepdim=True)


def _mi_vector(mi, w: torch.Tensor):
    return mi.Vector3f(*(mi.Float(c.float().contiguous().numpy()) for c in w.T))


@pytest.mark.mitsuba
@pytest.mark.parametrize("alpha,eta", [(0.05, 1.5), (0.3, 1.5), (0.9, 1.33)])
def test_eval_and_pdf_match_mitsubas_roughdielectric_reflection(alpha, eta):
    """Mitsuba's eval is f_r cos_o; its pdf (both lobes enabled) is the visible-normal density times F(wi . h)."""
    mi = mitsuba_or_skip()
    import drjit as dr
    gen = torch.Generator().manual_seed(1)
    n = 2000
    viewer, light = _upper(n, gen), _upper(n, gen)
    bsdf = mi.load_dict({"type": "roughdielectric", "distribution": "ggx", "alpha": alpha, "int_ior": eta,
                         "ext_ior": 1.0})
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = _mi_vector(mi, viewer)
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    ctx = mi.BSDFContext()
    value = torch.from_numpy(np.array(bsdf.eval(ctx, si, _mi_vector(mi, light)), dtype=np.float64)[0].copy())
    pdf = torch.from_numpy(np.array(bsdf.pdf(ctx, si, _mi_vector(mi, light)), dtype=np.float64))
    # the float32 inputs Mitsuba saw, normalised again in float64
    viewer, light = (torch.nn.functional.normalize(w.float().double(), dim=-1) for w in (viewer, light))
    mine = rough_dielectric_reflection(light, viewer, alpha, eta) * light[:, 2]
    assert bool((value > 0).all())
    assert float(((mine - value).abs() / value).max()) < 1e-4
    h = torch.nn.functional.normalize(light + viewer, dim=-1)
    mine_pdf = rough_dielectric_reflection_pdf(light, viewer, alpha) * fresnel_dielectric((light * h).sum(-1), eta)
    assert float(((mine_pdf - pdf).abs() / pdf).max()) < 1e-4
    # reflection is reciprocal
    assert torch.allclose(rough_dielectric_reflection(viewer, light, alpha, eta), mine / light[:, 2], rtol=1e-12)


@pytest.mark.parametrize("theta,alpha", [(0.0, 0.3), (0.8, 0.1), (1.3, 0.6)])
def test_sampler_chi2(theta, alpha):
    wo = torch.tensor([[math.sin(theta), 0.0, math.cos(theta)]], dtype=torch.float64)

    def sample_fn(u):
        wi, pdf = sample_rough_dielectric_reflection(wo.expand(len(u), 3), u.double(), alpha)
        return wi, pdf > 0

    r = chi2_directions(sample_fn, lambda w: rough_dielectric_reflection_pdf(w, wo.expand(len(w), 3), alpha),
                        n_samples=200_000, res=(20, 40), quad=16, n_tests=3, dtype=torch.float64)
    assert r.passed, r.message


def test_albedo_at_normal_incidence_is_fresnel_for_a_smooth_surface():
    """For alpha -> 0 the reflected albedo (integral of f_r cos over the hemisphere) at normal incidence is the
    Fresnel reflectance ((eta - 1) / (eta + 1))^2; estimated with the sampler, which also checks that f_r / pdf
    is what the sampler's weight should be."""
    gen = torch.Generator().manual_seed(0)
    n = 1 << 16
    for eta in (1.33, 1.5, 2.0):
        wo = torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64).expand(n, 3)
        wi, pdf = sample_rough_dielectric_reflection(wo, torch.rand(n, 2, generator=gen, dtype=torch.float64), 1e-3)
        albedo = (rough_dielectric_reflection(wi, wo, 1e-3, eta) * wi[:, 2] / pdf).mean()
        assert abs(float(albedo) - ((eta - 1) / (eta + 1)) ** 2) < 1e-5, (eta, float(albedo))
    # a rough surface: the sampler's estimate equals a midpoint quadrature of f_r cos over the hemisphere
    wi, pdf = sample_rough_dielectric_reflection(wo, torch.rand(n, 2, generator=gen, dtype=torch.float64), 0.5)
    ok = pdf > 0
    sampled = (rough_dielectric_reflection(wi[ok], wo[ok], 0.5, 1.5) * wi[ok, 2] / pdf[ok]).sum() / n
    k = 400
    z, phi = torch.meshgrid((torch.arange(k, dtype=torch.float64) + 0.5) / k,
                            (torch.arange(k, dtype=torch.float64) + 0.5) * (2 * math.pi / k), indexing="ij")
    r = (1 - z * z).sqrt()
    grid = torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], -1).reshape(-1, 3)
    f = rough_dielectric_reflection(grid, wo[:1].expand(len(grid), 3), 0.5, 1.5) * grid[:, 2]
    exact = float(f.mean() * 2 * math.pi)
    assert abs(float(sampled) - exact) < 0.01 * exact and exact < 0.04, (float(sampled), exact)


def test_world_frame_agrees_with_the_local_frame():
    gen = torch.Generator().manual_seed(2)
    m = 500
    normal = torch.nn.functional.normalize(torch.randn(m, 3, generator=gen, dtype=torch.float64), dim=-1)
    frame = (*frame_from_normal(normal), normal)
    wi_local, wo_local = _upper(m, gen), _upper(m, gen)
    wi, wo = to_world(wi_local, *frame), to_world(wo_local, *frame)
    assert torch.allclose(rough_dielectric_reflection(wi, wo, 0.3, 1.5, n=normal),
                          rough_dielectric_reflection(wi_local, wo_local, 0.3, 1.5), rtol=1e-10)
    assert torch.allclose(rough_dielectric_reflection_pdf(wi, wo, 0.3, n=normal),
                          rough_dielectric_reflection_pdf(wi_local, wo_local, 0.3), rtol=1e-10)
    u = torch.rand(m, 2, generator=gen, dtype=torch.float64)
    sampled, pdf = sample_rough_dielectric_reflection(wo, u, 0.3, n=normal)
    local, local_pdf = sample_rough_dielectric_reflection(wo_local, u, 0.3)
    assert torch.allclose(sampled, to_world(local, *frame), atol=1e-12) and torch.allclose(pdf, local_pdf, rtol=1e-10)
    assert torch.allclose(pdf, rough_dielectric_reflection_pdf(sampled, wo, 0.3, n=normal), rtol=1e-8)


def test_zero_below_the_surface_and_bad_input():
    up = torch.tensor([[0.0, 0.6, 0.8]], dtype=torch.float64)
    down = torch.tensor([[0.0, 0.6, -0.8]], dtype=torch.float64)
    assert float(rough_dielectric_reflection(up, down, 0.3, 1.5)) == 0
    assert float(rough_dielectric_reflection(down, up, 0.3, 1.5)) == 0
    assert float(rough_dielectric_reflection_pdf(up, down, 0.3)) == 0
    _, pdf = sample_rough_dielectric_reflection(down, torch.full((1, 2), 0.5, dtype=torch.float64), 0.3)
    assert float(pdf) == 0  # a viewer below the surface sees no reflection
    with pytest.raises(InputError, match="wi"):
        rough_dielectric_reflection(2 * up, up, 0.3, 1.5)
    with pytest.raises(InputError, match="alpha"):
        rough_dielectric_reflection(up, up, torch.ones(2), 1.5)
