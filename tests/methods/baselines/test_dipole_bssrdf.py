"""Dipole BSSRDF baseline: the profile against its closed-form plane integral, S_hat on a sphere against a
direct sum, fitting recovers known coefficients (homogeneous) and a known coefficient field (textured, which the
homogeneous model cannot), the texture's trilinear lookup and size, bad input."""
import math

import pytest
import torch

from neumat import InputError
from neumat.core.query import Query
from neumat.testing.kernel_parity import kernel_and_torch_errors
from neumat.fit.method import recipe_for
from neumat.fit.trainer import fit
from neumat.fit.translucent_observations import Observations
from neumat.methods.baselines.dipole_bssrdf import DipoleBSSRDF, dipole_profile, dipole_total_reflectance
from neumat.models.registry import build_model
from neumat.nn import cpu_kernels
from neumat.warp import sample_uniform_sphere


@pytest.mark.parametrize("sigma_a, sigma_s", [(0.01, 1.0), (0.5, 2.0), (0.002, 30.0)])
def test_profile_integrates_to_the_total_diffuse_reflectance(sigma_a, sigma_s):
    a, s = torch.full((3,), sigma_a, dtype=torch.float64), torch.full((3,), sigma_s, dtype=torch.float64)
    # 2 pi r R_d(r) dr on a log grid in r (the profile spans decades), trapezoids
    r = torch.logspace(-8, 4, 200001, dtype=torch.float64) / (sigma_a + sigma_s)
    integrand = 2 * math.pi * r * dipole_profile(r, a, s, 1.3)[:, 0]
    numeric = float(torch.trapezoid(integrand, r))
    assert numeric == pytest.approx(float(dipole_total_reflectance(a, s, 1.3)[0]), rel=1e-6)


def _sphere_model(samples=4096, **kw):
    m = DipoleBSSRDF(samples=samples, **kw)
    n = sample_uniform_sphere(torch.rand(samples, 2, generator=torch.Generator().manual_seed(0)))
    m.set_surface(n.clone(), n, torch.full((samples,), 4 * math.pi / samples))
    m.set_bounds(torch.full((3,), -1.0), torch.full((3,), 1.0))
    return m


def test_shat_is_the_quadrature_sum():
    m = _sphere_model(samples=512, init_sigma_a=0.1, init_sigma_s=3.0)
    g = torch.Generator().manual_seed(1)
    x = sample_uniform_sphere(torch.rand(5, 2, generator=g))
    wi, wo = sample_uniform_sphere(torch.rand(5, 2, generator=g)), x.clone()
    with torch.no_grad():
        got = m.eval(Query(wi=wi, wo=wo, x=x, n=x))
        back = m.eval(Query(wi=wi, wo=-wo, x=x, n=x))  # seen from inside: nothing
    ft = lambda c: 1 - _fresnel(c, 1.5)  # noqa: E731
    for q in range(5):
        total = torch.zeros(3)
        for k in range(512):
            c = float(m.normals[k] @ wi[q])
            if c > 0:
                r = (m.points[k] - x[q]).norm()
                total += ft(c) * c * m.areas[k] * dipole_profile(r, *m.coefficients(), 1.5)
        expected = total * ft(float(wo[q] @ x[q])) / math.pi
        assert torch.allclose(got[q], expected, rtol=1e-4), (got[q], expected)
    assert float(back.abs().max()) == 0


def _fresnel(c, eta):
    from neumat.reflectance.microfacet import fresnel_dielectric
    return float(fresnel_dielectric(torch.tensor([c]), eta)[0])


def test_fit_recovers_known_coefficients():
    truth = _sphere_model(samples=256, init_sigma_a=0.08, init_sigma_s=4.0)
    with torch.no_grad():
        truth.log_sigma_a.copy_(torch.log(torch.tensor([0.03, 0.08, 0.2])))
    g = torch.Generator().manual_seed(2)
    x = sample_uniform_sphere(torch.rand(3000, 2, generator=g))
    wi, wo = sample_uniform_sphere(torch.rand(3000, 2, generator=g)), x.clone()
    with torch.no_grad():
        value = truth.raw(wi, x, wo, x)
    obs = Observations(x=x, n=x.clone(), wo=wo, wi=wi, value=value)
    m = _sphere_model(samples=256)  # starts at sigma_a 0.05, sigma_s' 2
    m.set_surface(truth.points, truth.normals, truth.areas)
    recipe = recipe_for("dipole-bssrdf")  # 300 steps of 256, lr 0.05
    recipe.options["validation_fraction"] = 0  # every observation trains
    history = fit(m, obs, recipe, progress=False).history
    assert history[-1]["mse"] < 1e-3 * history[0]["mse"]
    a, s = m.coefficients()
    ta, ts = truth.coefficients()
    assert torch.allclose(a, ta, rtol=0.05) and torch.allclose(s, ts, rtol=0.05), (a, s)


