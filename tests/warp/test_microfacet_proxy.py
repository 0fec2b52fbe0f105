"""Two-lobe sampling proxy of Real-Time Neural Appearance Models (App. A): chi-square tests of sampler against
density, normalisation, the centred isotropic case against the GGX NDF, activations, gradients, bad input."""
from __future__ import annotations

import math

import pytest
import torch

from neumat import InputError
from neumat.warp.ggx_distribution import ggx_ndf
from neumat.testing.chi2 import chi2_directions
from neumat.warp.microfacet_proxy import (MAX_RHO, MIN_ALPHA, ProxyLobes, proxy_from_raw, proxy_pdf, sample_proxy,
                                          soft_sinh, soft_tanh)
from neumat.warp.sphere import sample_uniform_sphere


def lobes(n: int, w_d: float, mu_d=(0.0, 0.0), alpha=(0.3, 0.3), rho: float = 0.0, mu_s=(0.0, 0.0),
          dtype=torch.float32) -> ProxyLobes:
    def rows(v):
        return torch.tensor(v, dtype=dtype).expand(n, len(v)).clone()
    return ProxyLobes(torch.full((n,), w_d, dtype=dtype), rows(mu_d), rows(alpha), torch.full((n,), rho, dtype=dtype),
                      rows(mu_s))


def incident(theta_deg: float, phi_deg: float = 30.0, n: int = 1, dtype=torch.float32) -> torch.Tensor:
    t, p = math.radians(theta_deg), math.radians(phi_deg)
    return torch.tensor([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)], dtype=dtype).expand(n, 3)


CASES = {
    "diffuse tilted": (dict(w_d=1.0, mu_d=(0.4, -0.3)), 40.0),
    "specular isotropic": (dict(w_d=0.0, alpha=(0.3, 0.3)), 30.0),
    "specular anisotropic correlated": (dict(w_d=0.0, alpha=(0.15, 0.5), rho=0.6), 50.0),
    "specular non-centred slopes": (dict(w_d=0.0, alpha=(0.25, 0.4), rho=-0.3, mu_s=(0.5, -0.2)), 20.0),
    "mixture": (dict(w_d=0.35, mu_d=(-0.2, 0.1), alpha=(0.2, 0.35), rho=0.4, mu_s=(-0.3, 0.25)), 60.0),
}


@pytest.mark.parametrize("case", CASES)
def test_sampler_matches_its_density(case):
    params, theta = CASES[case]

    def sample(u):
        wo = sample_proxy(lobes(len(u), **params, dtype=u.dtype), incident(theta, n=len(u), dtype=u.dtype), u)
        return wo, torch.ones(len(u), dtype=torch.bool)

    def pdf(wo):
        return proxy_pdf(lobes(len(wo), **params, dtype=wo.dtype), incident(theta, n=len(wo), dtype=wo.dtype), wo)

    # quad 16: the reflected density has an integrable singularity at wo = -wi (half vectors orthogonal to wi,
    # Jacobian 1 / (4 |wo.h|)) that 6 x 6 points per cell integrate 0.1% short (the mixture case then fails)
    r = chi2_directions(sample, pdf, n_samples=200_000, sphere=True, n_tests=len(CASES), quad=16)
    assert r, r.message
    assert abs(r.pdf_integral - 1) < 5e-4


def test_density_integrates_to_one_over_the_sphere():
    w = sample_uniform_sphere(torch.rand(400_000, 2, generator=torch.Generator().manual_seed(3), dtype=torch.float64))
    params, theta = CASES["mixture"]
    est = (proxy_pdf(lobes(len(w), **params, dtype=w.dtype), incident(theta, n=len(w), dtype=w.dtype), w)
           * 4 * math.pi).mean().item()
    assert abs(est - 1) < 0.02


