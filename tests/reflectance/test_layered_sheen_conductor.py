"""Sheen layers and textured conductor bases of layered materials (`neumat.reflectance.sheen`,
`neumat.reflectance.conductor_base`, `neumat.reflectance.layered`): closed forms, energy, reciprocity, sampling,
the JSON description."""
import json
import math

import pytest
import torch

from neumat.catalog.open_material import open_material
from neumat.core.errors import InputError
from neumat.core.query import Query
from neumat.reflectance.analytic import GGX, Lambert
from neumat.reflectance.conductor_base import TexturedConductor
from neumat.reflectance.layered import SHEEN_FEATURES, Coat, LayeredMaterial, Sheen, sheen_albedo
from neumat.reflectance.sheen import charlie_sheen
from neumat.reflectance.smudge_map import smudge_map
from neumat.testing.chi2 import chi2_material
from neumat.testing.furnace import white_furnace
from neumat.testing.reciprocity import reciprocity_check


def _wi(thetas):
    th = torch.tensor(thetas, dtype=torch.float64)
    return torch.stack([th.sin(), 0 * th, th.cos()], -1)


def _dirs(n, seed=0):
    g = torch.Generator().manual_seed(seed)
    u = torch.rand(n, 6, generator=g)
    def hemi(a, b):
        r, phi = a.sqrt(), 2 * math.pi * b
        return torch.stack([r * phi.cos(), r * phi.sin(), (1 - a).clamp(min=1e-4).sqrt()], -1)
    return hemi(u[:, 0], u[:, 1]), hemi(u[:, 2], u[:, 3]), u[:, 4:]


