"""Layered coats over a base (`neumat.reflectance.layered`), their albedo table, smudge masks and the JSON reader."""
import json
import math

import pytest
import torch

from neumat.core.errors import InputError, UnknownNameError
from neumat.core.query import Query
from neumat.catalog.open_material import open_material
from neumat.reflectance.analytic import Lambert
from neumat.reflectance.coat_albedo import CoatAlbedo
from neumat.reflectance.layered import COAT_FEATURES, Coat, LayeredMaterial
from neumat.reflectance.lean import NormalGroup
from neumat.reflectance.microfacet import fresnel_dielectric
from neumat.warp.ggx_distribution import ggx_ndf, smith_g1
from neumat.reflectance.smudge_map import smudge_map
from neumat.reflectance.svbrdf import SVBRDF
from neumat.testing.chi2 import chi2_material
from neumat.testing.furnace import white_furnace
from neumat.testing.reciprocity import reciprocity_check
from test_svbrdf import _checker_set, _directions  # normal-mapped metal / dielectric checker


def _textured(size=16, **coat):
    """Checker SVBRDF under a smudged, tinted coat with a tilted normal map."""
    tilt = torch.tensor([0.2, -0.1, 1.0])
    normal = (tilt / tilt.norm()).expand(size, size, 3).clone()
    normal[: size // 2] = torch.tensor([0.0, 0.0, 1.0])
    args = dict(roughness=0.1 + 0.3 * smudge_map(size, seed=2), weight=0.9, eta=1.5, tint=(0.9, 0.8, 0.7),
                normal=normal)
    args.update(coat)
    return LayeredMaterial(SVBRDF(_checker_set()), [Coat(**args)])


# ----------------------------------------------------------------------------------------- albedo table

def _albedo_by_ndf_sampling(mu: float, alpha: float, eta: float, n: int = 1 << 20) -> tuple[float, float]:
    """E(mu) by sampling h ~ D(h) cos(h) (Walter et al. 2007), not the table's visible normals; float64."""
    g = torch.Generator().manual_seed(5)
    u = torch.rand(n, 2, generator=g, dtype=torch.float64)
    tan2 = alpha * alpha * u[:, 0] / (1 - u[:, 0])
    cos_h = 1 / (1 + tan2).sqrt()
    sin_h = (1 - cos_h * cos_h).sqrt()
    phi = 2 * math.pi * u[:, 1]
    h = torch.stack([sin_h * phi.cos(), sin_h * phi.sin(), cos_h], -1)
    wi = torch.tensor([math.sqrt(1 - mu * mu), 0.0, mu], dtype=torch.float64).expand(n, 3)
    c = (wi * h).sum(-1)
    wo = 2 * c.unsqueeze(-1) * h - wi
    pdf_wo = ggx_ndf(h, alpha, alpha) * cos_h / (4 * c.abs())
    f = ggx_ndf(h, alpha, alpha) * smith_g1(wi, alpha, alpha) * smith_g1(wo, alpha, alpha) \
        * fresnel_dielectric(c, eta) / (4 * mu * wo[:, 2].abs())
    x = torch.where((wo[:, 2] > 0) & (c > 0), f * wo[:, 2] / pdf_wo, torch.zeros_like(f))
    return float(x.mean()), float(x.std() / math.sqrt(n))


@pytest.mark.parametrize("mu, alpha", [(0.37, 0.13), (0.83, 0.45), (0.15, 0.05), (0.6, 0.9)])
def test_coat_albedo_matches_an_independent_estimate(mu, alpha):
    table = CoatAlbedo(1.5)
    ref, err = _albedo_by_ndf_sampling(mu, alpha, 1.5)
    got = float(table(torch.tensor([mu], dtype=torch.float64), torch.tensor([alpha], dtype=torch.float64)))
    # 4 standard errors of the reference plus 2e-3 for the table (Sobol noise and bilinear interpolation)
    assert abs(got - ref) < 4 * err + 2e-3, (got, ref, err)


def test_coat_albedo_average_is_the_exact_integral_of_the_interpolant():
    table = CoatAlbedo(1.3, samples=256)
    mu = torch.linspace(0, 1, 200_001, dtype=torch.float64)
    for alpha in (0.004, 0.21, 0.77):
        e = table(mu, torch.full_like(mu, alpha))
        integral = float(torch.trapezoid(e * 2 * mu, mu))
        assert abs(float(table.averaged(torch.tensor([alpha], dtype=torch.float64))) - integral) < 1e-8


def test_coat_albedo_is_fresnel_at_normal_incidence_for_a_smooth_coat():
    table = CoatAlbedo(1.5)
    e = float(table(torch.tensor([1.0], dtype=torch.float64), torch.tensor([1e-3], dtype=torch.float64)))
    assert abs(e - ((1.5 - 1) / (1.5 + 1)) ** 2) < 1e-4


# ------------------------------------------------------------------------------------------ closed forms

@pytest.mark.parametrize("roughness", [0.05, 0.3, 0.8])
def test_white_lambert_under_a_clear_coat_conserves_energy(roughness):
    m = LayeredMaterial(Lambert(1.0), [Coat(roughness=roughness, eta=1.5)])
    th = torch.tensor([0.0, 0.6, 1.1, 1.45])
    wi = torch.stack([th.sin(), 0 * th, th.cos()], -1)
    r = white_furnace(m, wi, n_samples=1 << 15, method="material", uv=torch.tensor([0.3, 0.3]), dtype=torch.float64)
    assert bool(((r.albedo - 1).abs() < 4 * r.stderr + 3e-3).all()), r


def test_index_matched_coat_is_invisible_and_its_tint_is_beer_lambert():
    wi, wo, uv = _directions(256)
    base = SVBRDF(_checker_set())
    clear = LayeredMaterial(base, [Coat(roughness=0.2, eta=1.0)])
    torch.testing.assert_close(clear.eval(Query(wi, wo, uv=uv)), base.eval(Query(wi, wo, uv=uv)), rtol=1e-5, atol=1e-6)
    tinted = LayeredMaterial(base, [Coat(roughness=0.2, eta=1.0, tint=(0.5, 0.25, 1.0))])
    expected = base.eval(Query(wi, wo, uv=uv)) * torch.tensor([0.5, 0.25, 1.0]) ** (0.5 / wi[:, 2:] + 0.5 / wo[:, 2:])
    torch.testing.assert_close(tinted.eval(Query(wi, wo, uv=uv)), expected, rtol=1e-4, atol=1e-6)


def test_coat_weight_blends_linearly_and_zero_weight_is_the_base():
    wi, wo, uv = _directions(256, seed=1)
    q = Query(wi, wo, uv=uv)
    f = {w: LayeredMaterial(SVBRDF(_checker_set()), [Coat(roughness=0.1, weight=w)]).eval(q) for w in (0.0, 0.3, 1.0)}
    torch.testing.assert_close(f[0.0], SVBRDF(_checker_set()).eval(q))
    torch.testing.assert_close(f[0.3], 0.7 * f[0.0] + 0.3 * f[1.0], rtol=1e-5, atol=1e-6)


def test_coat_over_a_black_base_is_the_ggx_dielectric_lobe():
    """Over a black base only the coat reflects: its GGX lobe with dielectric Fresnel, against the formula in
    float64 (the coat's maps are float32, so alpha = 0.3 carries a relative rounding of 1e-8)."""
    wi, wo, _ = _directions(64, seed=2)
    wi, wo = wi.double(), wo.double()
    m = LayeredMaterial(Lambert(0.0), [Coat(roughness=0.3, eta=1.7)])
    h = torch.nn.functional.normalize(wi + wo, dim=-1)
    ref = ggx_ndf(h, 0.3, 0.3) * smith_g1(wi, 0.3, 0.3) * smith_g1(wo, 0.3, 0.3) \
        * fresnel_dielectric((wi * h).sum(-1), 1.7) / (4 * wi[:, 2] * wo[:, 2])
    got = m.eval(Query(wi, wo, uv=torch.zeros(64, 2, dtype=torch.float64)))
    torch.testing.assert_close(got, ref.unsqueeze(-1).expand(-1, 3), rtol=1e-6, atol=1e-12)


# ------------------------------------------------------------------------------------------ properties

def test_textured_coat_is_reciprocal():
    result = reciprocity_check(_textured(), n=4096)
    assert result.passed, result


@pytest.mark.parametrize("wi, uv", [
    ((0.6, 0.0, 0.8), (0.3, 0.3)),
    pytest.param((-0.9, 0.3, 0.3), (0.71, 0.12), marks=pytest.mark.slow),
    pytest.param((0.1, 0.2, 0.97), (0.55, 0.9), marks=pytest.mark.slow),
])
def test_sampling_matches_pdf(wi, uv):
    wi = torch.tensor(wi)
    wi = wi / wi.norm()
    result = chi2_material(_textured(), wi, n_samples=100_000, res=(40, 40),
                           template=Query(wi[None], uv=torch.tensor([uv])))
    assert result, result.message


def test_sample_weight_is_eval_cos_over_pdf():
    wi, _, uv = _directions(512, seed=3)
    m = _textured()
    s = m.sample(Query(wi, uv=uv), torch.rand(512, 2, generator=torch.Generator().manual_seed(0)))
    ok = s.pdf > 0
    assert ok.float().mean() > 0.9
    ref = m.eval(Query(wi, s.wo, uv=uv))[ok] * (s.wo[ok, 2] / s.pdf[ok])[:, None]
    torch.testing.assert_close(s.weight[ok], ref)


def test_sample_direction_is_the_sampled_direction_without_an_evaluation(monkeypatch):
    """SVBRDF and LayeredMaterial draw wo and pdf without evaluating the footprint (the layered sampler asks
    its base for a direction only); the default (here GGX) returns sample's wo and pdf."""
    from neumat.reflectance.analytic import GGX

    wi, _, uv = _directions(256, seed=4)
    q = Query(wi, uv=uv)
    u = torch.rand(256, 2, generator=torch.Generator().manual_seed(1))
    for material in (_textured(), SVBRDF(_checker_set()), GGX(0.3)):
        s = material.sample(q, u)
        for m in (material, getattr(material, "base", None)):
            if isinstance(m, (SVBRDF, LayeredMaterial)):
                monkeypatch.setattr(m, "eval", lambda q: (_ for _ in ()).throw(AssertionError("evaluated")))
        wo, pdf = material.sample_direction(q, u)
        monkeypatch.undo()
        assert torch.equal(wo, s.wo) and torch.equal(pdf, s.pdf)
        assert float((pdf > 0).float().mean()) > 0.8      # most draws succeed: the comparison is not vacuous


def test_filtering_constant_maps_changes_nothing_and_lod_is_the_isotropic_footprint():
    wi, wo, uv = _directions(64, seed=4)
    flat = LayeredMaterial(Lambert(0.4), [Coat(roughness=0.2, tint=(0.8, 0.9, 1.0))], samples=8)
    cov = (torch.eye(2) * 0.1 ** 2).expand(64, 2, 2).contiguous()
    torch.testing.assert_close(flat.eval(Query(wi, wo, uv=uv, footprint=cov)), flat.eval(Query(wi, wo, uv=uv)))
    lod = torch.full((64,), 1.0)
    iso = (torch.eye(2) * (2 / 2 / 16) ** 2).expand(64, 2, 2).contiguous()   # 2^lod / 2 texels of 16
    a = LayeredMaterial(SVBRDF(_checker_set()), [Coat(roughness=0.1 + 0.3 * smudge_map(16))], samples=16, seed=1)
    b = LayeredMaterial(SVBRDF(_checker_set()), [Coat(roughness=0.1 + 0.3 * smudge_map(16))], samples=16, seed=1)
    torch.testing.assert_close(a.eval(Query(wi, wo, uv=uv, lod=lod)), b.eval(Query(wi, wo, uv=uv, footprint=iso)))


def test_sampling_features_are_the_base_parameters_then_each_coat():
    m = _textured()
    wi, _, uv = _directions(32, seed=5)
    k = m.sampling_features(Query(wi, uv=uv))
    assert k.shape == (32, 8 + COAT_FEATURES) == (32, m.sampling_feature_dim)
    torch.testing.assert_close(k[:, :8], m.base.sampling_features(Query(wi, uv=uv)))
    assert bool((k[:, 8] >= 0.1).all()) and bool(((k[:, 9] - 0.9).abs() < 1e-6).all())
    torch.testing.assert_close(k[:, 10:13].norm(dim=-1), torch.ones(32))
    # LEAN prefiltering finds each layer's normal and roughness: the base's principled pair, then the coat's alpha
    assert m.surface_normal_groups == (NormalGroup(3, 6, 2.0), NormalGroup(10, 8, 1.0))


def test_smudge_map_tiles_and_is_deterministic():
    a = smudge_map(64, seed=7)
    assert a.shape == (64, 64) and float(a.min()) >= 0 and float(a.max()) <= 1 and float(a.std()) > 0.05
    torch.testing.assert_close(a, smudge_map(64, seed=7))
    assert not torch.equal(a, smudge_map(64, seed=8))
    inner = (a[:, 1:] - a[:, :-1]).abs().max()
    assert float((a[:, 0] - a[:, -1]).abs().max()) <= float(inner) + 1e-6   # the seam is no jump
    assert float((a[0] - a[-1]).abs().max()) <= float((a[1:] - a[:-1]).abs().max()) + 1e-6


# ------------------------------------------------------------------------------------------ description files

def test_json_description(tmp_path):
    spec = {"type": "layered", "base": "lambert:albedo=0.6/0.3/0.1",
            "coats": [{"eta": 1.5, "roughness": 0.3, "tint": [1.0, 0.9, 0.8]},
                      {"eta": 1.4, "roughness": {"smudges": {"seed": 1, "size": 32}, "low": 0.05, "high": 0.4},
                       "weight": {"smudges": {"seed": 2, "size": 32}}}]}
    path = tmp_path / "coated.json"
    path.write_text(json.dumps(spec))
    m = open_material(path, samples=4)
    assert isinstance(m, LayeredMaterial) and len(m.coats) == 2 and m.samples == 4 and m.sampling_feature_dim == 10
    wi, wo, uv = _directions(16, seed=6)
    f = m.eval(Query(wi, wo, uv=uv))
    assert f.shape == (16, 3) and bool(torch.isfinite(f).all()) and bool((f >= 0).all())


@pytest.mark.parametrize("change, message", [
    ({"colour": 1}, "unknown key"),
    ({"coats": []}, "non-empty 'coats'"),
    ({"coats": [{"eta": 1.5}]}, "needs a 'roughness'"),
    ({"coats": [{"roughness": 0.1, "shine": 2}]}, "unknown key"),
    ({"coats": [{"roughness": {"smudges": {}, "image": "x.png", "low": 0, "high": 1}}]}, "exactly one"),
    ({"coats": [{"roughness": {"smudges": {}}}]}, "'low' and 'high'"),
    ({"coats": [{"roughness": {"smudges": {"sizes": 3}, "low": 0.1, "high": 0.2}}]}, "smudges"),
    ({"type": "btf"}, "\"type\": \"layered\""),
    ({"base": "glass:eta=2"}, "unknown material 'glass'"),
    ({"coats": [{"roughness": 0.1, "eta": "glass"}]}, "eta"),
    ({"coats": [{"roughness": 0.1, "tint": 0.5}]}, "tint"),
    ({"max_size": "big"}, "max_size"),
])
def test_bad_json_descriptions_raise(tmp_path, change, message):
    spec = {"type": "layered", "base": "lambert", "coats": [{"roughness": 0.1}]}
    spec.update(change)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(spec))
    with pytest.raises((InputError, UnknownNameError), match=message):
        open_material(path)
    path.write_text('{"type": "layered", ')
    with pytest.raises(InputError, match="not a readable JSON"):
        open_material(path)


