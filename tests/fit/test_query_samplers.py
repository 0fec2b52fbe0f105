"""Query samplers: chi-square tests against their densities, uv for spatially varying sources, replay."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from neumat.core.errors import InputError
from neumat.core.material import Material
from neumat.fit.measured_samples import MeasuredSamples
from neumat.fit.query_samplers import QUERY_SAMPLERS, REPLAY_CELLS_NSIDE, replay_cell_weights
from neumat.nn import healpix as hpx
from neumat.testing.chi2 import chi2_2d, chi2_directions


class _Plain(Material):
    name = "plain"


class _Textured(Material):
    name = "textured"
    spatially_varying = True


class _Sphere(Material):
    name = "translucent"
    full_sphere = True


def _sampler_fn(name, source, pick):
    """chi2 sample_fn: draws len(u) queries from the sampler (its own generator) and picks a quantity."""
    draw = QUERY_SAMPLERS.get(name)(source, None)
    gen = torch.Generator().manual_seed(5)
    return lambda u: pick(draw(u.shape[0], gen, "cpu"))


@pytest.mark.parametrize("which", ["wi", "wo"])
def test_cosine_sampler_chi2(which):
    res = chi2_directions(_sampler_fn("cosine", _Plain(), lambda q: getattr(q, which).double()),
                          lambda w: w[:, 2].clamp(min=0) / math.pi, n_samples=100_000, res=(16, 32), n_tests=2)
    assert res, res.message


def test_cosine_sampler_independence_and_uv():
    draw = QUERY_SAMPLERS.get("cosine")(_Textured(), None)
    q = draw(20_000, torch.Generator().manual_seed(0), "cpu")
    assert q.uv is not None and q.uv.shape == (20_000, 2) and float(q.uv.min()) >= 0 and float(q.uv.max()) < 1
    # wi and wo independent: correlation of their z components ~ 0 (sd 1/sqrt(N) = 0.007)
    assert abs(float(np.corrcoef(q.wi[:, 2].numpy(), q.wo[:, 2].numpy())[0, 1])) < 0.03
    assert QUERY_SAMPLERS.get("cosine")(_Plain(), None)(4, torch.Generator(), "cpu").uv is None


def _valid_fraction(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Fraction of phi_d in [0, 2 pi) with wi_z > 0 and wo_z > 0 for theta_h = x pi/2, theta_d = y pi/2.
    wi_z, wo_z = cos th cos td -/+ sin th sin td cos phi_d, so |cos phi_d| < c = 1 / (tan th tan td)."""
    th, td = x * math.pi / 2, y * math.pi / 2
    c = 1 / (torch.tan(th) * torch.tan(td)).clamp(min=1e-300)
    return torch.where(c >= 1, torch.ones_like(c), 1 - 2 / math.pi * torch.acos(c.clamp(max=1)))


def test_rusinkiewicz_sampler_chi2():
    """(theta_h, theta_d) must have density proportional to the valid fraction of phi_d (closed form)."""
    from neumat.core.coords import io_to_rusinkiewicz

    g = (torch.arange(4000, dtype=torch.float64) + 0.5) / 4000
    norm = _valid_fraction(g[:, None], g[None, :]).mean().item()

    def pick(q):
        th, _, td, _ = io_to_rusinkiewicz(q.wi.double(), q.wo.double())
        return torch.stack([th, td], -1) / (math.pi / 2)

    res = chi2_2d(_sampler_fn("rusinkiewicz", _Plain(), pick), lambda p: _valid_fraction(p[:, 0], p[:, 1]) / norm,
                  n_samples=100_000, res=(16, 16), quad=24)  # the density has a sqrt kink: more points
    assert res, res.message


def test_merl_sampler_chi2():
    """(sqrt(theta_h / (pi/2)), theta_d / (pi/2)) must have density proportional to the valid fraction of phi_d:
    theta_h = pi/2 u^2 with u uniform, as MERL's cells."""
    from neumat.core.coords import io_to_rusinkiewicz

    g = (torch.arange(4000, dtype=torch.float64) + 0.5) / 4000
    norm = _valid_fraction(g[:, None] ** 2, g[None, :]).mean().item()

    def pick(q):
        th, _, td, _ = io_to_rusinkiewicz(q.wi.double(), q.wo.double())
        return torch.stack([(th / (math.pi / 2)).sqrt(), td / (math.pi / 2)], -1)

    res = chi2_2d(_sampler_fn("merl", _Plain(), pick), lambda p: _valid_fraction(p[:, 0] ** 2, p[:, 1]) / norm,
                  n_samples=100_000, res=(16, 16), quad=24)
    assert res, res.message