def test_bad_input():
    with pytest.raises(InputError, match="samples"):
        DipoleBSSRDF(samples=0)
    with pytest.raises(InputError, match="ior"):
        DipoleBSSRDF(ior=-1.0)
    m = build_model({"type": "dipole-bssrdf", "samples": 8})
    x = torch.tensor([[0.0, 0.0, 1.0]])
    with pytest.raises(InputError, match="set_surface"):
        m.eval(Query(wi=x, wo=x, x=x, n=x))
    with pytest.raises(InputError, match="Query.n"):
        m.eval(Query(wi=x, wo=x, x=x))
    with pytest.raises(InputError, match=r"\(8, 3\)"):
        m.set_surface(torch.zeros(4, 3), torch.zeros(4, 3), torch.ones(4))
    assert m.size_bytes("fp32") == 24
    m.set_surface(torch.ones(8, 3), torch.ones(8, 3), torch.ones(8))  # the kept surface check follows the areas
    assert torch.isfinite(m.eval(Query(wi=x, wo=x, x=x, n=x))).all()
    with torch.no_grad():
        m.areas.zero_()
    with pytest.raises(InputError, match="set_surface"):
        m.eval(Query(wi=x, wo=x, x=x, n=x))


def test_texture_lookup_is_trilinear_over_the_box():
    m = DipoleBSSRDF(samples=4, texture_resolution=3, init_sigma_a=0.1, init_sigma_s=2.0)
    m.set_bounds(torch.tensor([0.0, -1.0, 2.0]), torch.tensor([2.0, 1.0, 6.0]))  # texel spacing 1, 1, 2
    with torch.no_grad():
        m.texture.copy_(torch.randn(6, 3, 3, 3, generator=torch.Generator().manual_seed(0)))
    corners = torch.tensor([[0.0, -1.0, 2.0], [2.0, 1.0, 6.0], [1.0, 0.0, 4.0], [2.0, -1.0, 2.0]])
    with torch.no_grad():
        got = m.texture_at(corners)
    t = m.texture.detach()
    for k, (i, j, l) in enumerate([(0, 0, 0), (2, 2, 2), (1, 1, 1), (2, 0, 0)]):  # (x, y, z) texels
        assert torch.allclose(got[k], t[:, i, j, l], atol=1e-6)
    p = torch.tensor([[0.25, 0.5, 3.0]])  # a quarter along x, half along y and z in the first cell
    w = torch.tensor([0.75, 0.25])[:, None, None] * torch.tensor([0.5, 0.5])[None, :, None] \
        * torch.tensor([0.5, 0.5])[None, None, :]
    expected = (t[:, 0:2, 1:3, 0:2] * w).sum((1, 2, 3))
    with torch.no_grad():
        assert torch.allclose(m.texture_at(p)[0], expected, atol=1e-6)
        a, s = m.coefficients(p)
        assert torch.allclose(a[0], 0.1 * expected[:3].exp()) and torch.allclose(s[0], 2.0 * expected[3:].exp())
        outside = m.texture_at(torch.tensor([[-5.0, -1.0, 2.0]]))  # clamped to the box
    assert torch.allclose(outside[0], t[:, 0, 0, 0], atol=1e-6)


