"""The fixed lobe mixture (cosine + GGX reflection lobes): chi-square tests of the sampler against its density,
normalisation, the mixture's components, bad input."""
from __future__ import annotations

import math

import pytest
import torch

from neumat import InputError
from neumat.testing.chi2 import chi2_directions
from neumat.warp.ggx import ggx_reflection_pdf
from neumat.warp.hemisphere import cosine_hemisphere_pdf
from neumat.warp.lobe_mixture import DEFAULT_ALPHAS, lobe_mixture_pdf, sample_lobe_mixture
from neumat.warp.sphere import sample_uniform_sphere


def view(theta_deg: float, n: int, dtype=torch.float64) -> torch.Tensor:
    t, p = math.radians(theta_deg), math.radians(20.0)
    return torch.tensor([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)], dtype=dtype).expand(n, 3)


# the default mixture's sharpest lobe (alpha 0.01) is narrower than any histogram cell: chi-square tests use
# lobes a cell grid resolves; the default mixture is checked by its normalisation and its components below
CASES = {"normal view": ((0.08, 0.3), 0.0), "oblique view": ((0.1, 0.45), 65.0), "one lobe": ((0.2,), 40.0)}


@pytest.mark.parametrize("case", CASES)
def test_sampler_matches_its_density(case):
    alphas, theta = CASES[case]

    def sample(u):
        wo = sample_lobe_mixture(view(theta, len(u), u.dtype), u, alphas)
        return wo, wo[:, 2] > 0

    def pdf(wo):
        return lobe_mixture_pdf(view(theta, len(wo), wo.dtype), wo, alphas)

    r = chi2_directions(sample, pdf, n_samples=300_000, sphere=True, n_tests=len(CASES), quad=16,
                        dtype=torch.float64)
    assert r, r.message


def test_default_density_is_the_mean_of_its_components():
    w = sample_uniform_sphere(torch.rand(4096, 2, generator=torch.Generator().manual_seed(1), dtype=torch.float64))
    wi = view(30.0, len(w))
    parts = [cosine_hemisphere_pdf(w)] + [ggx_reflection_pdf(wi, w, a, a) for a in DEFAULT_ALPHAS]
    assert torch.allclose(lobe_mixture_pdf(wi, w), torch.stack(parts).mean(0), rtol=1e-12, atol=0)


def test_each_component_is_picked_with_equal_probability():
    n = 200_000
    u = torch.rand(n, 2, generator=torch.Generator().manual_seed(2), dtype=torch.float64)
    wi = view(0.0, n)
    wo = sample_lobe_mixture(wi, u, (0.01,))
    near = (wo[:, 2] > math.cos(math.radians(3.0))).double().mean().item()  # within 3 degrees of the normal
    cosine_share = 1 - math.cos(math.radians(3.0)) ** 2
    t = math.tan(math.radians(1.5))  # wo within 3 degrees <=> half vector within 1.5 (normal view)
    ggx_share = t * t / (0.01 ** 2 + t * t)  # GGX: P(tan theta_h < t) = t^2 / (alpha^2 + t^2)
    assert abs(near - 0.5 * (cosine_share + ggx_share)) < 0.004


@pytest.mark.parametrize("alphas", [(), (0.1, 0.0), (-0.2,)])
def test_bad_roughnesses_are_refused(alphas):
    with pytest.raises(InputError, match="positive GGX roughnesses"):
        sample_lobe_mixture(view(10.0, 4), torch.rand(4, 2, dtype=torch.float64), alphas)
