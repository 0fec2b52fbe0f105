"""White furnace and reciprocity tools on the analytic materials, and their input checks."""
import math

import pytest
import torch

from neumat import InputError, Material
from neumat.reflectance.analytic import GGX, Lambert, Plastic, Principled
from neumat.reflectance.microfacet import fresnel_dielectric
from neumat.testing.furnace import white_furnace
from neumat.testing.reciprocity import reciprocity_check

THETAS = torch.tensor([0.0, 0.5, 1.0, 1.3, 1.5])
WI = torch.stack([THETAS.sin(), torch.zeros(5), THETAS.cos()], -1)
SIGMAS = 4.0  # agreement required, in combined Monte Carlo standard errors


@pytest.mark.parametrize("method", ["cosine", "material"])
def test_white_lambert_is_one(method):
    r = white_furnace(Lambert(1.0), WI, n_samples=4096, method=method)
    # both estimators are exact for Lambert (f cos / pdf = 1), so the error is float round-off
    torch.testing.assert_close(r.albedo, torch.ones(5, 3, dtype=torch.float64), atol=1e-6, rtol=0)
    assert r.albedo.shape == r.stderr.shape == (5, 3)


@pytest.mark.parametrize("alpha", [0.05, 0.3, 1.0])
def test_ggx_without_fresnel_loses_energy_but_never_gains(alpha):
    """F = 1: the single-scattering albedo stays <= 1 (+ 4 sigma); both estimators agree within 4 sigma."""
    mat = GGX(alpha, fresnel="none")
    by_material = white_furnace(mat, WI, n_samples=2 ** 15, method="material", seed=1)
    by_cosine = white_furnace(mat, WI, n_samples=2 ** 15, method="cosine", seed=2)
    assert bool((by_material.albedo <= 1 + SIGMAS * by_material.stderr + 1e-6).all()), by_material.albedo
    both = (by_material.stderr ** 2 + by_cosine.stderr ** 2).sqrt()
    assert bool(((by_material.albedo - by_cosine.albedo).abs() <= SIGMAS * both + 1e-6).all())
    if alpha == 0.05:  # a smooth mirror keeps (almost) all energy away from grazing
        assert bool((by_material.albedo[:3] > 0.99).all())


def test_plastic_albedo_is_coat_plus_transmitted_diffuse():
    """Plastic(diffuse=1) albedo = coat albedo + (1 - F(cos_i)), within 4 sigma, and <= 1."""
    plastic = white_furnace(Plastic(diffuse=1.0, roughness=0.3), WI, n_samples=2 ** 15, method="material")
    coat = white_furnace(GGX(0.3, fresnel="dielectric", eta=1.5), WI, n_samples=2 ** 15, method="material", seed=3)
    expected = coat.albedo + (1 - fresnel_dielectric(WI[:, 2].double(), 1.5)).unsqueeze(-1)
    both = (plastic.stderr ** 2 + coat.stderr ** 2).sqrt()
    assert bool(((plastic.albedo - expected).abs() <= SIGMAS * both + 1e-6).all())
    assert bool((plastic.albedo <= 1 + SIGMAS * plastic.stderr).all())


@pytest.mark.parametrize("mat", [Principled(base_color=1.0, metallic=1.0, roughness=0.2),
                                 Principled(base_color=1.0, metallic=0.0, roughness=0.5, anisotropy=0.6)])
def test_principled_white_furnace_bounded(mat):
    r = white_furnace(mat, WI, n_samples=2 ** 14, method="material")
    assert bool((r.albedo <= 1 + SIGMAS * r.stderr).all()), r.albedo


MATERIALS = [Lambert((0.8, 0.5, 0.2)), GGX(0.05, material="gold"), GGX(alpha_x=0.5, alpha_y=0.1, fresnel="dielectric"),
             GGX(0.3, fresnel="schlick", f0=(0.9, 0.5, 0.1)), GGX(0.8, fresnel="none"),
             Plastic(diffuse=(0.2, 0.4, 0.9), roughness=0.2), Principled(metallic=0.4, roughness=0.3, anisotropy=0.8),
             Principled(roughness=0.0)]


@pytest.mark.parametrize("mat", MATERIALS, ids=lambda m: m.describe())
def test_reciprocity_to_float_precision(mat):
    r64 = reciprocity_check(mat, dtype=torch.float64, rtol=1e-12, atol=0)
    assert r64.passed and r64.max_rel < 1e-12, r64
    r32 = reciprocity_check(mat)
    assert r32.passed and r32.max_rel < 1e-4, r32


