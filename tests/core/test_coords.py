import math

import pytest
import torch

from neumat.core.coords import (disk_to_hemisphere, disk_to_polar, dir_to_spherical, hd_to_io, hd_vectors,
                                hemisphere_to_disk, io_to_hd, io_to_rusinkiewicz, polar_to_disk,
                                rusinkiewicz_to_io, spherical_to_dir)


def _hemi(n, gen):
    w = torch.nn.functional.normalize(torch.randn(n, 3, generator=gen, dtype=torch.float64), dim=-1)
    w[:, 2] = w[:, 2].abs()
    return w


def test_spherical_round_trip(gen):
    w = torch.nn.functional.normalize(torch.randn(1000, 3, generator=gen, dtype=torch.float64), dim=-1)
    theta, phi = dir_to_spherical(w)
    assert theta.min() >= 0 and theta.max() <= math.pi and phi.min() >= 0 and phi.max() < 2 * math.pi
    assert torch.allclose(spherical_to_dir(theta, phi), w, atol=1e-12)


def test_half_difference_round_trip(gen):
    wi, wo = _hemi(2000, gen), _hemi(2000, gen)
    h, d = io_to_hd(wi, wo)
    a, b = hd_to_io(h, d)
    assert torch.allclose(a, wi, atol=1e-10) and torch.allclose(b, wo, atol=1e-10)
    angles = io_to_rusinkiewicz(wi, wo)
    a, b = rusinkiewicz_to_io(*angles)
    assert torch.allclose(a, wi, atol=1e-10) and torch.allclose(b, wo, atol=1e-10)


def test_rusinkiewicz_against_definition(gen):
    wi, wo = _hemi(500, gen), _hemi(500, gen)
    theta_h, _, theta_d, phi_d = io_to_rusinkiewicz(wi, wo)
    h = torch.nn.functional.normalize(wi + wo, dim=-1)
    # theta_h is the angle of h to the normal; theta_d the angle between wi and h
    assert torch.allclose(torch.cos(theta_h), h[:, 2], atol=1e-10)
    assert torch.allclose(torch.cos(theta_d), (wi * h).sum(-1), atol=1e-10)
    # swapping wi and wo rotates phi_d by pi (the reciprocity fold of MERL relies on it)
    _, _, theta_d2, phi_d2 = io_to_rusinkiewicz(wo, wi)
    assert torch.allclose(theta_d2, theta_d, atol=1e-10)
    dphi = torch.remainder(phi_d2 - phi_d, 2 * math.pi)
    assert torch.allclose(dphi, torch.full_like(dphi, math.pi), atol=1e-8)


def test_disk_maps_round_trip(gen):
    w = _hemi(1000, gen)
    p = hemisphere_to_disk(w)
    assert (p.norm(dim=-1) <= 1 + 1e-12).all()
    assert torch.allclose(disk_to_hemisphere(p), w, atol=1e-7)
    r, phi = disk_to_polar(p)
    assert torch.allclose(polar_to_disk(r, phi), p, atol=1e-12)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_dtype_follows_input(dtype):
    w = torch.tensor([[0.0, 0.6, 0.8]], dtype=dtype)
    assert dir_to_spherical(w)[0].dtype == dtype
    assert io_to_hd(w, w)[1].dtype == dtype


@pytest.mark.parametrize("dtype, atol", [(torch.float64, 1e-12), (torch.float32, 2e-5)])
def test_hd_vectors_equal_io_to_hd(gen, dtype, atol):
    """The trigonometry-free h, d equal `io_to_hd`'s (float32: its acos / cos round trip loses ~1e-5 near the
    pole), including h at the pole (phi_h = 0 in both)."""
    wi, wo = _hemi(5000, gen), _hemi(5000, gen)
    wo[:10] = wi[:10] * torch.tensor([-1.0, -1.0, 1.0], dtype=torch.float64)  # h = +z exactly
    wi, wo = wi.to(dtype), wo.to(dtype)
    h, d = io_to_hd(wi, wo)
    h2, d2 = hd_vectors(wi, wo)
    torch.testing.assert_close(h2, h, atol=atol, rtol=0)
    torch.testing.assert_close(d2, d, atol=atol, rtol=0)
    torch.testing.assert_close(d2[:10], wi[:10], atol=atol, rtol=0)
