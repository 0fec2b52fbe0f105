"""Azimuthal-equidistant Gaussian lobe (NeuPreSS): normalisation, closed form, round trips, chi-square, gradients."""
import math

import numpy as np
import pytest
import torch

from neumat import InputError
from neumat.testing.chi2 import chi2_2d, chi2_directions
from neumat.testing.jacobian import sphere_jacobian
from neumat.warp import azimuthal_gaussian_pdf, invert_azimuthal_gaussian, sample_azimuthal_gaussian

Z = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
TILTED = torch.nn.functional.normalize(torch.tensor([0.3, -0.5, 0.8], dtype=torch.float64), dim=0)
SIGMAS = [1e-3, 0.1, 0.5, 2.0, 10.0, 1e3]


def _u(n, seed=0, lo=1e-3, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    return (lo + (1 - 2 * lo) * torch.rand(n, 2, generator=g, dtype=torch.float64)).to(dtype)


def _frame(axis):
    """An orthonormal frame (t, b) around axis, built independently of neumat.core.frames."""
    e = torch.tensor([1.0, 0.0, 0.0], dtype=axis.dtype) if abs(axis[0]) < 0.9 else torch.tensor([0.0, 1.0, 0.0],
                                                                                                  dtype=axis.dtype)
    t = e - (e @ axis) * axis
    t = t / t.norm()
    return t, torch.linalg.cross(axis, t)


def _polar(axis, theta, phi):
    """Directions (N, 3) at angle theta from axis and azimuth phi in `_frame(axis)`."""
    t, b = _frame(axis)
    return (torch.sin(theta)[:, None] * (torch.cos(phi)[:, None] * t + torch.sin(phi)[:, None] * b)
            + torch.cos(theta)[:, None] * axis)


def _reference_pdf(theta, sigma):
    """float64 textbook form exp(-theta^2 / 2 s^2) / (2 pi s^2 (1 - exp(-pi^2 / 2 s^2))) theta / sin theta."""
    c = 1 - math.exp(-math.pi ** 2 / (2 * sigma ** 2))
    return torch.exp(-theta ** 2 / (2 * sigma ** 2)) / (2 * math.pi * sigma ** 2 * c) * theta / torch.sin(theta)


def _valid(w):
    return torch.ones(len(w), dtype=torch.bool)


@pytest.mark.parametrize("axis", [Z, TILTED], ids=["z", "tilted"])
@pytest.mark.parametrize("sigma", [0.1, 0.5, 2.0, 10.0])
def test_chi2_axis_polar(sigma, axis):
    """Chi-square over the whole sphere, binned in (theta / pi, phi / 2 pi) around the axis (test's own frame).

    The pdf diverges like 1 / (pi - theta) at the antipode; in these coordinates the cell density
    pdf sin(theta) is smooth there, so the cell integrals are exact for every sigma.
    """
    ax = axis.float()
    t, b = _frame(ax)

    def sample_fn(u):
        w = sample_azimuthal_gaussian(u, ax, sigma)
        theta = 2 * torch.atan2((w - ax).norm(dim=-1), (w + ax).norm(dim=-1))
        phi = torch.remainder(torch.atan2(w @ b, w @ t), 2 * math.pi)
        return torch.stack([theta / math.pi, phi / (2 * math.pi)], -1)

    def pdf_fn(p):
        theta, phi = math.pi * p[:, 0], 2 * math.pi * p[:, 1]
        return azimuthal_gaussian_pdf(_polar(ax, theta, phi), ax, sigma) * torch.sin(theta) * 2 * math.pi ** 2

    r = chi2_2d(sample_fn, pdf_fn, n_samples=200_000, n_tests=8)
    assert r, r.message
    assert abs(r.pdf_integral - 1) < 1e-4


@pytest.mark.parametrize("axis", [Z, TILTED], ids=["z", "tilted"])
@pytest.mark.parametrize("sigma", [0.1, 0.5])
def test_chi2_world_grid(sigma, axis):
    """Chi-square on the world (cos theta, phi) grid over the whole sphere.

    Only for sigma where the lobe has no mass near the antipode: there the density's integrable 1 / (pi - theta)
    spike defeats the grid's Gauss-Legendre cell integrals (pdf integral off by ~1e-3 at sigma = 10),
    which `test_chi2_axis_polar` avoids.
    """
    ax = axis.float()
    r = chi2_directions(lambda u: (sample_azimuthal_gaussian(u, ax, sigma), _valid(u)),
                        lambda w: azimuthal_gaussian_pdf(w, ax, sigma), n_samples=200_000, sphere=True, n_tests=4)
    assert r, r.message
    assert abs(r.pdf_integral - 1) < 1e-4


@pytest.mark.parametrize("sigma", SIGMAS)
def test_pdf_integrates_to_one(sigma):
    """float64 quadrature in polar coordinates around a tilted axis: composite 16-point Gauss-Legendre in theta
    over [0, min(pi, 40 sigma)] (64 panels; beyond 40 sigma the lobe is < e^-800) times the trapezoid rule in phi
    (exact for the phi-independent lobe, 8 nodes). Tolerance 1e-12."""
    x, wq = (torch.from_numpy(a) for a in np.polynomial.legendre.leggauss(16))
    top, panels = min(math.pi, 40 * sigma), 64
    h = top / panels
    theta = ((torch.arange(panels, dtype=torch.float64)[:, None] + (x[None] + 1) / 2) * h).reshape(-1)
    wt = (wq / 2 * h).repeat(panels)
    n_phi = 8
    phi = torch.arange(n_phi, dtype=torch.float64) * 2 * math.pi / n_phi
    tt, pp = torch.meshgrid(theta, phi, indexing="ij")
    w = _polar(TILTED, tt.reshape(-1), pp.reshape(-1))
    p = azimuthal_gaussian_pdf(w, TILTED, sigma).reshape(tt.shape)
    integral = ((p * torch.sin(tt)).sum(1) * 2 * math.pi / n_phi * wt).sum().item()
    assert abs(integral - 1) < 1e-12


@pytest.mark.parametrize("sigma", [0.05, 0.5, 2.0, 10.0])
def test_pdf_matches_reference(sigma):
    g = torch.Generator().manual_seed(1)
    theta = 0.01 + (math.pi - 0.02) * torch.rand(5000, generator=g, dtype=torch.float64)
    phi = 2 * math.pi * torch.rand(5000, generator=g, dtype=torch.float64)
    w = _polar(TILTED, theta, phi)
    torch.testing.assert_close(azimuthal_gaussian_pdf(w, TILTED, sigma), _reference_pdf(theta, sigma),
                               rtol=1e-10, atol=1e-290)  # atol: far tail of sigma = 0.05 is subnormal


def test_axis_and_antipode_are_stable():
    for sigma in SIGMAS:
        c = -math.expm1(-math.pi ** 2 / (2 * sigma ** 2))
        at_axis = azimuthal_gaussian_pdf(Z[None], Z, sigma)
        torch.testing.assert_close(at_axis, torch.tensor([1 / (2 * math.pi * sigma ** 2 * c)], dtype=torch.float64),
                                   rtol=1e-14, atol=0)
        # theta = pi - 1e-7 and 1e-7: textbook formula is fine there in float64
        eps = torch.tensor([1e-7, math.pi - 1e-7], dtype=torch.float64)
        w = _polar(TILTED, eps, torch.tensor([0.3, 2.0], dtype=torch.float64))
        torch.testing.assert_close(azimuthal_gaussian_pdf(w, TILTED, sigma), _reference_pdf(eps, sigma),
                                   rtol=1e-8, atol=0)
    for dtype in (torch.float32, torch.float64):
        # exactly at the antipode the density diverges; it is capped to a large finite value
        p = azimuthal_gaussian_pdf(-Z[None].to(dtype), Z.to(dtype), 2.0)
        assert torch.isfinite(p).all() and p.item() > 1e6


@pytest.mark.parametrize("sigma", SIGMAS)
def test_roundtrip_and_jacobian(sigma):
    u = _u(2000)
    w = sample_azimuthal_gaussian(u, TILTED, sigma)
    assert torch.isfinite(w).all()
    torch.testing.assert_close(w.norm(dim=-1), torch.ones(2000, dtype=torch.float64))
    torch.testing.assert_close(invert_azimuthal_gaussian(w, TILTED, sigma), u, atol=1e-9, rtol=0)
    torch.testing.assert_close(sample_azimuthal_gaussian(invert_azimuthal_gaussian(w, TILTED, sigma), TILTED, sigma),
                               w, atol=1e-9, rtol=0)
    # pdf * |dw/du| = 1 (central differences)
    jac = sphere_jacobian(lambda v: sample_azimuthal_gaussian(v, TILTED, sigma), u)
    torch.testing.assert_close(azimuthal_gaussian_pdf(w, TILTED, sigma) * jac, torch.ones(2000, dtype=torch.float64),
                               atol=0, rtol=1e-4)


def test_batched_axes_and_sigmas():
    g = torch.Generator().manual_seed(3)
    axis = torch.nn.functional.normalize(torch.randn(500, 3, generator=g, dtype=torch.float64), dim=-1)
    sigma = 10 ** (-3 + 6 * torch.rand(500, generator=g, dtype=torch.float64))
    u = _u(500)
    w = sample_azimuthal_gaussian(u, axis, sigma)
    torch.testing.assert_close(invert_azimuthal_gaussian(w, axis, sigma), u, atol=1e-9, rtol=0)
    theta = torch.arccos((w * axis).sum(-1).clamp(-1, 1))
    ok = (theta > 1e-3) & (theta < math.pi - 1e-3)  # where arccos is accurate enough for the reference
    ref = torch.stack([_reference_pdf(t[None], s.item())[0] for t, s in zip(theta[ok], sigma[ok])])
    torch.testing.assert_close(azimuthal_gaussian_pdf(w, axis, sigma)[ok], ref, rtol=1e-6, atol=0)


def test_small_sigma_is_the_plane_gaussian():
    for dtype, rtol in ((torch.float64, 1e-12), (torch.float32, 1e-5)):
        sigma = 1e-3
        axis = TILTED.to(dtype)
        plane_peak = 1 / (2 * math.pi * sigma ** 2)
        torch.testing.assert_close(azimuthal_gaussian_pdf(axis[None], axis, sigma).double(),
                                   torch.tensor([plane_peak], dtype=torch.float64), rtol=rtol, atol=0)
        # at theta = r = k sigma the lobe is the plane Gaussian up to theta / sin(theta) = 1 + O(theta^2)
        k = torch.tensor([0.5, 1.0, 2.0], dtype=torch.float64)
        w = _polar(TILTED, k * sigma, torch.tensor([0.1, 2.0, 4.0], dtype=torch.float64)).to(dtype)
        torch.testing.assert_close(azimuthal_gaussian_pdf(w, axis, sigma).double(), plane_peak * torch.exp(-k ** 2 / 2),
                                   rtol=1e-3 if dtype == torch.float32 else 1e-6, atol=0)


def test_large_sigma_is_uniform_over_the_projected_disk():
    u = _u(1000)
    w = sample_azimuthal_gaussian(u, Z, 1e3)
    theta = torch.arccos(w[:, 2].clamp(-1, 1))
    torch.testing.assert_close(theta / math.pi, u[:, 0].sqrt(), atol=1e-5, rtol=0)
    # the planar density tends to 1 / pi^3 (uniform disk of radius pi)
    p = azimuthal_gaussian_pdf(w, Z, 1e3) * torch.sin(theta) / theta
    torch.testing.assert_close(p, torch.full_like(p, math.pi ** -3), rtol=1e-5, atol=0)


@pytest.mark.parametrize("sigma", [1e-3, 1e3])
def test_float32_extremes(sigma):
    u = torch.rand(20_000, 2, generator=torch.Generator().manual_seed(4))
    u[:4] = torch.tensor([[0.0, 0.0], [1.0, 1.0], [0.0, 1.0], [1.0, 0.5]])
    axis = TILTED.float()
    w = sample_azimuthal_gaussian(u, axis, sigma)
    assert w.dtype == torch.float32 and torch.isfinite(w).all()
    torch.testing.assert_close(w.norm(dim=-1), torch.ones(len(w)), atol=1e-5, rtol=0)
    p = azimuthal_gaussian_pdf(w, axis, sigma)
    assert torch.isfinite(p).all() and (p > 0).all()
    back = invert_azimuthal_gaussian(w[4:], axis, sigma)
    assert torch.isfinite(back).all()
    torch.testing.assert_close(back[:, 0], u[4:, 0], atol=2e-3, rtol=0)


def test_gradients_wrt_sigma():
    g = torch.Generator().manual_seed(5)
    n = 12
    theta = math.pi * torch.rand(n, generator=g, dtype=torch.float64)
    w = _polar(TILTED, theta, 2 * math.pi * torch.rand(n, generator=g, dtype=torch.float64))
    sigma = (10 ** (-1.3 + 2.6 * torch.rand(n, generator=g, dtype=torch.float64))).requires_grad_()
    u = _u(n, seed=6)
    assert torch.autograd.gradcheck(lambda s: azimuthal_gaussian_pdf(w, TILTED, s), (sigma,))
    assert torch.autograd.gradcheck(lambda s: sample_azimuthal_gaussian(u, TILTED, s), (sigma,))
    assert torch.autograd.gradcheck(lambda s: invert_azimuthal_gaussian(w, TILTED, s)[:, 0], (sigma,))
    # finite gradients at the ends of the u range too
    s = torch.full((4,), 0.3, dtype=torch.float64, requires_grad=True)
    edge = torch.tensor([[0.0, 0.0], [1.0, 0.2], [1e-300, 0.5], [1 - 1e-16, 0.9]], dtype=torch.float64)
    sample_azimuthal_gaussian(edge, TILTED, s).sum().backward()
    assert torch.isfinite(s.grad).all()


def test_dtype_follows_inputs():
    u = _u(8, dtype=torch.float32)
    w = sample_azimuthal_gaussian(u, TILTED.float(), torch.full((8,), 0.4))
    assert w.dtype == torch.float32
    assert azimuthal_gaussian_pdf(w, TILTED.float(), 0.4).dtype == torch.float32
    assert invert_azimuthal_gaussian(w, TILTED.float(), 0.4).dtype == torch.float32
    assert sample_azimuthal_gaussian(torch.zeros(0, 2), TILTED.float(), 0.4).shape == (0, 3)


def test_bad_input():
    u = torch.rand(4, 2)
    w = torch.nn.functional.normalize(torch.randn(4, 3), dim=-1)
    ax = TILTED.float()
    with pytest.raises(InputError, match="sigma"):
        sample_azimuthal_gaussian(u, ax, 0.0)
    with pytest.raises(InputError, match="sigma"):
        azimuthal_gaussian_pdf(w, ax, torch.tensor([0.1, -1.0, 0.1, 0.1]))
    with pytest.raises(InputError, match="sigma"):
        invert_azimuthal_gaussian(w, ax, float("nan"))
    with pytest.raises(InputError, match="sigma"):
        sample_azimuthal_gaussian(u, ax, float("inf"))
    with pytest.raises(InputError, match="sigma"):
        azimuthal_gaussian_pdf(w, ax, torch.ones(3))
    with pytest.raises(InputError, match="axis"):
        sample_azimuthal_gaussian(u, torch.tensor([1.0, 1.0, 0.0]), 0.5)
    with pytest.raises(InputError, match="axis"):
        azimuthal_gaussian_pdf(w, torch.tensor([[0.0, 0.0, 1.0]] * 3), 0.5)
    with pytest.raises(InputError, match="axis"):
        invert_azimuthal_gaussian(w, torch.tensor([0.0, 1.0]), 0.5)
    with pytest.raises(InputError, match="w"):
        azimuthal_gaussian_pdf(2 * w, ax, 0.5)
    with pytest.raises(InputError, match="w"):
        invert_azimuthal_gaussian(w[:, :2], ax, 0.5)
    with pytest.raises(InputError, match="u"):
        sample_azimuthal_gaussian(torch.rand(4, 3), ax, 0.5)
    with pytest.raises(InputError, match="u"):
        sample_azimuthal_gaussian(torch.tensor([[0.5, float("nan")]]), ax, 0.5)
