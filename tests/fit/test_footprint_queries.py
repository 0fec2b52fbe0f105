import math

import pytest
import torch
from scipy import stats

from neumat.core.errors import InputError
from neumat.fit.footprint_queries import footprint_scale, sample_footprints
from neumat.fit.query_samplers import QUERY_SAMPLERS
from neumat.nn.latent_texture import check_footprint, footprint_axes
from neumat.reflectance.analytic import Lambert


def test_covariance_matches_eq9_in_float64():
    g = torch.Generator().manual_seed(0)
    n = 200
    cos_view = torch.rand(n, generator=g, dtype=torch.float64) * 0.99 + 0.01
    u = torch.rand(n, 2, generator=g, dtype=torch.float64)
    z2 = 0.2 * torch.randn(n, generator=g, dtype=torch.float64)
    got = sample_footprints(cos_view, u, z2)
    for k in range(n):
        log2_e1 = -13 + 14 * (math.exp(5 * u[k, 0].item()) - 1) / (math.exp(5) - 1)
        a = max(1 + z2[k].item(), 0.2) / cos_view[k].item()
        ang = 2 * math.pi * u[k, 1].item()
        rot = torch.tensor([[math.cos(ang), -math.sin(ang)], [math.sin(ang), math.cos(ang)]], dtype=torch.float64)
        m = 2.0 ** log2_e1 * torch.diag(torch.tensor([a, 1.0], dtype=torch.float64)) @ rot
        torch.testing.assert_close(got[k], m.T @ m, rtol=1e-9, atol=0)


def test_scale_range_and_fine_level_bias():
    e3 = torch.tensor([0.0, 0.5, 1.0], dtype=torch.float64)
    log2 = torch.log2(footprint_scale(e3))
    torch.testing.assert_close(log2, torch.tensor([-13.0, -13 + 14 * math.expm1(2.5) / math.expm1(5), 1.0],
                                                  dtype=torch.float64))
    assert log2[1] < -11.5  # half of the queries use footprints below 2^-11.5


def test_draw_distribution():
    draw = QUERY_SAMPLERS.get("footprint")(Lambert(), None)
    q = draw(20000, torch.Generator().manual_seed(1), "cpu")
    check_footprint(q.footprint)
    # cosine-weighted directions: z^2 uniform; uv uniform
    for x in (q.wi[:, 2] ** 2, q.wo[:, 2] ** 2, q.uv[:, 0], q.uv[:, 1]):
        assert stats.kstest(x.double().numpy(), "uniform").pvalue > 1e-3
    # elongation follows 1 / cos(theta_o): grazing views give elongated footprints
    major, minor, _ = footprint_axes(q.footprint.double())
    ratio = major / minor
    grazing, frontal = ratio[q.wo[:, 2] < 0.2].median(), ratio[q.wo[:, 2] > 0.9].median()
    assert grazing > 5 and frontal < 1.3
    again = draw(20000, torch.Generator().manual_seed(1), "cpu")
    assert torch.equal(again.footprint, q.footprint)


def test_bad_arguments_raise():
    with pytest.raises(InputError, match="min_cos"):
        QUERY_SAMPLERS.get("footprint")(Lambert(), None, min_cos=0)
