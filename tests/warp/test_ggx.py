"""GGX visible-normal and reflection warps: chi-square, round trips, Jacobian = 1 / pdf, bad input."""
import math

import pytest
import torch

from neumat import InputError
from neumat.testing.chi2 import chi2_directions
from neumat.testing.jacobian import sphere_jacobian
from neumat.warp import (ggx_reflection_pdf, ggx_vndf_pdf, invert_ggx_reflection, invert_ggx_vndf,
                         sample_ggx_reflection, sample_ggx_vndf)

CASES = [  # (theta_i, phi_i, alpha_x, alpha_y)
    (0.0, 0.0, 0.3, 0.3),
    (0.6, 0.4, 0.1, 0.1),
    (1.2, 2.0, 0.5, 0.5),
    (1.45, -1.0, 0.8, 0.8),
    (0.9, 0.7, 0.4, 0.1),
    (1.3, 2.5, 0.1, 0.6),
]


def _wi(theta, phi, dtype=torch.float32):
    return torch.tensor([math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta)],
                        dtype=torch.float64).to(dtype)


def _u(n, seed=0, lo=1e-3):
    g = torch.Generator().manual_seed(seed)
    return lo + (1 - 2 * lo) * torch.rand(n, 2, generator=g, dtype=torch.float64)


def _chi2(sample, pdf, wi, ax, ay, n, res):
    def sample_fn(u):
        w = sample(wi.expand(len(u), 3), u, ax, ay)
        return w, w[:, 2] > 0

    return chi2_directions(sample_fn, lambda w: pdf(wi.expand(len(w), 3), w, ax, ay), n_samples=n, res=res,
                           quad=16, n_tests=2 * len(CASES))


@pytest.mark.parametrize("theta,phi,ax,ay", CASES)
def test_vndf_and_reflection_chi2(theta, phi, ax, ay):
    wi = _wi(theta, phi)
    r = _chi2(sample_ggx_vndf, ggx_vndf_pdf, wi, ax, ay, 200_000, (20, 40))
    assert r.passed, r.message
    assert abs(r.pdf_integral - 1) < 2e-3, r.message  # every visible normal lies in the upper hemisphere
    r = _chi2(sample_ggx_reflection, ggx_reflection_pdf, wi, ax, ay, 200_000, (20, 40))
    assert r.passed, r.message


@pytest.mark.slow
@pytest.mark.parametrize("theta,phi,ax,ay", CASES)
def test_vndf_and_reflection_chi2_large(theta, phi, ax, ay):
    wi = _wi(theta, phi)
    for sample, pdf in ((sample_ggx_vndf, ggx_vndf_pdf), (sample_ggx_reflection, ggx_reflection_pdf)):
        r = _chi2(sample, pdf, wi, ax, ay, 4_000_000, (40, 80))
        assert r.passed, r.message


@pytest.mark.parametrize("theta,phi,ax,ay", CASES)
def test_roundtrips_and_jacobian(theta, phi, ax, ay):
    wi = _wi(theta, phi, torch.float64).expand(2000, 3)
    u = _u(2000)
    m = sample_ggx_vndf(wi, u, ax, ay)
    torch.testing.assert_close(m.norm(dim=-1), torch.ones(2000, dtype=torch.float64))
    assert bool(((wi * m).sum(-1) >= 0).all()) and bool((m[:, 2] >= 0).all())
    torch.testing.assert_close(invert_ggx_vndf(wi, m, ax, ay), u, atol=1e-9, rtol=0)
    wo = sample_ggx_reflection(wi, u, ax, ay)
    up = wo[:, 2] > 1e-6
    torch.testing.assert_close(invert_ggx_reflection(wi[up], wo[up], ax, ay), u[up], atol=1e-8, rtol=0)
    # density times the area element of the map u -> m is 1 (central differences)
    jac = sphere_jacobian(lambda v: sample_ggx_vndf(wi, v, ax, ay), u)
    torch.testing.assert_close(ggx_vndf_pdf(wi, m, ax, ay) * jac, torch.ones(2000, dtype=torch.float64),
                               atol=0, rtol=1e-4)


def test_reflection_pdf_is_vndf_over_four_cos():
    wi = _wi(0.8, 0.3, torch.float64).expand(1000, 3)
    wo = sample_ggx_reflection(wi, _u(1000, seed=3), 0.3, 0.2)
    up = wo[:, 2] > 0
    h = (wi + wo) / (wi + wo).norm(dim=-1, keepdim=True)
    expected = ggx_vndf_pdf(wi, h, 0.3, 0.2) / (4 * (wi * h).sum(-1))
    torch.testing.assert_close(ggx_reflection_pdf(wi, wo, 0.3, 0.2)[up], expected[up], rtol=1e-12, atol=0)
    assert bool((ggx_reflection_pdf(wi, wo, 0.3, 0.2)[~up] == 0).all())


def test_per_query_alphas_and_zero_density_cases():
    wi = _wi(0.5, 0.0).expand(4, 3)
    ax = torch.tensor([0.1, 0.2, 0.3, 0.4])
    m = sample_ggx_vndf(wi, torch.full((4, 2), 0.3), ax, ax.flip(0))
    assert m.shape == (4, 3) and torch.isfinite(m).all()
    below = torch.tensor([[0.0, 0.0, -1.0]])
    assert ggx_vndf_pdf(below, torch.tensor([[0.0, 0.0, 1.0]]), 0.3, 0.3).item() == 0
    assert ggx_vndf_pdf(_wi(0.3, 0)[None], torch.tensor([[0.0, 0.0, -1.0]]), 0.3, 0.3).item() == 0


def test_bad_input():
    wi = _wi(0.5, 0.0).expand(3, 3)
    u = torch.rand(3, 2)
    with pytest.raises(InputError, match="alpha_x"):
        sample_ggx_vndf(wi, u, 0.0, 0.3)
    with pytest.raises(InputError, match="alpha_y"):
        ggx_vndf_pdf(wi, wi, 0.3, torch.tensor([0.1, 0.2]))
    with pytest.raises(InputError, match="u"):
        sample_ggx_vndf(wi, torch.rand(4, 2), 0.3, 0.3)
    with pytest.raises(InputError, match="unit length"):
        sample_ggx_reflection(2 * wi, u, 0.3, 0.3)
    with pytest.raises(InputError, match="wo"):
        ggx_reflection_pdf(wi, wi[:2], 0.3, 0.3)
    with pytest.raises(InputError, match="alpha_x"):
        invert_ggx_vndf(wi, wi, float("nan"), 0.3)