def _conductor(size=16):
    tilt = torch.tensor([0.25, 0.1, 1.0])
    normal = (tilt / tilt.norm()).expand(size, size, 3).clone()
    normal[: size // 2] = torch.tensor([0.0, 0.0, 1.0])
    return TexturedConductor("gold", 0.08 + 0.3 * smudge_map(size, seed=3), normal)


def _sheened_conductor():
    return LayeredMaterial(_conductor(), [Coat(roughness=0.1, weight=0.8)],
                           sheen=Sheen(color=(0.9, 0.7, 0.5), roughness=0.2 + 0.5 * smudge_map(16, seed=4), weight=0.8))


# ------------------------------------------------------------------------------------------------ sheen

@pytest.mark.parametrize("mu, alpha", [(0.3, 0.4), (0.8, 1.0), (0.1, 0.25)])
def test_sheen_albedo_matches_uniform_sampling_in_float64(mu, alpha):
    """Where the raw lobe's albedo stays below 1 (no normalisation), the table is int D V cos dwo, here
    estimated with uniformly distributed directions (not the table's cosine-distributed ones)."""
    n = 1 << 20
    u = torch.rand(n, 2, generator=torch.Generator().manual_seed(2), dtype=torch.float64)
    z, phi = u[:, 0], 2 * math.pi * u[:, 1]
    r = (1 - z * z).sqrt()
    wo = torch.stack([r * phi.cos(), r * phi.sin(), z], -1)
    wi = torch.tensor([math.sqrt(1 - mu * mu), 0.0, mu], dtype=torch.float64).expand(n, 3)
    x = charlie_sheen(wi, wo, alpha) * z * 2 * math.pi
    ref, err = float(x.mean()), float(x.std() / math.sqrt(n))
    got = float(sheen_albedo()(torch.tensor([mu], dtype=torch.float64), torch.tensor([alpha], dtype=torch.float64)))
    assert abs(got - ref) < 4 * err + 3e-3, (got, ref, err)


def test_sheen_albedo_is_bounded_by_one_after_normalisation():
    table = sheen_albedo()
    assert float(table.raw.table.max()) > 1.5          # the raw Charlie lobe gains energy at grazing angles
    assert float(table.table.max()) <= 1.0 + 1e-9 and float(table.table.min()) >= 0


def test_sheen_over_a_black_base_is_the_coloured_lobe():
    wi, wo, uv = _dirs(128)
    m = LayeredMaterial(Lambert(0.0), [], sheen=Sheen(color=(0.5, 0.25, 1.0), roughness=0.6))
    ref = charlie_sheen(wi, wo, 0.6)        # alpha 0.6: E_0 < 1 everywhere, so no normalisation
    torch.testing.assert_close(m.eval(Query(wi, wo, uv=uv)), ref[:, None] * torch.tensor([0.5, 0.25, 1.0]),
                               rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize("alpha", [0.05, 0.3, 1.0])
def test_white_sheen_over_white_lambert_conserves_energy(alpha):
    m = LayeredMaterial(Lambert(1.0), [], sheen=Sheen(roughness=alpha))
    r = white_furnace(m, _wi([0.0, 0.7, 1.2, 1.5]), n_samples=1 << 15, method="material",
                      uv=torch.tensor([0.3, 0.3]), dtype=torch.float64)
    assert bool(((r.albedo - 1).abs() < 4 * r.stderr + 4e-3).all()), r


def test_coloured_sheen_and_gold_stay_below_one():
    m = LayeredMaterial(GGX(0.3, material="gold"), [Coat(roughness=0.1)], sheen=Sheen(color=(1.0, 0.5, 0.2)))
    r = white_furnace(m, _wi([0.0, 0.7, 1.2, 1.5]), n_samples=1 << 14, method="material",
                      uv=torch.tensor([0.3, 0.3]), dtype=torch.float64)
    assert bool((r.albedo < 1 + 4 * r.stderr).all()) and bool((r.albedo > 0.2).all()), r


def test_sheen_weight_zero_is_the_material_without_it_and_features_append_two():
    wi, wo, uv = _dirs(64, seed=1)
    q = Query(wi, wo, uv=uv)
    plain = LayeredMaterial(Lambert(0.5), [Coat(roughness=0.2)])
    off = LayeredMaterial(Lambert(0.5), [Coat(roughness=0.2)], sheen=Sheen(weight=0.0))
    torch.testing.assert_close(off.eval(q), plain.eval(q))
    assert off.sampling_feature_dim == plain.sampling_feature_dim + SHEEN_FEATURES
    torch.testing.assert_close(off.sampling_features(q)[:, -2:], torch.tensor([[0.3, 0.0]]).expand(64, 2))


# --------------------------------------------------------------------------------------- conductor base

def test_flat_conductor_base_is_the_ggx_conductor():
    wi, wo, uv = _dirs(128, seed=2)
    m = TexturedConductor("copper", 0.25)
    torch.testing.assert_close(m.eval(Query(wi, wo, uv=uv)), GGX(0.25, material="copper").eval(Query(wi, wo)),
                               rtol=1e-5, atol=1e-6)


def test_conductor_base_under_a_coat_and_a_sheen_is_reciprocal():
    assert reciprocity_check(_sheened_conductor(), n=4096).passed
    assert reciprocity_check(_conductor(), n=4096).passed


@pytest.mark.parametrize("material", ["conductor", "layered"])
def test_sampling_matches_pdf(material):
    m = _conductor() if material == "conductor" else _sheened_conductor()
    wi = torch.tensor([0.5, 0.2, 0.84])
    wi = wi / wi.norm()
    result = chi2_material(m, wi, n_samples=100_000, res=(20, 40),
                           template=Query(wi[None], uv=torch.tensor([[0.3, 0.7]])))
    assert result, result.message


def test_sample_weight_is_eval_cos_over_pdf():
    wi, _, uv = _dirs(256, seed=3)
    m = _sheened_conductor()
    s = m.sample(Query(wi, uv=uv), torch.rand(256, 2, generator=torch.Generator().manual_seed(0)))
    ok = s.pdf > 0
    assert ok.float().mean() > 0.9
    torch.testing.assert_close(s.weight[ok], m.eval(Query(wi, s.wo, uv=uv))[ok] * (s.wo[ok, 2] / s.pdf[ok])[:, None])


def test_bad_conductors_and_sheens_raise():
    with pytest.raises(InputError, match="preset"):
        TexturedConductor("unobtainium")
    with pytest.raises(InputError, match="both eta and k"):
        TexturedConductor(None, eta=(1, 1, 1))
    with pytest.raises(InputError, match="sheen color"):
        LayeredMaterial(Lambert(0.5), [], sheen=Sheen(color=(2.0, 0.0, 0.0)))
    with pytest.raises(InputError, match="sheen roughness"):
        LayeredMaterial(Lambert(0.5), [], sheen=Sheen(roughness=0.01))
    with pytest.raises(InputError, match="empty only under a sheen"):
        LayeredMaterial(Lambert(0.5), [])


def test_json_conductor_base_and_sheen(tmp_path):
    path = tmp_path / "velvet gold.json"
    path.write_text(json.dumps({
        "type": "layered", "samples": 4,
        "base": {"conductor": "gold", "roughness": {"smudges": {"size": 16, "seed": 2}, "low": 0.1, "high": 0.4}},
        "coats": [{"eta": 1.5, "roughness": 0.05}],
        "sheen": {"color": [0.8, 0.8, 0.9], "roughness": 0.4, "weight": 0.5}}))
    m = open_material(path)
    assert isinstance(m.base, TexturedConductor) and m.sheen is not None and m.texture_size == (16, 16)
    assert m.sampling_feature_dim == 4 + 5 + 2
    wi, wo, uv = _dirs(32, seed=4)
    assert bool(torch.isfinite(m.eval(Query(wi, wo, uv=uv))).all())
    path.write_text(json.dumps({"type": "layered", "base": {"conductor": "gold", "eta": [1, 1, 1]}, "coats": [],
                                "sheen": {}}))
    with pytest.raises(InputError, match="either 'conductor'"):
        open_material(path)
