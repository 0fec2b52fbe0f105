import math

import numpy as np
import pytest
import torch
from scipy.interpolate import RegularGridInterpolator

from neumat.core.coords import disk_to_polar, io_to_hd
from neumat.core.errors import InputError
from neumat.nn.angular_texture import AngularTexture, disk_polar, half_difference
from neumat.warp.hemisphere import sample_cosine_hemisphere


def _pairs(n, seed=0):
    g = torch.Generator().manual_seed(seed)
    return (sample_cosine_hemisphere(torch.rand(n, 2, generator=g, dtype=torch.float64)),
            sample_cosine_hemisphere(torch.rand(n, 2, generator=g, dtype=torch.float64)))


def test_half_difference_matches_rusinkiewicz_coords():
    wi, wo = _pairs(2000)
    h, d = half_difference(wi, wo)
    h_ref, d_ref = io_to_hd(wi, wo)
    torch.testing.assert_close(h, h_ref)
    torch.testing.assert_close(d, d_ref, atol=1e-9, rtol=0)


def test_gradients_are_finite_at_the_pole():
    wi = torch.tensor([[0.3, 0.1, math.sqrt(0.9)]], dtype=torch.float64, requires_grad=True)
    wo = torch.tensor([[-0.3, -0.1, math.sqrt(0.9)]], dtype=torch.float64, requires_grad=True)  # h = +z
    h, d = half_difference(wi, wo)
    r, phi = disk_polar(h)
    (r + phi + d.sum()).sum().backward()
    assert bool(torch.isfinite(wi.grad).all() and torch.isfinite(wo.grad).all())


def test_disk_polar_matches_coords_and_wraps():
    wi, _ = _pairs(500, seed=1)
    r, phi = disk_polar(wi)
    r_ref, phi_ref = disk_to_polar(wi[:, :2])
    torch.testing.assert_close(r, r_ref)
    torch.testing.assert_close(phi, phi_ref)
    _, phi_pi = disk_polar(wi, math.pi)
    torch.testing.assert_close(phi_pi, torch.remainder(phi_ref, math.pi))


def _reference(tex: np.ndarray, period: float, r: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Independent bilinear reference: explicitly padded grid (pole row broadcast, one circular column
    each side) interpolated with scipy."""
    c, nr, nphi = tex.shape
    grid = tex.copy()
    grid[:, 0, :] = tex[:, 0, :1]
    grid = np.concatenate([grid[:, :, -1:], grid, grid[:, :, :1]], axis=2)
    rs = np.arange(nr) / (nr - 1)
    phis = (np.arange(-1, nphi + 1) + 0.5) * period / nphi
    pts = np.stack([r, np.mod(phi, period)], -1)
    return np.stack([RegularGridInterpolator((rs, phis), grid[k])(pts) for k in range(c)], -1)


@pytest.mark.parametrize("period", [2 * math.pi, math.pi])
def test_read_matches_padded_bilinear_reference(period):
    torch.manual_seed(0)
    tex = AngularTexture(3, 6, 10, period).double()
    g = torch.Generator().manual_seed(2)
    r = torch.rand(3000, generator=g, dtype=torch.float64)
    phi = torch.rand(3000, generator=g, dtype=torch.float64) * 4 * math.pi - math.pi
    got = tex(r, phi)
    ref = _reference(tex.raw.detach().numpy(), period, r.numpy(), phi.numpy())
    np.testing.assert_allclose(got.detach().numpy(), ref, atol=1e-12)


def test_pole_is_single_valued_and_texel_centres_are_exact():
    tex = AngularTexture(2, 5, 8).double()
    phi = torch.linspace(0, 2 * math.pi, 17, dtype=torch.float64)
    at_pole = tex(torch.zeros(17, dtype=torch.float64), phi)
    torch.testing.assert_close(at_pole, tex.raw[:, 0, 0].detach().expand(17, 2))
    i, j = 3, 5
    value = tex(torch.tensor([i / 4], dtype=torch.float64), torch.tensor([(j + 0.5) * 2 * math.pi / 8],
                                                                          dtype=torch.float64))
    torch.testing.assert_close(value[0], tex.raw[:, i, j].detach())


def test_difference_read_is_reciprocal():
    wi, wo = _pairs(3000, seed=3)
    tex = AngularTexture(4, 8, 12, math.pi).double()
    _, d = half_difference(wi, wo)
    _, d_swapped = half_difference(wo, wi)
    torch.testing.assert_close(d_swapped[:, :2], -d[:, :2])
    a = tex(*disk_polar(d, math.pi))
    b = tex(*disk_polar(d_swapped, math.pi))
    torch.testing.assert_close(a, b, atol=1e-9, rtol=0)


def test_bad_sizes_raise():
    with pytest.raises(InputError, match="radial"):
        AngularTexture(4, 1, 8)



def test_read_is_differentiable_in_texture_and_radius():
    """Gradients of the fused read (texels and r, which the radial warps need) match finite differences."""
    torch.manual_seed(3)
    tex = AngularTexture(2, 5, 7, math.pi).double()
    g = torch.Generator().manual_seed(4)
    r = (torch.rand(20, generator=g, dtype=torch.float64) * 0.9 + 0.05).requires_grad_()
    phi = torch.rand(20, generator=g, dtype=torch.float64) * 3 * math.pi
    raw = tex.raw.detach().clone().requires_grad_()
    read = lambda raw, r: torch.func.functional_call(tex, {"raw": raw}, (r, phi))  # noqa: E731
    assert torch.autograd.gradcheck(read, (raw, r))
