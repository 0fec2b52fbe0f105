"""von Mises-Fisher warp: closed-form normalisation, stability at extreme kappa, round trips, chi-square."""
import math

import pytest
import torch

from neumat import InputError
from neumat.testing.chi2 import chi2_directions
from neumat.testing.jacobian import sphere_jacobian
from neumat.warp import invert_vmf, sample_uniform_sphere, sample_vmf, uniform_sphere_pdf, vmf_pdf

MU = torch.tensor([0.48, -0.6, 0.64], dtype=torch.float64)


def _u(n, seed=0, lo=1e-3):
    g = torch.Generator().manual_seed(seed)
    return lo + (1 - 2 * lo) * torch.rand(n, 2, generator=g, dtype=torch.float64)


def _reference_pdf(cos, kappa):
    """float64 closed form kappa exp(kappa cos) / (4 pi sinh kappa), fine for moderate kappa."""
    kappa = torch.as_tensor(kappa, dtype=torch.float64)
    return kappa * torch.exp(kappa * cos) / (4 * math.pi * torch.sinh(kappa))


@pytest.mark.parametrize("kappa", [0.0, 1e-8, 0.5, 10.0, 300.0])
def test_pdf_matches_reference_and_integrates(kappa):
    w = sample_uniform_sphere(_u(200_000, seed=2, lo=0))
    p = vmf_pdf(w, MU, kappa)
    if 0 < kappa < 100:
        torch.testing.assert_close(p, _reference_pdf(w @ MU, kappa), rtol=1e-10, atol=0)
    if kappa < 1e-6:
        torch.testing.assert_close(p, uniform_sphere_pdf(w))
    if kappa <= 10:
        assert abs((p * 4 * math.pi).mean().item() - 1) < 0.02
    else:  # peaked lobe: integrate in (1 - cos) with the trapezoid rule instead
        t = torch.linspace(0, 2, 2_000_001, dtype=torch.float64)
        w_line = torch.stack([(t * (2 - t)).sqrt(), torch.zeros_like(t), 1 - t], -1)
        dens = vmf_pdf(w_line, torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64), kappa)
        assert abs(torch.trapezoid(dens * 2 * math.pi, t).item() - 1) < 1e-6


@pytest.mark.parametrize("kappa", [1e-8, 2.0, 50.0, 1e4])
def test_roundtrips_and_jacobian(kappa):
    u = _u(2000)
    w = sample_vmf(u, MU, kappa)
    assert torch.isfinite(w).all()
    torch.testing.assert_close(w.norm(dim=-1), torch.ones(2000, dtype=torch.float64))
    torch.testing.assert_close(invert_vmf(w, MU, kappa), u, atol=1e-7, rtol=0)
    torch.testing.assert_close(sample_vmf(invert_vmf(w, MU, kappa), MU, kappa), w, atol=1e-7, rtol=0)
    jac = sphere_jacobian(lambda v: sample_vmf(v, MU, kappa), u)
    torch.testing.assert_close(vmf_pdf(w, MU, kappa) * jac, torch.ones(2000, dtype=torch.float64),
                               atol=0, rtol=1e-4)


def test_large_kappa_float32_is_finite_and_concentrated():
    u = torch.rand(10_000, 2)
    w = sample_vmf(u, MU.float(), 1e6)
    assert torch.isfinite(w).all()
    # E[1 - cos] = 1/kappa for large kappa
    assert abs((1 - w.double() @ MU).mean().item() * 1e6 - 1) < 0.1
    assert torch.isfinite(vmf_pdf(w, MU.float(), 1e6)).all()


def test_batched_mu_kappa():
    mu = torch.nn.functional.normalize(torch.randn(500, 3, dtype=torch.float64), dim=-1)
    kappa = torch.rand(500, dtype=torch.float64) * 20
    u = _u(500)
    w = sample_vmf(u, mu, kappa)
    torch.testing.assert_close(invert_vmf(w, mu, kappa), u, atol=1e-7, rtol=0)
    torch.testing.assert_close(vmf_pdf(w, mu, kappa), _reference_pdf((w * mu).sum(-1), kappa), rtol=1e-9, atol=0)


@pytest.mark.parametrize("kappa", [0.0, 3.0, 80.0])
def test_chi2(kappa):
    r = chi2_directions(lambda u: (sample_vmf(u, MU.float(), kappa), torch.ones(len(u), dtype=torch.bool)),
                        lambda w: vmf_pdf(w, MU.float(), kappa), n_samples=100_000, sphere=True, n_tests=3)
    assert r, r.message
    assert abs(r.pdf_integral - 1) < 1e-3


def test_bad_input():
    u = torch.rand(4, 2)
    with pytest.raises(InputError, match="kappa"):
        sample_vmf(u, MU.float(), -1.0)
    with pytest.raises(InputError, match="mu"):
        sample_vmf(u, torch.tensor([1.0, 1.0, 0.0]), 1.0)
    with pytest.raises(InputError, match="kappa"):
        vmf_pdf(torch.tensor([[0.0, 0.0, 1.0]]), MU.float(), torch.ones(3))
