"""Disk, hemisphere and sphere warps: normalisation, round trips, Jacobians, chi-square."""
import math

import pytest
import torch

from neumat import InputError
from neumat.testing.chi2 import chi2_2d, chi2_directions
from neumat.testing.jacobian import sphere_jacobian
from neumat.warp import (concentric_disk_pdf, cosine_hemisphere_pdf, invert_concentric_disk,
                         invert_cosine_hemisphere, invert_uniform_hemisphere, invert_uniform_sphere,
                         sample_concentric_disk, sample_cosine_hemisphere, sample_uniform_hemisphere,
                         sample_uniform_sphere, uniform_hemisphere_pdf, uniform_sphere_pdf)

DIRECTION_WARPS = {
    "uniform_hemisphere": (sample_uniform_hemisphere, uniform_hemisphere_pdf, invert_uniform_hemisphere, False),
    "cosine_hemisphere": (sample_cosine_hemisphere, cosine_hemisphere_pdf, invert_cosine_hemisphere, False),
    "uniform_sphere": (sample_uniform_sphere, uniform_sphere_pdf, invert_uniform_sphere, True),
}


def _u(n, seed=0, lo=1e-3):
    g = torch.Generator().manual_seed(seed)
    return lo + (1 - 2 * lo) * torch.rand(n, 2, generator=g, dtype=torch.float64)


@pytest.mark.parametrize("name", DIRECTION_WARPS)
def test_direction_warp_roundtrips_and_jacobian(name):
    sample, pdf, invert, _ = DIRECTION_WARPS[name]
    u = _u(2000)
    w = sample(u)
    assert w.dtype == torch.float64
    torch.testing.assert_close(w.norm(dim=-1), torch.ones(2000, dtype=torch.float64))
    torch.testing.assert_close(invert(w), u, atol=1e-9, rtol=0)
    torch.testing.assert_close(sample(invert(w)), w, atol=1e-9, rtol=0)
    # pdf * |Jacobian| = 1 (the warp pushes the uniform density forward)
    torch.testing.assert_close(pdf(w) * sphere_jacobian(sample, u), torch.ones(2000, dtype=torch.float64),
                               atol=0, rtol=1e-5)


@pytest.mark.parametrize("name", DIRECTION_WARPS)
def test_direction_pdf_integrates_to_one(name):
    _, pdf, _, sphere = DIRECTION_WARPS[name]
    # uniform-sphere Monte Carlo estimate of the integral of pdf
    w = sample_uniform_sphere(_u(200_000, seed=1, lo=0))
    est = (pdf(w) * 4 * math.pi).mean().item()
    assert abs(est - 1) < 0.01


@pytest.mark.parametrize("name", DIRECTION_WARPS)
def test_direction_chi2(name):
    sample, pdf, _, sphere = DIRECTION_WARPS[name]
    r = chi2_directions(lambda u: (sample(u), torch.ones(len(u), dtype=torch.bool)), pdf, n_samples=100_000,
                        sphere=sphere, n_tests=len(DIRECTION_WARPS))
    assert r, r.message
    assert abs(r.pdf_integral - 1) < 1e-4


def test_hemisphere_pdfs_vanish_below_horizon():
    w = torch.tensor([[0.0, 0.6, -0.8]])
    assert uniform_hemisphere_pdf(w).item() == 0 and cosine_hemisphere_pdf(w).item() == 0


def test_disk_roundtrip_jacobian_and_chi2():
    u = _u(2000)
    p = sample_concentric_disk(u)
    assert (p.norm(dim=-1) <= 1 + 1e-12).all()
    torch.testing.assert_close(invert_concentric_disk(p), u, atol=1e-9, rtol=0)
    torch.testing.assert_close(sample_concentric_disk(invert_concentric_disk(p)), p, atol=1e-9, rtol=0)
    h = 1e-6
    e0, e1 = torch.tensor([h, 0.0], dtype=u.dtype), torch.tensor([0.0, h], dtype=u.dtype)
    d0 = (sample_concentric_disk(u + e0) - sample_concentric_disk(u - e0)) / (2 * h)
    d1 = (sample_concentric_disk(u + e1) - sample_concentric_disk(u - e1)) / (2 * h)
    jac = (d0[:, 0] * d1[:, 1] - d0[:, 1] * d1[:, 0]).abs()
    torch.testing.assert_close(concentric_disk_pdf(p) * jac, torch.ones(2000, dtype=torch.float64), atol=0, rtol=1e-5)
    assert concentric_disk_pdf(torch.tensor([[0.8, 0.7]])).item() == 0
    # exact points: centre and the square's edge midpoints
    corners = torch.tensor([[0.5, 0.5], [1.0, 0.5], [0.5, 1.0]])
    torch.testing.assert_close(sample_concentric_disk(corners), torch.tensor([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]),
                               atol=1e-7, rtol=0)
    r = chi2_2d(sample_concentric_disk, concentric_disk_pdf, n_samples=100_000, domain="disk", res=(20, 40))
    assert r, r.message


def test_float32_and_bad_input():
    u = torch.rand(10, 2)
    assert sample_cosine_hemisphere(u).dtype == torch.float32
    with pytest.raises(InputError, match="u"):
        sample_uniform_sphere(torch.rand(10, 3))
    with pytest.raises(InputError, match="w"):
        uniform_sphere_pdf(torch.ones(4, 3))