def test_cosine_merl_sampler_is_half_cosine_then_half_merl():
    n = 1001
    q = QUERY_SAMPLERS.get("cosine_merl")(_Textured(), None)(n, torch.Generator().manual_seed(3), "cpu")
    gen = torch.Generator().manual_seed(3)
    a = QUERY_SAMPLERS.get("cosine")(_Textured(), None)(n // 2, gen, "cpu")
    b = QUERY_SAMPLERS.get("merl")(_Textured(), None)(n - n // 2, gen, "cpu")
    for got, want in ((q.wi, (a.wi, b.wi)), (q.wo, (a.wo, b.wo)), (q.uv, (a.uv, b.uv))):
        torch.testing.assert_close(got, torch.cat(want), rtol=0, atol=0)


def test_rusinkiewicz_sampler_valid_and_exact_count():
    q = QUERY_SAMPLERS.get("rusinkiewicz")(_Textured(), None)(1000, torch.Generator().manual_seed(1), "cpu")
    assert len(q) == 1000 and q.uv.shape == (1000, 2)
    assert bool((q.wi[:, 2] > 0).all() and (q.wo[:, 2] > 0).all())


def test_replay_sampler_draws_stored_samples_uniformly():
    n = 7
    gen = torch.Generator().manual_seed(0)
    wi = torch.nn.functional.normalize(torch.rand(n, 3, generator=gen) + 0.1, dim=-1)
    wo = torch.nn.functional.normalize(torch.rand(n, 3, generator=gen) + 0.1, dim=-1)
    samples = MeasuredSamples(wi, wo, torch.arange(3 * n, dtype=torch.float32).reshape(n, 3))
    q = QUERY_SAMPLERS.get("replay")(samples, None)(14_000, torch.Generator().manual_seed(2), "cpu")
    torch.testing.assert_close(samples.eval(q), samples.value[q.index], rtol=0, atol=0)
    torch.testing.assert_close(q.wi, wi[q.index], rtol=0, atol=0)
    counts = torch.bincount(q.index, minlength=n).double()
    stat = float(((counts - 2000) ** 2 / 2000).sum())
    assert stat < 22.5  # chi-square, 6 degrees of freedom, p = 0.001


@pytest.mark.parametrize("name", ["cosine", "rusinkiewicz", "merl", "cosine_merl"])
def test_full_sphere_source_raises(name):
    with pytest.raises(InputError, match="translucent.*whole sphere"):
        QUERY_SAMPLERS.get(name)(_Sphere(), None)


def test_replay_needs_measured_samples():
    with pytest.raises(InputError, match="MeasuredSamples.*plain"):
        QUERY_SAMPLERS.get("replay")(_Plain(), None)


def _clustered_samples():
    """Samples in three (wi, wo) HEALPix cells of "replay_cells", holding 1, 3 and 12 samples, each near its
    pixels' centres: a crowded cell, as an RGL file's nodes crowd into its specular peak."""
    nside, gen = REPLAY_CELLS_NSIDE, torch.Generator().manual_seed(3)

    def near(pixel: int, n: int) -> torch.Tensor:
        centre = hpx.pix2vec(nside, torch.tensor([pixel]), torch.float32)
        return torch.nn.functional.normalize(centre + 0.01 * torch.randn(n, 3, generator=gen), dim=-1)

    parts = [(near(pi, n), near(po, n)) for n, (pi, po) in zip((1, 3, 12), ((2, 2), (30, 2), (33, 40)))]
    wi, wo = (torch.cat(p) for p in zip(*parts))
    cells = hpx.vec2pix(nside, wi) * (12 * nside ** 2) + hpx.vec2pix(nside, wo)
    assert torch.unique(cells).numel() == 3 and bool((wi[:, 2] > 0).all() and (wo[:, 2] > 0).all())
    return MeasuredSamples(wi, wo, torch.rand(wi.shape[0], 3, generator=gen)), cells


def test_replay_cells_draws_every_cell_equally_and_uniformly_within():
    samples, cells = _clustered_samples()
    weights = replay_cell_weights(samples)
    expected = torch.tensor([1 / 3] + [1 / 9] * 3 + [1 / 36] * 12, dtype=torch.float64)
    torch.testing.assert_close(weights, expected, rtol=1e-12, atol=0)
    n = 36_000
    q = QUERY_SAMPLERS.get("replay_cells")(samples, None)(n, torch.Generator().manual_seed(4), "cpu")
    torch.testing.assert_close(samples.eval(q), samples.value[q.index], rtol=0, atol=0)
    counts = torch.bincount(q.index, minlength=len(samples)).double()
    stat = float(((counts - n * expected) ** 2 / (n * expected)).sum())
    assert stat < 37.7  # chi-square, 15 degrees of freedom, p = 0.001
    per_cell = torch.stack([counts[cells == c].sum() for c in torch.unique(cells)])
    assert float(((per_cell - n / 3) ** 2 / (n / 3)).sum()) < 13.8  # chi-square, 2 degrees of freedom, p = 0.001


def test_replay_cells_is_reproducible_and_needs_measured_samples():
    samples, _ = _clustered_samples()
    draw = QUERY_SAMPLERS.get("replay_cells")(samples, None)
    a, b = (draw(100, torch.Generator().manual_seed(9), "cpu").index for _ in range(2))
    assert torch.equal(a, b)
    with pytest.raises(InputError, match="replay_cells.*MeasuredSamples.*plain"):
        QUERY_SAMPLERS.get("replay_cells")(_Plain(), None)
