"""Dipole BSSRDF baseline: the profile against its closed-form plane integral, S_hat on a sphere against a
direct sum, fitting recovers known coefficients, bad input."""
import math

import pytest
import torch

from neumat import InputError
from neumat.core.query import Query
from neumat.fit.recipe import recipe_for
from neumat.fit.trainer import fit
from neumat.fit.translucent_observations import Observations
from neumat.models.dipole_bssrdf import DipoleBSSRDF, dipole_profile, dipole_total_reflectance
from neumat.models.registry import build_model
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
    truth = _sphere_model(samples=1024, init_sigma_a=0.08, init_sigma_s=4.0)
    with torch.no_grad():
        truth.log_sigma_a.copy_(torch.log(torch.tensor([0.03, 0.08, 0.2])))
    g = torch.Generator().manual_seed(2)
    x = sample_uniform_sphere(torch.rand(3000, 2, generator=g))
    wi, wo = sample_uniform_sphere(torch.rand(3000, 2, generator=g)), x.clone()
    with torch.no_grad():
        value = truth.raw(wi, x, wo, x)
    obs = Observations(x=x, n=x.clone(), wo=wo, wi=wi, value=value)
    m = _sphere_model(samples=1024)  # starts at sigma_a 0.05, sigma_s' 2
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