def test_centred_isotropic_lobe_is_ggx_ndf_sampling():
    """mu = 0, rho = 0, a_x = a_y = a: p_s(wo) = D(h) h_z / (4 |wo.h|), D the GGX NDF of roughness a."""
    g = torch.Generator().manual_seed(4)
    wo = torch.nn.functional.normalize(torch.randn(5000, 3, generator=g, dtype=torch.float64), dim=-1)
    wi = incident(35.0, n=5000, dtype=torch.float64)
    for a in (0.1, 0.45, 1.0):
        h = torch.nn.functional.normalize(wi + wo, dim=-1)
        h = torch.where(h[:, 2:] < 0, -h, h)
        expected = ggx_ndf(h, a, a) * h[:, 2] / (4 * (wo * h).sum(-1).abs())
        got = proxy_pdf(lobes(5000, 0.0, alpha=(a, a), dtype=torch.float64), wi, wo)
        assert torch.allclose(got, expected, rtol=1e-10, atol=1e-12)


def test_samples_of_the_specular_lobe_reflect_wi_about_their_half_vector():
    u = torch.rand(1000, 2, generator=torch.Generator().manual_seed(5), dtype=torch.float64)
    wi = incident(45.0, n=1000, dtype=torch.float64)
    wo = sample_proxy(lobes(1000, 0.0, alpha=(0.2, 0.3), mu_s=(0.3, 0.1), dtype=torch.float64), wi, u)
    assert torch.allclose(wo.norm(dim=-1), torch.ones(1000, dtype=torch.float64))
    assert torch.allclose((wo * wi).sum(-1), 1 - 2 * (1 - (torch.nn.functional.normalize(wi + wo, dim=-1) * wi)
                                                       .sum(-1) ** 2))   # cos(wi, wo) = 2 cos^2(wi, h) - 1


def test_activations_give_valid_parameters():
    raw = torch.linspace(-50, 50, 9 * 101).reshape(101, 9)
    lo = proxy_from_raw(raw)
    assert bool(((lo.w_d >= 0) & (lo.w_d <= 1)).all())
    assert lo.alpha.min() >= MIN_ALPHA and lo.alpha.max() <= 1
    assert lo.rho.abs().max() <= MAX_RHO
    x = torch.linspace(-3, 3, 601, dtype=torch.float64, requires_grad=True)
    (dt,) = torch.autograd.grad(soft_tanh(x).sum(), x)
    assert torch.allclose(soft_tanh(x[x.abs() >= 2]).abs(), torch.ones(1, dtype=torch.float64))
    assert dt.min() >= 0 and abs(dt[300].item() - 1) < 1e-12       # monotone, tanh'(0) = 1, flat beyond 2
    (ds,) = torch.autograd.grad(soft_sinh(x).sum(), x)
    assert ds.min() >= 1 and torch.allclose(soft_sinh(-x), -soft_sinh(x))


def test_density_gradients_match_finite_differences():
    raw = torch.tensor([[0.3, 0.2, -0.4, -0.1, 0.5, -0.7, 0.3, 0.2, -0.1]] * 4, dtype=torch.float64,
                       requires_grad=True)
    wi = incident(40.0, n=4, dtype=torch.float64)
    wo = torch.nn.functional.normalize(torch.tensor([[0.3, -0.2, 0.9], [-0.5, 0.1, 0.8], [0.1, 0.6, 0.7],
                                                     [0.2, 0.2, -0.3]], dtype=torch.float64), dim=-1)
    assert torch.autograd.gradcheck(lambda r: proxy_pdf(proxy_from_raw(r), wi, wo), (raw,))


def test_bad_input_is_refused():
    with pytest.raises(InputError, match="raw proxy parameters"):
        proxy_from_raw(torch.zeros(4, 8))
    with pytest.raises(InputError, match="raw proxy parameters"):
        proxy_from_raw(torch.full((4, 9), float("nan")))
    wi, u = incident(30.0, n=4), torch.rand(4, 2)
    with pytest.raises(InputError, match="alpha"):
        sample_proxy(lobes(4, 0.5, alpha=(0.0, 0.3)), wi, u)
    with pytest.raises(InputError, match="rho"):
        proxy_pdf(lobes(4, 0.5, rho=1.0), wi, wi)
    with pytest.raises(InputError, match="w_d"):
        proxy_pdf(lobes(4, 1.5), wi, wi)
    with pytest.raises(InputError, match="mu_s"):
        proxy_pdf(lobes(4, 0.5)._replace(mu_s=torch.zeros(3, 2)), wi, wi)
    with pytest.raises(InputError, match="unit length"):
        proxy_pdf(lobes(4, 0.5), wi * 2, wi)
