"""Comparison renderings: the "mis-lobes" strategy and the "sobol" sampler are unbiased (a Lambertian under a
constant sky reflects albedo x radiance), quasi-random points converge faster, and the noise floor is scored like
the material and falls with the sample count."""
from __future__ import annotations

import pytest

import torch

from neumat import InputError
from neumat.catalog.open_material import open_material
from neumat.core.material import Material, NonNegative
from neumat.core.query import Query
from neumat.render.comparison import comparison_images, image_comparison, reference_renders
from neumat.render.render import render
from neumat.warp.hemisphere import sample_cosine_hemisphere


@pytest.mark.parametrize("strategy, sampler, tol", [("mis-lobes", "random", 0.02), ("mis-lobes", "sobol", 0.002),
                                                    ("mis", "sobol", 0.002)])
def test_lambertian_under_a_constant_sky_reflects_albedo_times_radiance(strategy, sampler, tol):
    """The mean of 36 pixels at 512 spp; tol about 6 standard deviations (measured at 4096 spp: per-pixel
    standard deviation 0.0066 for independent numbers, 1e-4 for Sobol points)."""
    img = render(open_material("lambert:albedo=0.5"), light="const:1", spp=512, resolution=16, strategy=strategy,
                 sampler=sampler, jitter=False)
    centre = img[5:11, 5:11]  # on the sphere: radiance 0.5 exactly, the rest is estimator noise
    assert abs(centre.mean().item() - 0.5) < tol


def test_sobol_points_converge_faster_than_independent_ones():
    """The sphere under the sky, one pixel's error over spp: quasi-random points beat independent ones."""
    m = open_material("ggx:roughness=0.2")
    ref = render(m, spp=2048, resolution=16, strategy="mis-lobes", sampler="sobol", seed=9)
    err = {s: (render(m, spp=64, resolution=16, strategy="mis-lobes", sampler=s) - ref).abs().mean().item()
           for s in ("random", "sobol")}
    assert err["sobol"] < 0.8 * err["random"], err


def test_the_reference_scores_the_floor_the_floor_falls_with_spp_and_another_material_is_above_it():
    """The material and the floor are scored the same way: the reference as the material gets exactly the floor
    (the floor is what a perfect model scores), which falls with spp, and a different material scores worse."""
    m = open_material("ggx:roughness=0.1")
    same = image_comparison(m, m, spp=4, resolution=16)
    assert same["mae"] == same["floor_mae"] > 0 and same["ssim"] == same["floor_ssim"]
    assert image_comparison(m, m, spp=64, resolution=16)["floor_mae"] < 0.5 * same["floor_mae"]
    other = image_comparison(open_material("ggx:roughness=0.4"), m, spp=64, resolution=16)
    assert other["mae"] > 2 * other["floor_mae"] and other["ssim"] < other["floor_ssim"]


class RedNoise(Material):
    """A glossy material whose red channel carries a negative offset, as measured tables' noise: negative away
    from the highlight, positive in it."""

    def __init__(self) -> None:
        self.inner = open_material("ggx:roughness=0.2")
        self.can_sample = True

    def eval(self, q):
        return self.inner.eval(q) - torch.tensor([0.05, 0.0, 0.0], dtype=q.wi.dtype)

    def sample(self, q, u):
        return self.inner.sample(q, u)

    def pdf(self, q):
        return self.inner.pdf(q)


def test_the_reference_is_scored_with_its_negative_values_read_as_zero():
    """reference_renders renders NonNegative(reference) (what every fit's targets are), which is not what the raw
    reference renders; a model equal to the clamped function scores the floor exactly."""
    ref = RedNoise()
    clamped = NonNegative(ref)
    renders = reference_renders(ref, spp=16, resolution=16)
    want = comparison_images({"c": clamped}, 16, 16, seed=0)["c"]
    raw = comparison_images({"r": ref}, 16, 16, seed=0)["r"]
    assert torch.equal(torch.as_tensor(renders[1]), torch.as_tensor(want))
    assert float((torch.as_tensor(raw) - torch.as_tensor(want))[..., 0].abs().max()) > 0.01  # the clamp matters
    scores = image_comparison(clamped, ref, spp=16, resolution=16)
    assert scores["mae"] == scores["floor_mae"] and scores["ssim"] == scores["floor_ssim"]


def test_non_negative_clamps_values_and_sample_weights_and_keeps_the_rest():
    ref, g = RedNoise(), torch.Generator().manual_seed(0)
    wi, wo = (sample_cosine_hemisphere(torch.rand(256, 2, generator=g)) for _ in range(2))
    q, u = Query(wi, wo), torch.rand(256, 2, generator=g)
    m = NonNegative(ref)
    assert torch.equal(m.eval(q), ref.eval(q).clamp(min=0)) and bool((ref.eval(q)[:, 0] < 0).any())
    s, s_ref = m.sample(q, u), ref.sample(q, u)
    assert torch.equal(s.wo, s_ref.wo) and torch.equal(s.pdf, s_ref.pdf)
    assert torch.equal(s.weight, s_ref.weight.clamp(min=0))
    assert torch.equal(m.pdf(q), ref.pdf(q)) and m.can_sample and not m.spatially_varying


def test_unknown_sampler_is_refused():
    with pytest.raises(InputError, match="sampler: expected one of random, sobol"):
        render(open_material("lambert"), spp=1, resolution=8, sampler="halton")


def test_the_converged_reference_spends_the_floors_footprint_positions_per_pixel(monkeypatch):
    """A Monte Carlo footprint filter (a texture set's SVBRDF) renders the 16x-spp reference with 1/16 of its
    positions an evaluation (as many per pixel as the floor), from a copy: the material keeps its count and its
    generator; its expectation is unchanged (a plane at 64 spp: the two means within 1 %); materials without the
    filter are rendered as they are."""
    from neumat.reflectance.procedural_texture import procedural_texture_set
    from neumat.reflectance.svbrdf import SVBRDF
    from neumat.render import comparison
    from neumat.render.comparison import REFERENCE_FACTOR, per_pixel_footprint_budget

    svbrdf = SVBRDF(procedural_texture_set("bumps", size=16), samples=64)
    state = svbrdf.generator.get_state()
    fewer = per_pixel_footprint_budget(svbrdf, REFERENCE_FACTOR)
    assert fewer.samples == 4 and svbrdf.samples == 64 and fewer.maps is svbrdf.maps
    assert fewer.generator is not svbrdf.generator and torch.equal(svbrdf.generator.get_state(), state)
    assert per_pixel_footprint_budget(SVBRDF(procedural_texture_set("bumps", size=8), samples=8), 100).samples == 1
    ggx = open_material("ggx:roughness=0.3")
    assert per_pixel_footprint_budget(ggx, REFERENCE_FACTOR) is ggx
    used = []
    real = comparison.comparison_images
    monkeypatch.setattr(comparison, "comparison_images", lambda materials, spp, *a, **k: used.append(
        (spp, materials["ref"].material.samples)) or real(materials, spp, *a, **k))
    reference_renders(svbrdf, 2, 8)
    assert used == [(2 * REFERENCE_FACTOR, 4), (2, 64)]
    means = [render(m, scene="plane", spp=64, resolution=16, seed=0).mean() for m in (svbrdf, fewer)]
    assert abs(float(means[0] / means[1]) - 1) < 0.01
