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


def _svbrdf(texels):
    from neumat.io.texture_set import TextureSet
    from neumat.reflectance.svbrdf import SVBRDF

    z = torch.zeros(texels, texels)
    normal = torch.stack([z, z, torch.ones_like(z)], -1)
    return SVBRDF(TextureSet(color=torch.full((texels, texels, 3), 0.5), normal=normal, roughness=z + 0.5,
                             metalness=z, height=z, name=f"flat{texels}"), samples=1)


def _minor_texels(sampler, texels, n, seed):
    """The footprints' minor standard deviation in texels of a texels^2 source, (n,)."""
    q = QUERY_SAMPLERS.get(sampler)(_svbrdf(texels))(n, torch.Generator().manual_seed(seed), "cpu")
    return torch.linalg.eigvalsh(q.footprint.double())[:, 0].sqrt() * texels


def test_texel_relative_footprints_match_the_paper_at_1024():
    """At a 64^2 source the default sampler's footprints, in texels, follow the paper's 1024^2 distribution (the
    fractions below 1/8 and 1 texel agree within 5 binomial standard deviations); the uv sampler puts ~3/4 of
    them below 1/8 texel."""
    n = 200_000
    paper = _minor_texels("footprint-uv", 1024, n, 0)
    small = _minor_texels("footprint", 64, n, 1)
    for limit in (1 / 8, 1.0, 16.0):
        p, q = (paper < limit).double().mean().item(), (small < limit).double().mean().item()
        sigma = math.sqrt(max(p * (1 - p), 1 / n) * 2 / n)
        assert abs(p - q) < 5 * sigma, (limit, p, q)
    # at 1024^2 the texel-relative draw is the uv draw
    assert torch.equal(paper, _minor_texels("footprint", 1024, n, 0))
    assert (_minor_texels("footprint-uv", 64, n, 1) < 1 / 8).double().mean().item() > 0.7


def test_fine_bias_and_elongation_std_are_recipe_options_that_reach_the_draws(monkeypatch):
    """The multiscale family's options fine_bias / elongation_std are checked by name and build its fit's footprint
    sampler; with elongation_std 0 every footprint's elongation is exactly 1 / cos theta_o (clamped)."""
    import neumat.methods.latent_mlp.train as tripleplane
    from neumat.fit.phase import FitContext
    from neumat.fit.preset import resolve_preset
    from neumat.fit.method import recipe_for
    from neumat.models.registry import build_model

    import neumat.methods.latent_mlp.train as multiscale
    with pytest.raises(InputError, match=r"option.fine_bias: expected a value > 0, got 0"):
        resolve_preset("tripleplane", "paper", overrides={"option.fine_bias": 0})
    assert recipe_for("neumip", "cpu").options == {"fine_bias": 5.0, "elongation_std": 0.2, "target_samples": 0}
    built = []

    class Recording:
        def get(self, name):
            return lambda *args, **kwargs: built.append(kwargs) or QUERY_SAMPLERS.get(name)(*args, **kwargs)

    monkeypatch.setattr(multiscale, "QUERY_SAMPLERS", Recording())
    recipe = recipe_for("tripleplane", "cpu")
    recipe.options.update(fine_bias=3.0, elongation_std=0.0)
    ctx = FitContext(build_model({"type": "tripleplane"}), Lambert(), recipe, torch.device("cpu"),
                     torch.Generator().manual_seed(0), resuming=True)
    tripleplane.phases(ctx)
    assert built == [{"fine_bias": 3.0, "elongation_std": 0.0}]
    q = QUERY_SAMPLERS.get("footprint")(Lambert(), **built[0])(256, torch.Generator().manual_seed(1), "cpu")
    eig = torch.linalg.eigvalsh(q.footprint.double())
    want = (1 / q.wo[:, 2].clamp(min=0.01)).double()
    assert torch.allclose((eig[:, 1] / eig[:, 0]).sqrt(), torch.maximum(want, 1 / want), rtol=1e-4)


def test_target_samples_filter_the_fits_targets_with_that_many_footprint_positions(monkeypatch):
    """Option target_samples: the fit's source is a copy estimating each footprint with that many positions (the
    same estimate as a source built with that count, drawn from the same generator); the user's source keeps its
    own; 0 keeps the source's count, and a source without footprint filtering is used as it is."""
    import neumat.methods.latent_mlp.train as train
    from neumat.fit.footprint_queries import with_target_samples
    from neumat.fit.method import recipe_for
    from neumat.fit.phase import FitContext
    from neumat.models.registry import build_model

    source = _svbrdf(8)
    copy = with_target_samples(source, 5)
    assert copy.samples == 5 and source.samples == 1 and with_target_samples(source, 0) is source
    lambert = Lambert()
    assert with_target_samples(lambert, 5) is lambert
    q = QUERY_SAMPLERS.get("footprint")(source)(64, torch.Generator().manual_seed(2), "cpu")
    reference = _svbrdf(8)
    reference.samples = 5
    for material in (copy, reference):
        material.generator.manual_seed(3)
    assert torch.equal(copy.eval(q), reference.eval(q))
    seen = []
    monkeypatch.setattr(train, "online_phase", lambda ctx, *a, **k: seen.append(ctx.source.samples))
    recipe = recipe_for("multiscale", "cpu")
    recipe.options.update(target_samples=5)
    ctx = FitContext(build_model({"type": "multiscale"}), source, recipe, torch.device("cpu"),
                     torch.Generator().manual_seed(0), resuming=True)
    train.phases(ctx)
    assert seen == [5] and source.samples == 1
