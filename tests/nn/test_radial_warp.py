import math

import pytest
import torch

from neumat.core.errors import InputError
from neumat.nn.radial_warp import RadialWarp, warp_radius


def test_near_identity_at_initialisation():
    r = torch.linspace(0, 1, 1001, dtype=torch.float64)
    warp = RadialWarp(2).double()
    bound = r * (torch.cosh(0.1 * torch.log(r.clamp(min=1e-9))) - 1)
    err = (warp(r) - r).abs()
    assert bool((err <= bound * (1 + 1e-5) + 1e-8).all()) and err.max() < 3e-3
    z = torch.randn(1001, 8, dtype=torch.float64)
    torch.testing.assert_close(RadialWarp(2, latent_dim=8).double()(r, z), warp(r))


def test_matches_formula_and_is_monotone_onto_unit_interval():
    g = torch.Generator().manual_seed(0)
    logits = torch.randn(50, 2, generator=g, dtype=torch.float64) * 2
    raw = torch.randn(50, 2, generator=g, dtype=torch.float64) * 2
    r = torch.linspace(0, 1, 201, dtype=torch.float64)
    for k in range(50):
        w = torch.softmax(logits[k], 0)
        alpha = 0.5 + torch.nn.functional.softplus(raw[k])
        assert bool((alpha >= 0.5).all())
        ref = w[0] * r ** alpha[0] + w[1] * r ** alpha[1]
        got = warp_radius(r, logits[k], raw[k])
        torch.testing.assert_close(got[1:], ref[1:])
        assert got[0] < 1e-4 and abs(got[-1] - 1) < 1e-12
        assert bool((got[1:] - got[:-1] > 0).all())


def test_square_root_warp_is_reachable():
    """Dupuy & Jakob's choice (one term, alpha = 1/2) is the limit of the parameterisation."""
    got = warp_radius(torch.tensor([0.25]), torch.tensor([0.0]), torch.tensor([-40.0]))
    assert got.item() == pytest.approx(math.sqrt(0.25), abs=1e-6)


def test_gradients_are_finite_at_zero_and_latent_warp_needs_z():
    r = torch.tensor([0.0, 0.5, 1.0])
    warp = RadialWarp(2)
    warp(r).sum().backward()
    assert bool(torch.isfinite(warp.params.grad).all())
    with pytest.raises(InputError, match="pass z"):
        RadialWarp(2, latent_dim=4)(r)
    with pytest.raises(InputError, match="terms"):
        RadialWarp(0)