def test_fit_recovers_a_known_coefficient_field_which_the_homogeneous_model_cannot():
    truth = _sphere_model(samples=256, texture_resolution=4, init_sigma_a=0.08, init_sigma_s=4.0)
    c = torch.linspace(-1, 1, 4)
    with torch.no_grad():
        truth.texture[0] = 1.2 * c[:, None, None]  # red absorption grows along x (x 11 across the sphere)
        truth.texture[4] = -0.8 * c[None, :, None]  # green scattering falls along y
    g = torch.Generator().manual_seed(2)
    x = sample_uniform_sphere(torch.rand(1500, 2, generator=g))
    wi = sample_uniform_sphere(torch.rand(1500, 2, generator=g))
    with torch.no_grad():
        value = truth.raw(wi, x, x, x)
    obs = Observations(x=x, n=x.clone(), wo=x.clone(), wi=wi, value=value)
    probe = sample_uniform_sphere(torch.rand(400, 2, generator=g))
    with torch.no_grad():
        ta, ts = truth.coefficients(probe)
    errors = {}
    for resolution in (4, 1):
        m = _sphere_model(samples=256, texture_resolution=resolution)  # starts homogeneous, sigma_a 0.05, s' 2
        recipe = recipe_for("dipole-bssrdf")
        recipe.options.update(validation_fraction=0, smoothness=0, bounds=[[-1.0] * 3, [1.0] * 3])
        fit(m, obs, recipe, steps=150, progress=False)
        with torch.no_grad():
            a, s = m.coefficients(probe)
        errors[resolution] = max(float((a / ta).log().abs().max()), float((s / ts).log().abs().max()))
    # log-coefficient error over the surface, where the truth spans 2.4 (sigma_a) and 1.6 (sigma_s')
    assert errors[4] < 0.25 and errors[1] > 0.8, errors


def test_textured_size_and_bad_config():
    m = DipoleBSSRDF(samples=8, texture_resolution=8)
    assert m.textured and m.texture.shape == (6, 8, 8, 8)
    assert m.size_bytes("fp32") == (6 + 6 * 8 ** 3) * 4 + 6 * 4 and m.size_bytes("fp16") == (6 + 6 * 512) * 2 + 24
    assert "texture" not in DipoleBSSRDF(samples=8).state_dict()  # the homogeneous model keeps its six numbers
    with pytest.raises(InputError, match="texture_resolution"):
        DipoleBSSRDF(texture_resolution=0)
    with pytest.raises(InputError, match="set_bounds"):
        m.set_bounds(torch.ones(3), torch.zeros(3))
    with pytest.raises(InputError, match=r"^dipole-bssrdf recipe options: option.smoothness: expected a value "
                                         r">= 0, got -1.0$"):
        x = sample_uniform_sphere(torch.rand(64, 2, generator=torch.Generator().manual_seed(0)))
        obs = Observations(x=x, n=x.clone(), wo=x.clone(), wi=x.clone(), value=torch.rand(64, 3))
        recipe = recipe_for("dipole-bssrdf")
        recipe.options["smoothness"] = -1.0
        fit(m, obs, recipe, steps=1, progress=False)


@pytest.mark.skipif(cpu_kernels.library() is None, reason=f"CPU kernels unavailable: {cpu_kernels.unavailable()}")
@pytest.mark.parametrize("resolution", [1, 4])
def test_fused_kernel_is_as_close_to_float64_as_the_torch_path(resolution):
    """The C kernel (cpu_kernels.dipole_eval) and the float32 torch path against the model in float64, homogeneous
    and textured (coefficients per query): views from outside and inside, light from every side; the kernel's worst
    error relative to its row within 2x the torch path's."""
    torch.manual_seed(2)
    m = _sphere_model(samples=1024, init_sigma_a=0.1, init_sigma_s=3.0, texture_resolution=resolution)
    if resolution > 1:
        with torch.no_grad():
            m.texture.copy_(0.5 * torch.randn(m.texture.shape))
    g = torch.Generator().manual_seed(3)
    x = sample_uniform_sphere(torch.rand(300, 2, generator=g))
    q = Query(wi=sample_uniform_sphere(torch.rand(300, 2, generator=g)),
              wo=sample_uniform_sphere(torch.rand(300, 2, generator=g)), x=x, n=x)
    q64 = Query(q.wi.double(), q.wo.double(), x=x.double(), n=x.double())
    fast, kernel, torch32 = kernel_and_torch_errors(m, q, q64, floor=1e-12)
    assert m.eval(q).requires_grad  # with autograd on, the torch path: fits get their gradients
    assert (fast == 0).any() and (fast > 0).any()
    assert kernel <= 2 * torch32, (kernel, torch32)