class _Skewed(Material):
    """f = (1 + wi_x) / pi: not reciprocal."""

    def eval(self, q):
        return ((1 + q.wi[:, 0]) / math.pi).unsqueeze(-1).expand(-1, 3)


class _Textured(Material):
    spatially_varying = True

    def eval(self, q):
        q.require("uv")
        return (q.uv[:, :1] / math.pi).expand(-1, 3) * (q.wi[:, 2:] > 0)


def test_reciprocity_detects_violation_and_supports_textures():
    r = reciprocity_check(_Skewed())
    assert not r and r.max_abs > 0.1 and r.max_rel > 0.1
    assert reciprocity_check(_Textured()).passed
    albedo = white_furnace(_Textured(), WI[:2], n_samples=1000, uv=(0.5, 0.2)).albedo
    torch.testing.assert_close(albedo, torch.full((2, 3), 0.5, dtype=torch.float64), atol=1e-6, rtol=0)


def test_bad_input():
    with pytest.raises(InputError, match="expected a neumat Material"):
        white_furnace(object(), WI)
    with pytest.raises(InputError, match="unit length"):
        white_furnace(Lambert(), torch.tensor([0.0, 0.0, 2.0]))
    with pytest.raises(InputError, match=r"\(M, 3\)"):
        white_furnace(Lambert(), [0.0, 0.0, 1.0])
    with pytest.raises(InputError, match="method"):
        white_furnace(Lambert(), WI, method="uniform")
    with pytest.raises(InputError, match="n_samples"):
        white_furnace(Lambert(), WI, n_samples=1)
    with pytest.raises(InputError, match="cannot sample"):
        white_furnace(_Skewed(), WI, method="material")
    with pytest.raises(InputError, match="spatially varying"):
        white_furnace(_Textured(), WI)
    with pytest.raises(InputError, match="uv must be"):
        white_furnace(_Textured(), WI, uv=(0.5, 2.0))
    with pytest.raises(InputError, match="only used"):
        white_furnace(Lambert(), WI, uv=(0.5, 0.5))
    with pytest.raises(InputError, match="expected a neumat Material"):
        reciprocity_check("ggx")
    with pytest.raises(InputError, match="n: expected"):
        reciprocity_check(Lambert(), n=0)
    with pytest.raises(InputError, match="tolerances"):
        reciprocity_check(Lambert(), rtol=-1)
    full = Lambert()
    full.full_sphere = True
    with pytest.raises(InputError, match="full_sphere"):
        reciprocity_check(full)


@pytest.mark.parametrize("theta_o_deg", [0, 40])
def test_mirror_cone_samples_on_a_lambertian_brdf(theta_o_deg):
    """f = 1 / pi: albedo 1; inside a cone of half-angle a around the normal (theta_o = 0) sin^2 a."""
    from neumat.testing.furnace import mirror_cone_samples

    cone = math.radians(10)
    q, w, in_cone = mirror_cone_samples(math.radians(theta_o_deg), cone, 2 ** 18, torch.Generator().manual_seed(1))
    assert float(w.sum() / math.pi) == pytest.approx(1.0, abs=0.01)
    if theta_o_deg == 0:
        assert float((w.squeeze(-1) * in_cone).sum() / math.pi) == pytest.approx(math.sin(cone) ** 2, rel=0.01)
    assert bool((q.wi[:, 2] > 0).all())


def test_mirror_cone_samples_agree_with_the_white_furnace_on_a_sharp_lobe():
    """On a sharp GGX lobe (alpha 0.05) the mirror-cone estimate of a(wo) equals the cosine-sampled furnace's
    (reciprocity: a(wo) = a(wi) at the same direction) within their standard errors."""
    from neumat.reflectance.spec import parse_spec
    from neumat.testing.furnace import mirror_cone_samples, white_furnace

    ggx = parse_spec("ggx:alpha_x=0.05,alpha_y=0.05,material=gold")
    theta = math.radians(30)
    q, w, _ = mirror_cone_samples(theta, math.radians(10), 2 ** 18, torch.Generator().manual_seed(3))
    with torch.no_grad():
        cone_estimate = (ggx.eval(q).double() * w.double()).sum(0)
    furnace = white_furnace(ggx, torch.tensor([math.sin(theta), 0.0, math.cos(theta)]), n_samples=2 ** 20,
                            method="material")
    assert torch.allclose(cone_estimate, furnace.albedo[0], rtol=0.02), (cone_estimate, furnace.albedo[0])