@pytest.mark.parametrize("coat, message", [
    (dict(roughness=0.0), "roughness"),
    (dict(roughness=torch.full((4, 4), 2.0)), "roughness"),
    (dict(weight=1.5), "weight"),
    (dict(eta=0.5), "eta"),
    (dict(eta="glass"), "eta"),
    (dict(tint=(1.2, 1.0, 1.0)), "tint"),
    (dict(tint="amber"), "tint"),
    (dict(roughness="rough"), "roughness"),
    (dict(normal=torch.tensor([0.0, 0.0, -1.0]).expand(4, 4, 3)), "normal"),
    (dict(roughness=torch.rand(2, 3, 4)), "roughness"),
])
def test_bad_coats_raise(coat, message):
    with pytest.raises(InputError, match=message):
        LayeredMaterial(Lambert(0.5), [Coat(**coat)])


def test_bad_bases_and_queries_raise():
    with pytest.raises(InputError, match="non-empty list of Coat"):
        LayeredMaterial(Lambert(0.5), [])
    with pytest.raises(InputError, match="Material"):
        LayeredMaterial("lambert", [Coat()])
    m = LayeredMaterial(Lambert(0.5), [Coat()])
    wi, wo, _ = _directions(4)
    with pytest.raises(InputError, match="Query.uv"):
        m.eval(Query(wi, wo))


def test_real_texture_set_under_smudged_coat(shared_data, tmp_path):
    spec = {"type": "layered", "base": str(shared_data / "svbrdf" / "Wood092_1K"), "max_size": 32, "samples": 8,
            "coats": [{"roughness": {"smudges": {"size": 32}, "low": 0.03, "high": 0.3}, "tint": [0.95, 0.9, 0.8]}]}
    path = tmp_path / "varnished_wood.json"
    path.write_text(json.dumps(spec))
    m = open_material(path)
    wi, wo, uv = _directions(256, seed=9)
    cov = (torch.eye(2) * 0.01 ** 2).expand(256, 2, 2).contiguous()
    f = m.eval(Query(wi, wo, uv=uv, footprint=cov))
    base = m.base.eval(Query(wi, wo, uv=uv, footprint=cov))
    assert bool(torch.isfinite(f).all()) and bool((f >= 0).all())
    assert float(f.mean()) > 0 and not torch.allclose(f, base)
